"""CPU of a master listening to a busy bus (issue 20): 8,000 frames/s, in real time.

A generator thread sends, on python-can's ``virtual`` bus, what 64 nodes and a SYNC producer
put on a loaded network: each node's TPDO1 at 100 Hz (6,400 frames/s), its heartbeat at 10 Hz
(640/s), and SYNC at 1 kHz (1,000/s) — 8,040 frames/s, in 10 ms bursts.

The master under test supervises the 64 nodes: it decodes every TPDO1 (two 16-bit values)
and watches every heartbeat. cobus: a blocking ``Network`` with 64 remote nodes
(``watch_heartbeat``, a mapped ``tpdo[1]``). python-canopen: a ``Network`` with 64
``RemoteNode`` whose TPDO1 is mapped and subscribed (its NMT listens to heartbeats itself).
Each runs alone for the same time; the figure is the CPU its own threads used (reader, loop),
in percent of one core — not the generator's, which stands for the bus. Run longer with
COBUS_BENCH_LOAD_SECONDS.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable

import can
import canopen

from cobus.runtime import AsyncNetwork, Network

NODES = 64
SECONDS = float(os.environ.get("COBUS_BENCH_LOAD_SECONDS", "5"))
TICK = 0.01  # s between bursts


class _Generator:
    """8,040 frames/s from a thread of its own, in bursts every 10 ms."""

    def __init__(self, channel: str) -> None:
        self.bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
        self.sent = 0
        self._stop = threading.Event()
        self._tpdos = [
            can.Message(arbitration_id=0x180 + n, data=bytes([n, 0, 0, 1]), is_extended_id=False)
            for n in range(1, NODES + 1)
        ]
        self._heartbeats = [
            can.Message(arbitration_id=0x700 + n, data=b"\x05", is_extended_id=False)
            for n in range(1, NODES + 1)
        ]
        self._sync = can.Message(arbitration_id=0x80, data=b"", is_extended_id=False)
        self._thread = threading.Thread(target=self._run, name="generator", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def _run(self) -> None:
        send = self.bus.send
        tick = 0
        next_at = time.perf_counter()
        while not self._stop.is_set():
            burst = [*self._tpdos, *([self._sync] * 10)]
            if tick % 10 == 0:
                burst += self._heartbeats
            for msg in burst:
                send(msg)
            self.sent += len(burst)
            tick += 1
            next_at += TICK
            delay = next_at - time.perf_counter()
            if delay > 0:
                self._stop.wait(delay)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()
        self.bus.shutdown()


def _thread_cpu(names: Callable[[str], bool]) -> float:
    """CPU seconds used so far by this process's threads whose name ``names`` accepts."""
    by_id = {str(t.native_id): t.name for t in threading.enumerate()}
    ticks = 0
    for tid in os.listdir("/proc/self/task"):
        name = by_id.get(tid)
        if name is None or not names(name):
            continue
        try:
            with open(f"/proc/self/task/{tid}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
        except OSError:
            continue
        ticks += int(fields[11]) + int(fields[12])  # utime + stime
    return ticks / os.sysconf("SC_CLK_TCK")


def _measure(channel: str, names: Callable[[str], bool]) -> tuple[float, int]:
    """Percent of one core used by the named threads while the generator runs; frames sent."""
    gen = _Generator(channel)
    gen.start()
    time.sleep(0.5)  # settle
    c0, t0, s0 = _thread_cpu(names), time.perf_counter(), gen.sent
    time.sleep(SECONDS)
    c1, t1, s1 = _thread_cpu(names), time.perf_counter(), gen.sent
    gen.stop()
    return (c1 - c0) / (t1 - t0) * 100, int((s1 - s0) / (t1 - t0))


def cobus_figures() -> tuple[float, int, int]:
    """(percent of a core, frames/s offered, frames received) for a cobus master."""
    channel = f"load-cobus-{os.getpid()}"
    with Network(interface="virtual", channel=channel) as net:
        for n in range(1, NODES + 1):
            cobus_master_node(net, n)
        before = net.frames_received
        load, rate = _measure(channel, lambda name: name.startswith("cobus"))
        return load, rate, net.frames_received - before


def _canopen_od() -> canopen.ObjectDictionary:
    """Two mappable values and TPDO1's communication and mapping records."""
    od = canopen.ObjectDictionary()
    types = canopen.objectdictionary.datatypes

    def record(index: int, subs: list[tuple[int, int]]) -> None:
        rec = canopen.objectdictionary.ODRecord(f"{index:04X}", index)
        for sub, data_type in subs:
            var = canopen.objectdictionary.ODVariable(f"{index:04X}.{sub}", index, sub)
            var.data_type = data_type
            var.access_type = "rw"
            rec.add_member(var)
        od.add_object(rec)

    record(0x1800, [(0, types.UNSIGNED8), (1, types.UNSIGNED32), (2, types.UNSIGNED8)])
    record(0x1A00, [(0, types.UNSIGNED8)] + [(sub, types.UNSIGNED32) for sub in range(1, 9)])
    for index in (0x6041, 0x6061):
        var = canopen.objectdictionary.ODVariable(f"Value {index:04X}", index, 0)
        var.data_type = canopen.objectdictionary.datatypes.UNSIGNED16
        var.access_type = "ro"
        od.add_object(var)
    return od


def cobus_master_node(net: AsyncNetwork | Network, n: int) -> None:
    """What the cobus master knows of node ``n``: its heartbeat watched, TPDO1 decoded (on
    the loop for an ``AsyncNetwork``; the blocking ``Network`` runs each call there)."""
    node = net.add_remote(n)
    node.nmt.watch_heartbeat(0.3)
    tpdo = node.tpdo[1]
    tpdo.add(0x6041, 0, 16)
    tpdo.add(0x6061, 0, 16)
    tpdo.cob_id = 0x180 + n
    tpdo.enabled = True


def canopen_master_node(net: canopen.Network, n: int) -> None:
    """What python-canopen's master knows of node ``n``: TPDO1 mapped and subscribed (its NMT
    listens to heartbeats itself)."""
    node: canopen.RemoteNode = canopen.RemoteNode(n, _canopen_od())
    net.add_node(node)
    tpdo = node.tpdo[1]
    tpdo.clear()
    tpdo.add_variable(0x6041)
    tpdo.add_variable(0x6061)
    tpdo.cob_id = 0x180 + n
    tpdo.enabled = True
    tpdo.subscribe()


def canopen_figures() -> tuple[float, int]:
    """(percent of a core, frames/s offered) for python-canopen."""
    channel = f"load-canopen-{os.getpid()}"
    net = canopen.Network()
    net.connect(interface="virtual", channel=channel)
    try:
        for n in range(1, NODES + 1):
            canopen_master_node(net, n)
        load, rate = _measure(channel, lambda name: name.startswith("Notifier"))
        return load, rate
    finally:
        net.disconnect()


def main() -> None:
    cob, rate, received = cobus_figures()
    co, co_rate = canopen_figures()
    print(
        f"\nA master listening to {rate:,} frames/s of 64 nodes ({SECONDS:g} s; virtual bus, "
        "real time)"
    )
    print(f"  {'':<44} {'cobus':>12} {'canopen':>12}")
    print(f"  {'CPU of its threads (% of one core)':<44} {cob:>12.1f} {co:>12.1f}")
    print(f"  {'frames/s offered':<44} {rate:>12,} {co_rate:>12,}")
    print(f"  {'frames received by cobus (whole run)':<44} {received:>12,} {'-':>12}")
    print("  (target: under 25 % of one core; the generator's own CPU is not counted)")


if __name__ == "__main__":
    main()
