"""``cobus monitor --raw``: the bus by CAN identifier, as python-can's viewer shows it - how
many frames, how often, the last data - with what each identifier carries in CANopen terms.

On a terminal one line per identifier, updated in place (``p`` pauses, ``q`` quits); piped
or with ``--json``, the table (or a JSON list) once at the end.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import time
from dataclasses import dataclass
from typing import Any

__all__ = ["RawView", "run_raw"]


@dataclass
class IdStats:
    """What the bus showed of one identifier."""

    cob_id: int
    extended: bool
    count: int = 0
    first: float = 0.0
    last: float = 0.0
    last_gap: float | None = None
    dlc: int = 0
    data: bytes = b""
    rtr: bool = False
    what: str = ""

    @property
    def period(self) -> float | None:
        """The mean time between two frames (None before the second)."""
        return (self.last - self.first) / (self.count - 1) if self.count > 1 else None

    @property
    def label(self) -> str:
        return f"{self.cob_id:08X}" if self.extended else f"{self.cob_id:03X}"

    def to_dict(self) -> dict[str, Any]:
        period = self.period
        return {
            "id": f"0x{self.cob_id:X}",
            "extended": self.extended,
            "count": self.count,
            "period_ms": None if period is None else round(period * 1000, 3),
            "dlc": self.dlc,
            "data": None if self.rtr else self.data.hex(),
            "rtr": self.rtr,
            "what": self.what,
        }


_WORDS = {
    "nmt": "NMT",
    "sync": "SYNC",
    "time": "TIME",
    "emcy": "EMCY",
    "sdo": "SDO",
    "pdo": "PDO",
    "hb": "heartbeat",
    "lss": "LSS",
}
_RECORDS = {
    "NmtCommandRecord": "NMT",
    "Bootup": "boot-up",
    "Heartbeat": "heartbeat",
    "GuardRequest": "guarding request",
    "GuardResponse": "guarding",
    "SyncRecord": "SYNC",
    "TimeRecord": "TIME",
    "EmergencyRecord": "EMCY",
    "SdoTransfer": "SDO",
    "SdoBlockFrame": "SDO block",
    "LssFrame": "LSS",
    "LssSession": "LSS",
}


def _what(rec: Any) -> str:
    """What a record's identifier carries, in words: ``heartbeat node 10``, ``TPDO1 node 9``."""
    name = type(rec).__name__
    if name == "PdoRecord":
        word = f"{'TPDO' if rec.tpdo else 'RPDO'}{rec.number or ''}"
    else:
        word = _RECORDS.get(name, rec.kind)
    node = getattr(rec, "node", None)
    return word + (f" node {node}" if node else "")


class RawView:
    """Counts, periods and last data by identifier; ``what`` from the decoder's records."""

    def __init__(self) -> None:
        self.ids: dict[tuple[int, bool], IdStats] = {}

    def feed(self, frame: Any, stamp: float, records: list[Any]) -> None:
        key = (frame.cob_id, frame.extended)
        stats = self.ids.get(key)
        if stats is None:
            stats = self.ids[key] = IdStats(frame.cob_id, frame.extended, first=stamp)
        else:
            stats.last_gap = stamp - stats.last
        stats.count += 1
        stats.last = stamp
        stats.dlc, stats.data, stats.rtr = frame.dlc, frame.data, frame.rtr
        if records:
            stats.what = _what(records[-1])
        elif not stats.what:
            from cobus.trace.decoder import frame_kind

            kind = frame_kind(frame)
            node = frame.cob_id & 0x7F if kind in ("sdo", "pdo", "emcy", "hb") else 0
            stats.what = _WORDS.get(kind, kind) + (f" node {node}" if node else "")

    def rows(self) -> list[IdStats]:
        return [self.ids[k] for k in sorted(self.ids, key=lambda k: (k[1], k[0]))]

    def table(self, title: str) -> Any:
        from cobus._console import table as new_table

        table = new_table("id", "count", "period", "last gap", "dlc", "data", "what", title=title)
        for s in self.rows():
            period, gap = s.period, s.last_gap
            table.add_row(
                s.label,
                str(s.count),
                "" if period is None else f"{period * 1000:.1f} ms",
                "" if gap is None else f"{gap * 1000:.1f} ms",
                str(s.dlc),
                "remote" if s.rtr else s.data.hex(" ").upper(),
                s.what,
            )
        return table


def run_raw(args: argparse.Namespace, decoder: Any) -> int:
    """The raw view until ``--duration``, ``q`` or Ctrl-C (see the module's docstring)."""
    import sys

    from rich.live import Live

    from cobus._console import print_table
    from cobus.trace.monitor import BusReader, _frames, _Keys, _running

    view = RawView()
    live_view = sys.stdout.isatty() and not args.json
    deadline = None if args.duration is None else time.monotonic() + args.duration
    started = time.monotonic()
    first: float | None = None
    drawn = 0.0

    readers: list[BusReader] = []

    def dropped() -> int:
        return readers[0].dropped if readers else 0

    def title() -> str:
        frames = sum(s.count for s in view.ids.values())
        seconds = time.monotonic() - started
        lost = f", {dropped():,} dropped (counting fell behind)" if dropped() else ""
        return f"{len(view.ids)} identifier(s), {frames} frame(s) in {seconds:.1f} s{lost}"

    def say(text: str) -> None:
        print(f"# {text}", file=sys.stderr)

    display: Any = contextlib.nullcontext()
    if live_view:
        from rich.console import Console

        console = Console(highlight=False)
        display = Live(view.table(title()), console=console, auto_refresh=False)
    try:
        with _Keys() as keys, display as live:
            for item in _running(_frames(args, say, readers), keys, deadline):
                if item is not None:
                    frame, stamp = item
                    first = stamp if first is None else first
                    view.feed(frame, stamp, decoder.feed(frame, stamp - first))
                now = time.monotonic()
                if live is not None and not keys.paused and now - drawn >= 0.1:
                    drawn = now
                    live.update(view.table(title()), refresh=True)
    except ConnectionError as exc:
        print(f"cobus monitor: cannot open the bus: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        pass
    if args.json:
        print(json.dumps([s.to_dict() for s in view.rows()]))
    elif live_view:
        pass  # (the live table stays on the screen)
    else:
        print_table(view.table(title()))
    if dropped():
        print(
            f"cobus monitor: {dropped():,} frames dropped: the counts and periods miss them",
            file=sys.stderr,
        )
    return 0
