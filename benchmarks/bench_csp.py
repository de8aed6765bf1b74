"""Eight axes in cyclic synchronous position at a 1 ms SYNC, in real time on python-can's
virtual bus: CPU per cycle and cycles missed over ``COBUS_BENCH_CSP_SECONDS`` (10 s).

Each stack produces the SYNC itself and, on each SYNC it sees, sends every axis the next
point of a trapezoid by RPDO 3 (controlword + target position of the simulated servo's EDS):
cobus the per-cycle path of ``AsyncDrive402.follow()`` (the trajectory point, the set-point
in increments, the drive's RPDO through its port), python-canopen ``BaseNode402`` nodes whose
RPDO 3 is set and transmitted from a ``network.subscribe(0x80, ...)`` callback (its bus
echoes its own frames, as cobus's network does). No drive answers: what is measured is the
master's side. A cycle is missed when the set-points of a SYNC period did not go out (two
SYNC callbacks more than 1.5 periods apart count the periods between them).

What it showed when written (2 cores, another process busy): cobus about 280 µs of CPU per
cycle against python-canopen's 450, but about 5 % of the cycles missed against 0.5 %: cobus
produces SYNC from asyncio timers on its event loop, python-canopen from python-can's
periodic send thread. The producer's own count of skipped periods is printed beside it; a
steadier SYNC producer belongs to the real-time path (issue 20).
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

import canopen
from canopen.profiles.p402 import BaseNode402

from cobus.profiles import AsyncDrive402
from cobus.profiles.trajectory import Trapezoid
from cobus.runtime import Network

DURATION = float(os.environ.get("COBUS_BENCH_CSP_SECONDS", "10"))
PERIOD = 0.001
AXES = 8
EDS = str(Path(__file__).resolve().parent.parent / "examples" / "networks" / "servo.eds")
MOVE = Trapezoid(0, 200_000, velocity=100_000, acceleration=500_000)


class Cycles:
    """SYNC callbacks: how many, how many periods without one, the CPU time they took."""

    def __init__(self) -> None:
        self.count = 0
        self.missed = 0
        self.last: float | None = None
        self.first: float | None = None

    def tick(self) -> float:
        now = time.perf_counter()
        if self.last is not None and now - self.last > 1.5 * PERIOD:
            self.missed += round((now - self.last) / PERIOD) - 1
        if self.first is None:
            self.first = now
        self.last = now
        self.count += 1
        return now - self.first


def _figures(name: str, cycles: Cycles, cpu: float) -> str:
    per_cycle = cpu / cycles.count * 1e6 if cycles.count else float("nan")
    expected = round(DURATION / PERIOD)
    return (
        f"  {name:<16} {cycles.count:>8,} SYNC of {expected:,}   {per_cycle:>7.1f} µs CPU per "
        f"cycle (all threads)   {cycles.missed:>6,} cycles missed"
    )


def cobus_run() -> str:
    cycles = Cycles()
    with Network(interface="virtual", channel=f"bench-csp-cobus-{os.getpid()}") as net:
        drives: list[AsyncDrive402] = []
        for n in range(AXES):
            node = net.add_remote(10 + n, EDS)
            node.rpdo.load_from_od()
            drives.append(net._runner.call(lambda node=node: AsyncDrive402(node.aio)))

        def on_sync(frame: Any, now: float) -> None:
            t = cycles.tick() + PERIOD
            for drive in drives:  # what follow() does each cycle, for each axis
                target = drive._inc("set-point", MOVE.position(t % MOVE.duration))
                drive._port.send_cyclic({(0x607A, 0): target, (0x6040, 0): 0x0F})

        net._runner.call(lambda: net.aio.subscribe(0x80, on_sync))
        cpu = time.process_time()
        net.sync.start(PERIOD)
        time.sleep(DURATION)
        cpu = time.process_time() - cpu
        late = f"   (SYNC producer: {net.sync.skipped} periods skipped, worst delay "
        late += f"{net.sync.late_max * 1000:.1f} ms)"
        net.sync.stop()
    return _figures("cobus", cycles, cpu) + late


def canopen_run() -> str:
    cycles = Cycles()
    network = canopen.Network()
    network.connect(
        interface="virtual",
        channel=f"bench-csp-canopen-{os.getpid()}",
        receive_own_messages=True,
    )
    try:
        nodes = []
        for n in range(AXES):
            node = BaseNode402(10 + n, EDS)
            network.add_node(node)
            node.rpdo.read(from_od=True)
            nodes.append(node)

        def on_sync(cob_id: int, data: bytearray, timestamp: float) -> None:
            t = cycles.tick() + PERIOD
            for node in nodes:
                pdo = node.rpdo[3]
                pdo["Target position"].raw = round(MOVE.position(t % MOVE.duration))
                pdo["Controlword"].raw = 0x0F
                pdo.transmit()

        network.subscribe(0x80, on_sync)
        cpu = time.process_time()
        network.sync.start(PERIOD)
        time.sleep(DURATION)
        network.sync.stop()
        cpu = time.process_time() - cpu
    finally:
        network.disconnect()
    return _figures("python-canopen", cycles, cpu)


def main() -> None:
    print(f"\n{AXES} axes, cyclic synchronous position at a 1 ms SYNC, {DURATION:g} s")
    print(cobus_run())
    print(canopen_run())


if __name__ == "__main__":
    main()
