"""Cyclic behaviour (issue 20): SYNC every 1 ms, its interval jitter, and a cobus device's
SYNC -> TPDO latency, beside python-canopen's SYNC (python-can's ``send_periodic``).

All in this process on python-can's ``virtual`` bus in real time. An observer (a plain
python-can bus in a thread of its own) records every frame with the time it was sent (the
virtual bus stamps frames when they are sent). For cobus, the producing network also serves
an SDO client against the device throughout, so a SYNC that goes missing under load shows.
"Missed": intervals longer than 1.5 periods. Run longer with COBUS_BENCH_CYCLIC_SECONDS.

cobus runs twice: SYNC timed by the network's loop, and handed to the CAN interface
(``by_interface=True``), which ``virtual`` refuses (a dash). On a host with SocketCAN, run
it where the kernel times SYNC: ``COBUS_BENCH_CYCLIC_INTERFACE=socketcan
COBUS_BENCH_CYCLIC_CHANNEL=vcan0`` (after ``ip link add dev vcan0 type vcan; ip link set up
vcan0``); ``udp_multicast`` works too (python-can's thread sends there).

cobus runs on ``cobus.runtime.run`` (a ``RealTimeLoop``, whose waits under 2 ms are not rounded
up to whole milliseconds) and calls ``gc.freeze()`` once set up, as docs/realtime.md advises
for cyclic work: otherwise a full garbage collection stops every thread for ~10 ms. Then the
lateness of the loop's own timers, 1.3 ms ahead, on a RealTimeLoop and on asyncio's loop.
"""

from __future__ import annotations

import asyncio
import gc
import itertools
import os
import statistics
import threading
import time
from collections.abc import Callable
from typing import Any

import can
import canopen

from cobus.device import DictionaryBuilder, add_device
from cobus.od import DataType
from cobus.runtime import AsyncNetwork, InterfaceTimingError, RealTimeLoop, run

PERIOD = 0.001
SECONDS = float(os.environ.get("COBUS_BENCH_CYCLIC_SECONDS", "5"))
INTERFACE = os.environ.get("COBUS_BENCH_CYCLIC_INTERFACE", "virtual")
CHANNEL = os.environ.get("COBUS_BENCH_CYCLIC_CHANNEL")
NODE = 5
SYNC, TPDO1 = 0x80, 0x180 + NODE


def _bus_args(name: str) -> dict[str, Any]:
    """The bus of one run: a virtual channel of its own, or the one the environment names."""
    if INTERFACE == "virtual":
        return {"interface": "virtual", "channel": f"{name}-{os.getpid()}"}
    if CHANNEL is None and INTERFACE == "udp_multicast":
        from can.interfaces.udp_multicast import UdpMulticastBus

        return {"interface": INTERFACE, "channel": UdpMulticastBus.DEFAULT_GROUP_IPv6}
    return {"interface": INTERFACE, "channel": CHANNEL}


class _Observer:
    """Every frame on the channel with its time stamp (the virtual bus stamps a frame when it
    is sent; SocketCAN when the kernel receives it), from a thread of its own."""

    def __init__(self, args: dict[str, Any]) -> None:
        self._bus = can.Bus(**args, receive_own_messages=False)
        self.frames: list[tuple[float, int]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            msg = self._bus.recv(0.05)
            if msg is not None:
                self.frames.append((msg.timestamp, msg.arbitration_id))

    def close(self) -> list[tuple[float, int]]:
        self._stop.set()
        self._thread.join()
        self._bus.shutdown()
        return self.frames


def _stats(frames: list[tuple[float, int]]) -> dict[str, float]:
    syncs = [t for t, cob in frames if cob == SYNC]
    gaps = [b - a for a, b in itertools.pairwise(syncs)]
    jitter = sorted(abs(g - PERIOD) for g in gaps)
    out = {
        "syncs": len(syncs),
        "p99": jitter[int(len(jitter) * 0.99)] * 1e6 if jitter else float("nan"),
        "max": jitter[-1] * 1e6 if jitter else float("nan"),
        "missed": sum(1 for g in gaps if g > 1.5 * PERIOD),
    }
    latencies = []
    last_sync = None
    for t, cob in frames:
        if cob == SYNC:
            last_sync = t
        elif cob == TPDO1 and last_sync is not None:
            latencies.append(t - last_sync)
            last_sync = None
    if latencies:
        latencies.sort()
        out["tpdo_median"] = statistics.median(latencies) * 1e6
        out["tpdo_p99"] = latencies[int(len(latencies) * 0.99)] * 1e6
    return out


def cobus_figures(by_interface: bool = False) -> dict[str, float] | None:
    """None: the interface cannot time SYNC (``by_interface``)."""
    args = _bus_args("cyc-cob-iface" if by_interface else "cyc-cob")
    observer = _Observer(args)

    async def main() -> int | None:
        async with AsyncNetwork(**args) as master, AsyncNetwork(**args) as field:
            b = DictionaryBuilder(device_name="cyclic")
            b.variable(0x2000, "Counter", DataType.UNSIGNED16, access="ro", mappable=True)
            b.tpdo(1, [(0x2000, 0)], transmission_type=1)  # every SYNC
            device = add_device(field, NODE, b.build())
            master.nmt.start(NODE)
            sdo = master.add_remote(NODE).sdo
            await asyncio.sleep(0.05)
            gc.freeze()  # set up: a full collection no longer pauses every thread ~10 ms
            try:
                master.sync.start(PERIOD, by_interface=by_interface)
            except InterfaceTimingError:
                return None
            trips = 0
            deadline = time.monotonic() + SECONDS
            while time.monotonic() < deadline:  # the master serves SDO traffic meanwhile
                device.set(0x2000, 0, trips & 0xFFFF)
                await sdo.upload(0x1000)
                trips += 1
            master.sync.stop()
            await asyncio.sleep(0.01)
            return trips

    trips = run(main())
    frames = observer.close()
    if trips is None:
        return None
    out = _stats(frames)
    out["sdo_trips"] = trips
    return out


def canopen_figures() -> dict[str, float]:
    args = _bus_args("cyc-co")
    observer = _Observer(args)
    net = canopen.Network()
    net.connect(**args)
    try:
        net.sync.start(PERIOD)
        time.sleep(SECONDS)
        net.sync.stop()
    finally:
        net.disconnect()
    return _stats(observer.close())


def _fire(fired: asyncio.Future[float], loop: asyncio.AbstractEventLoop) -> None:
    fired.set_result(loop.time())


def timer_lateness(loop_factory: Callable[[], asyncio.AbstractEventLoop]) -> tuple[float, float]:
    """Median and p99 lateness (µs) of 500 timers set 1.3 ms ahead on an idle loop."""

    async def main() -> list[float]:
        loop = asyncio.get_running_loop()
        late = []
        for _ in range(500):
            fired: asyncio.Future[float] = loop.create_future()
            due = loop.time() + 0.0013
            loop.call_at(due, _fire, fired, loop)
            late.append((await fired - due) * 1e6)
        return sorted(late)

    with asyncio.Runner(loop_factory=loop_factory) as runner:
        late = runner.run(main())
    return statistics.median(late), late[int(len(late) * 0.99)]


def _cell(figures: dict[str, float] | None, key: str) -> str:
    if figures is None or key not in figures:
        return f"{'-':>12}"
    return f"{figures[key]:>12,.0f}"


def main() -> None:
    cob = cobus_figures()
    cob_iface = cobus_figures(by_interface=True)
    co = canopen_figures()
    print(
        f"\nSYNC every {PERIOD * 1e3:g} ms for {SECONDS:g} s ({INTERFACE}, real time; cobus "
        "serves SDO meanwhile)"
    )
    print(f"  {'':<44} {'cobus':>12} {'by interface':>12} {'canopen':>12}")
    for key, label in (
        ("syncs", "SYNCs sent"),
        ("p99", "interval jitter p99 (us)"),
        ("max", "interval jitter max (us)"),
        ("missed", "SYNCs missed (> 1.5 periods)"),
        ("tpdo_median", "device SYNC -> TPDO median (us)"),
        ("tpdo_p99", "device SYNC -> TPDO p99 (us)"),
        ("sdo_trips", "SDO round trips served meanwhile"),
    ):
        print(f"  {label:<44} {_cell(cob, key)} {_cell(cob_iface, key)} {_cell(co, key)}")
    print("  (python-canopen's SYNC is python-can's send_periodic; it has no device)")
    if cob_iface is None:
        print(
            f"  ({INTERFACE} cannot time SYNC itself: COBUS_BENCH_CYCLIC_INTERFACE=socketcan "
            "and COBUS_BENCH_CYCLIC_CHANNEL=vcan0 have the kernel do it)"
        )
    ours = timer_lateness(RealTimeLoop)
    theirs = timer_lateness(asyncio.new_event_loop)
    print(f"  {'':<44} {'RealTimeLoop':>12} {'asyncio':>12}")
    for label, at in (("median", 0), ("p99", 1)):
        name = f"loop timer 1.3 ms ahead: late, {label} (us)"
        print(f"  {name:<44} {ours[at]:>12,.0f} {theirs[at]:>12,.0f}")


if __name__ == "__main__":
    main()
