"""``cobus monitor`` soaked with a full bus: does it keep up, does memory stay flat, and are
the frames it cannot decode in time counted (issue 45)?

A sender paces a CANopen mix (SYNC, a TPDO per node and SYNC, heartbeats of ten nodes) onto
python-can's virtual bus at a full 1 Mbit/s bus's ≈8,000 frames/s, then at four times
that; the monitor (``--json``, its records counted instead of printed) decodes what it can.
Printed: frames offered, decoded, dropped, and the process's memory at the start, its peak
and at the end. python-canopen has no monitor to compare with; ``candump``-like reading
alone is python-can's (bench_trace). ``COBUS_SOAK_SECONDS`` (10) sets each run's length.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import threading
import time
import uuid

import can

from cobus.cli import main as cobus

FULL_BUS = 8_000  # frames/s of a fully loaded 1 Mbit/s bus (about 8 bytes a frame)


def _rss_kb() -> int:
    with open("/proc/self/status") as status:
        for line in status:
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    return 0


class _Lines(io.TextIOBase):
    """stdout that counts lines and keeps the last."""

    def __init__(self) -> None:
        self.count = 0
        self.last = ""

    def write(self, text: str) -> int:
        self.count += text.count("\n")
        stripped = text.strip()
        if stripped:
            self.last = stripped.splitlines()[-1]
        return len(text)


def _mix() -> list[can.Message]:
    """100 ms of a ten-node bus: SYNC every ms with a TPDO of each node, heartbeats."""
    out = []
    for ms in range(100):
        out.append(can.Message(arbitration_id=0x080, data=[ms & 0xFF], is_extended_id=False))
        for node in range(1, 11):
            data = (ms * node).to_bytes(4, "little") + bytes([0x37, 0x06, 0, 0])
            out.append(can.Message(arbitration_id=0x180 + node, data=data, is_extended_id=False))
        if ms % 10 == 0:
            for node in range(1, 11):
                out.append(can.Message(arbitration_id=0x700 + node, data=[5], is_extended_id=False))
    return out


def soak(rate: int, seconds: float) -> dict[str, float]:
    channel = f"soak-{uuid.uuid4()}"
    lines = _Lines()
    result: list[int] = []
    command = ["monitor", "-i", "virtual", "-c", channel, "--duration", str(seconds + 1.5)]
    rss = [_rss_kb()]

    def run() -> None:
        with contextlib.redirect_stdout(lines), contextlib.redirect_stderr(io.StringIO()):
            result.append(cobus([*command, "--json"]))

    monitor = threading.Thread(target=run)
    monitor.start()
    time.sleep(0.5)  # (the monitor opens its bus)
    mix = _mix()
    sent = 0
    with can.Bus(interface="virtual", channel=channel) as bus:
        start = time.monotonic()
        tick = 0.01
        while (now := time.monotonic()) - start < seconds:
            due = int((now - start + tick) * rate)
            while sent < due:
                bus.send(mix[sent % len(mix)])
                sent += 1
            if int((now - start) * 2) > len(rss) - 1:
                rss.append(_rss_kb())
            time.sleep(max(0.0, start + (sent / rate) - time.monotonic()))
        took = time.monotonic() - start
    monitor.join()
    rss.append(_rss_kb())
    dropped = json.loads(lines.last).get("dropped", 0) if lines.last.startswith("{") else -1
    return {
        "offered": sent / took,
        "sent": sent,
        "decoded": lines.count - 1,  # (the last line: the node table)
        "dropped": dropped,
        "rss_start": rss[0] / 1024,
        "rss_peak": max(rss) / 1024,
        "rss_end": rss[-1] / 1024,
    }


def main() -> None:
    seconds = float(os.environ.get("COBUS_SOAK_SECONDS", "10"))
    print(f"\nMonitor soak: {seconds:g} s a run on python-can's virtual bus")
    print(f"  {'offered':>14} {'sent':>9} {'decoded':>9} {'dropped':>9}   memory MB start/peak/end")
    for rate in (FULL_BUS, 4 * FULL_BUS):
        r = soak(rate, seconds)
        print(
            f"  {r['offered']:>9,.0f} fr/s {r['sent']:>9,} {r['decoded']:>9,} "
            f"{r['dropped']:>9,}   {r['rss_start']:.0f} / {r['rss_peak']:.0f} / {r['rss_end']:.0f}"
        )


if __name__ == "__main__":
    main()
