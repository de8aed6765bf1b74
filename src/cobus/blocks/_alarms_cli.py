"""cobus alarms: read an alarm history file (the SQLite file an AlarmHandler keeps).

    cobus alarms show alarms.db                       # the newest 50 activations, a table
    cobus alarms show alarms.db --node 10 --active    # what is still active on node 10
    cobus alarms show alarms.db --since 2026-11-24T08:00 --json
    cobus alarms export alarms.db week.csv --since 2026-11-17

Exit codes: 0 done, 1 the file cannot be used, 2 bad usage.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import sys
from pathlib import Path
from typing import Any

__all__ = ["register"]


def _moment(text: str) -> float:
    try:
        moment = dt.datetime.fromisoformat(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r}: a date and time as 2026-11-24 or 2026-11-24T08:30"
        ) from None
    return moment.timestamp()


def _code(text: str) -> int:
    try:
        return int(text, 0) if not text.lower().endswith("h") else int(text[:-1], 16)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: a code (17, 0x7121 or 7121h)") from None


def register(sub: Any) -> None:
    """Add ``cobus alarms ...`` to the top-level sub-command parser."""
    alarms: argparse.ArgumentParser = sub.add_parser(
        "alarms",
        help="read an alarm history file (show, export as CSV)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    actions = alarms.add_subparsers(dest="action", metavar="ACTION", required=True)
    for name, help_text in (
        ("show", "the activations as a table (newest first)"),
        ("export", "the activations as CSV, oldest first"),
    ):
        p = actions.add_parser(name, help=help_text, description=help_text)
        p.add_argument("history", type=Path, help="the history file (SQLite)")
        if name == "export":
            p.add_argument("csv", type=Path, help="the CSV file to write ('-': standard output)")
        p.add_argument("--node", type=int, help="only this node-ID")
        p.add_argument("--source", help="only this source (zapi, emcy, master, rule...)")
        p.add_argument("--code", type=_code, help="only this code")
        p.add_argument("--since", type=_moment, help="raised at or after (local time)")
        p.add_argument("--until", type=_moment, help="raised before (local time)")
        p.add_argument("--active", action="store_true", help="only those still active")
        if name == "show":
            p.add_argument("--limit", type=int, default=50, help="rows at most (default 50)")
            p.add_argument("--json", action="store_true", help="print JSON")
        p.set_defaults(handler=_run)


def _run(args: argparse.Namespace) -> int:
    from cobus.blocks.alarm_history import AlarmHistory, AlarmHistoryError

    if not args.history.is_file():
        print(f"cobus alarms: {args.history}: no such file", file=sys.stderr)
        return 1
    filters: dict[str, Any] = {
        "node": args.node,
        "source": args.source,
        "code": args.code,
        "since": args.since,
        "until": args.until,
        "active": True if args.active else None,
    }
    try:
        with AlarmHistory(args.history) as history:
            if args.action == "export":
                if str(args.csv) == "-":
                    count = history.export_csv(sys.stdout, **filters)
                else:
                    count = history.export_csv(args.csv, **filters)
                    print(f"{count} activations written to {args.csv}", file=sys.stderr)
                return 0
            records = history.query(limit=args.limit, **filters)
    except (AlarmHistoryError, OSError) as exc:
        print(f"cobus alarms: {exc}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps([vars(r) for r in records]))
        return 0
    from rich.markup import escape

    from cobus._console import print_table
    from cobus._console import table as new_table

    columns = ("raised", "cleared", "node", "source", "code", "text", "severity", "ack")
    table = new_table(*columns, title=f"{args.history}: {len(records)} activation(s)")

    def when(seconds: float | None) -> str:
        if seconds is None:
            return "[red]active[/]"
        return dt.datetime.fromtimestamp(seconds).strftime("%Y-%m-%d %H:%M:%S")

    for r in records:
        code = f"{r.code:04X}h" if r.source == "emcy" else str(r.code)
        table.add_row(
            when(r.raised_at),
            when(r.cleared_at),
            "" if r.node is None else str(r.node),
            escape(r.source),
            code,
            escape(r.text),
            r.severity,
            escape(r.acknowledged_by or ""),
        )
    print_table(table)
    return 0
