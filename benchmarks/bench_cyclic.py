"""Cyclic behaviour (issue 20): SYNC every 1 ms, its interval jitter, and a cobus device's
SYNC -> TPDO latency, beside python-canopen's SYNC (python-can's ``send_periodic``).

All in this process on python-can's ``virtual`` bus in real time. An observer (a plain
python-can bus in a thread of its own) records every frame with the time it was sent (the
virtual bus stamps frames when they are sent). For cobus, the producing network also serves
an SDO client against the device throughout, so a SYNC that goes missing under load shows.
"Missed": intervals longer than 1.5 periods. Run longer with COBUS_BENCH_CYCLIC_SECONDS.

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

import can
import canopen

from cobus.device import DictionaryBuilder, add_device
from cobus.od import DataType
from cobus.runtime import AsyncNetwork, RealTimeLoop, run

PERIOD = 0.001
SECONDS = float(os.environ.get("COBUS_BENCH_CYCLIC_SECONDS", "5"))
NODE = 5
SYNC, TPDO1 = 0x80, 0x180 + NODE


class _Observer:
    """Every frame on the channel with its send time, from a thread of its own."""

    def __init__(self, channel: str) -> None:
        self._bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
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


def cobus_figures() -> dict[str, float]:
    channel = f"cyc-cob-{os.getpid()}"
    observer = _Observer(channel)

    async def main() -> int:
        async with (
            AsyncNetwork(interface="virtual", channel=channel) as master,
            AsyncNetwork(interface="virtual", channel=channel) as field,
        ):
            b = DictionaryBuilder(device_name="cyclic")
            b.variable(0x2000, "Counter", DataType.UNSIGNED16, access="ro", mappable=True)
            b.tpdo(1, [(0x2000, 0)], transmission_type=1)  # every SYNC
            device = add_device(field, NODE, b.build())
            master.nmt.start(NODE)
            sdo = master.add_remote(NODE).sdo
            await asyncio.sleep(0.05)
            gc.freeze()  # set up: a full collection no longer pauses every thread ~10 ms
            master.sync.start(PERIOD)
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
    out = _stats(observer.close())
    out["sdo_trips"] = trips
    return out


def canopen_figures() -> dict[str, float]:
    channel = f"cyc-co-{os.getpid()}"
    observer = _Observer(channel)
    net = canopen.Network()
    net.connect(interface="virtual", channel=channel)
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


def main() -> None:
    cob = cobus_figures()
    co = canopen_figures()
    print(
        f"\nSYNC every {PERIOD * 1e3:g} ms for {SECONDS:g} s (virtual bus, real time; cobus "
        "serves SDO meanwhile)"
    )
    print(f"  {'':<44} {'cobus':>12} {'canopen':>12}")
    for key, label in (
        ("syncs", "SYNCs sent"),
        ("p99", "interval jitter p99 (us)"),
        ("max", "interval jitter max (us)"),
        ("missed", "SYNCs missed (> 1.5 periods)"),
    ):
        print(f"  {label:<44} {cob[key]:>12,.0f} {co[key]:>12,.0f}")
    print(
        f"  {'device SYNC -> TPDO median (us)':<44} {cob.get('tpdo_median', 0):>12,.0f} {'-':>12}"
    )
    print(f"  {'device SYNC -> TPDO p99 (us)':<44} {cob.get('tpdo_p99', 0):>12,.0f} {'-':>12}")
    print(f"  {'SDO round trips served meanwhile':<44} {cob['sdo_trips']:>12,.0f} {'-':>12}")
    print("  (python-canopen's SYNC is python-can's send_periodic thread; it has no device)")
    ours = timer_lateness(RealTimeLoop)
    theirs = timer_lateness(asyncio.new_event_loop)
    print(f"  {'':<44} {'RealTimeLoop':>12} {'asyncio':>12}")
    for label, at in (("median", 0), ("p99", 1)):
        name = f"loop timer 1.3 ms ahead: late, {label} (us)"
        print(f"  {name:<44} {ours[at]:>12,.0f} {theirs[at]:>12,.0f}")


if __name__ == "__main__":
    main()
