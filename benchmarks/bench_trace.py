"""The decoder's throughput, frames per second, beside python-can reading the same trace.

The traffic of a simulated session (a master booting the thesis servo: NMT, SDO transfers,
heartbeats, SYNC every 1 ms, TPDOs decoded by name from the servo's EDS) is repeated to
about 60,000 frames. A fully loaded 1 Mbit/s bus carries about 9,000 frames/s; the issue's
bar is ten times that. python-canopen has no decoder to compare with; python-can's own
reading of the same frames from a candump ``.log`` is the raw rate beside it.
"""

from __future__ import annotations

import asyncio
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import can

from cobus.device import export_eds
from cobus.od import ObjectDictionary, loads
from cobus.proto import Frame
from cobus.runtime import AsyncNetwork, SimulatedEventLoop
from cobus.sim.drive402 import SimulatedDrive402
from cobus.trace import Decoder

BUS_MAX = 9_000  # frames/s a fully loaded 1 Mbit/s bus carries
TARGET = 60_000


def _session() -> tuple[list[tuple[Frame, float]], ObjectDictionary]:
    async def run() -> tuple[list[tuple[Frame, float]], ObjectDictionary]:
        async with AsyncNetwork() as net:
            servo = SimulatedDrive402(net, 10)
            od = loads(export_eds(servo.od))
            od.node_id = 10
            frames: list[tuple[Frame, float]] = []
            net.subscribe_all(lambda f, now: frames.append((f, now)))
            servo.start()
            node = net.add_remote(10, od)
            await node.sdo.upload(0x1008, 0)
            await node.sdo.download(0x1017, 0, (10).to_bytes(2, "little"))
            net.nmt.send(0x01, 10)
            net.sync.start(0.001)
            await asyncio.sleep(1.0)
            net.sync.stop()
            return frames, od

    loop = SimulatedEventLoop()
    try:
        return loop.run_until_complete(run())
    finally:
        loop.close()


def main() -> None:
    session, od = _session()
    frames = []
    while len(frames) < TARGET:
        frames.extend(session)
    frames = frames[:TARGET]

    def decode() -> float:
        decoder = Decoder({10: od})
        t0 = time.perf_counter()
        for frame, now in frames:
            decoder.feed(frame, now)
        return time.perf_counter() - t0

    best = min(decode() for _ in range(3))
    rate = len(frames) / best
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "trace.log"
        with can.Logger(str(path)) as logger:
            for n, (f, _now) in enumerate(frames):
                msg = can.Message(
                    timestamp=n * 1e-4,
                    arbitration_id=f.cob_id,
                    data=f.data,
                    is_extended_id=False,
                    is_remote_frame=f.rtr,
                    dlc=f.dlc,
                )
                logger(msg)
        t0 = time.perf_counter()
        count = sum(1 for _ in can.LogReader(str(path)))
        raw = count / (time.perf_counter() - t0)
    bulk = _bulk(frames, od)
    probe = Decoder({10: od})
    kinds = sorted({r.kind for f, now in session for r in probe.feed(f, now)})
    print(f"\nDecoder: {len(frames):,} frames of a simulated session ({', '.join(kinds)})")
    print(f"  {'cobus decoder':<44} {rate:>12,.0f} frames/s  x{rate / BUS_MAX:5.1f} a full bus")
    print(f"  {'python-can reading a candump .log':<44} {raw:>12,.0f} frames/s")
    print(f"  {'target (10 x a full 1 Mbit/s bus)':<44} {10 * BUS_MAX:>12,.0f} frames/s")
    for line in bulk:
        print(line)


def _bulk(frames: list[tuple[Frame, float]], od: ObjectDictionary) -> list[str]:
    """Whole traces (issue 45): the session's frames repeated to ``BULK`` as .blf and candump
    .log files; python-can's reader alone, cobus's block reader, ``cobus decode --summary``
    in process (read, count, each frame's stuff bits, SDO/EMCY/NMT through the decoder, the
    result as JSON and as text; the command's start-up not counted); the batch decoder's
    records as columns, from blocks already read and read from the file; ``cobus decode``
    with ``--json`` and as text, the command end to end (its start-up counted)."""
    from cobus.trace.batch import BatchDecoder
    from cobus.trace.blocks import blocks
    from cobus.trace.summary import TraceSummary

    lines = [f"\nWhole traces: {BULK:,} frames of the same session, as files"]
    with tempfile.TemporaryDirectory() as tmp:
        for suffix in ("blf", "log"):
            path = Path(tmp) / f"bulk.{suffix}"
            with can.Logger(str(path)) as logger:
                n = 0
                while n < BULK:
                    for f, _now in frames:
                        logger(
                            can.Message(
                                timestamp=1.7e9 + n * 1e-4,
                                arbitration_id=f.cob_id,
                                data=f.data,
                                is_extended_id=False,
                                is_remote_frame=f.rtr,
                                dlc=f.dlc,
                            )
                        )
                        n += 1
                        if n == BULK:
                            break

            def rate(run: object) -> float:
                t0 = time.perf_counter()
                count = run()  # type: ignore[operator]
                return float(count) / (time.perf_counter() - t0)

            raw = rate(lambda p=path: sum(1 for _ in can.LogReader(str(p))))
            read = rate(lambda p=path: sum(len(b) for b in blocks(p)))

            def summarise(p: Path = path) -> int:
                summary = TraceSummary(dictionaries={10: od}).feed(blocks(p))
                json.dumps(summary.result())  # (what --summary --json prints)
                summary.lines()
                return summary.frames

            summed = rate(summarise)
            read_blocks = list(blocks(path))

            def batch(p: Path = path, read: bool = False, kept: list[Any] = read_blocks) -> int:
                decoder = BatchDecoder({10: od})
                count = 0
                for block in blocks(p) if read else kept:
                    decoder.decode(block, 1.7e9)
                    count += len(block)
                return count

            batched = rate(batch)
            read_batched = rate(lambda: batch(read=True))
            eds = Path(tmp) / "servo.eds"
            eds.write_text(export_eds(od))

            def command(options: tuple[str, ...], p: Path = path, e: Path = eds) -> int:
                decode = [sys.executable, "-m", "cobus", "decode", str(p), "--eds", f"10={e}"]
                subprocess.run([*decode, *options], stdout=subprocess.DEVNULL, check=True)
                return BULK

            as_json = rate(lambda c=command: c(("--json",)))
            as_text = rate(lambda c=command: c(()))
            lens = _lens(path) if suffix == "log" else None
            lines += [
                f"  {'python-can reading .' + suffix:<44} {raw:>12,.0f} frames/s",
                f"  {'cobus blocks of .' + suffix:<44} {read:>12,.0f} frames/s",
                f"  {'cobus decode --summary, .' + suffix:<44} {summed:>12,.0f} frames/s"
                "  (target 1,000,000)",
                f"  {'cobus batch decoding, blocks in memory':<44} {batched:>12,.0f} frames/s"
                "  (target 2,000,000)",
                f"  {'cobus batch decoding, read from .' + suffix:<44} {read_batched:>12,.0f}"
                " frames/s",
                f"  {'cobus decode --json, .' + suffix + ' (the command)':<44} {as_json:>12,.0f}"
                " frames/s  (target 200,000)",
                f"  {'cobus decode, text, .' + suffix + ' (the command)':<44} {as_text:>12,.0f}"
                " frames/s",
            ]
            if lens is not None:
                lines.append(
                    f"  {'canopen-lens opening the .log (C++ core)':<44} {lens:>12,.0f} frames/s"
                )
    return lines


BULK = 500_000


def _lens(path: Path) -> float | None:
    """canopen-lens (where installed: ``pip install canopen-lens``) reading and decoding
    the same candump .log; it reads no other format."""
    try:
        import canopen_lens
    except ImportError:
        return None
    t0 = time.perf_counter()
    canopen_lens.open_log(str(path))
    return BULK / (time.perf_counter() - t0)
