"""cobus plot: PDO signals over time from a trace file, to a PNG.

    cobus plot bench.asc --list --eds 10=servo.eds          # which signals the trace holds
    cobus plot bench.asc "Position actual value" --eds 10=servo.eds
    cobus plot bench.pcapng 10:Statusword 20:Digital_in --network line.yml -o run.png
    cobus plot bench.log 10:6064h:00 --from 2.5 --to 4     # (no EDS: objects by address)

A signal is a mapped object of a PDO, named as the decoder names it: the EDS name (with the
record's name in front for a sub-index), or its address ``6064h:00`` when the node's EDS is
not given but the mapping was seen on the bus (an SDO writing 1A00h...). Write ``NODE:NAME``
when several nodes have the name. Each signal gets its own panel, all on one time axis
(seconds from the trace's first frame), drawn as steps: a PDO holds its value until the next.

Needs matplotlib (``pip install 'cobus[plot]'``). Exit codes: 0 written (or listed), 1 the
trace or a signal cannot be used, 2 bad usage.
"""

from __future__ import annotations

import argparse
import difflib
import json
import math
import sys
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cobus._args import seconds_or_zero
from cobus.master.errors import SignalError  # (one name per idea: a signal not found)
from cobus.od import ObjectDictionary
from cobus.od._lookup import normalize_name
from cobus.proto import Frame
from cobus.trace.decoder import Decoder, PdoRecord

__all__ = ["Series", "SignalError", "collect", "pick", "plot", "register", "window"]


@dataclass
class Series:
    """One signal: the node, its name, and its samples (seconds from the trace's start)."""

    node: int | None
    name: str
    times: list[float] = field(default_factory=list)
    values: list[float] = field(default_factory=list)
    skipped: int = 0  # samples that were no number (a string, bytes)

    @property
    def label(self) -> str:
        """``NODE:NAME``, as a command line names the signal."""
        return f"{self.node}:{self.name}" if self.node is not None else self.name


def collect(
    frames: Iterable[tuple[float, Frame]],
    dictionaries: Mapping[int, ObjectDictionary] | None = None,
    network: Any = None,
    wanted: Sequence[str] | None = None,
) -> dict[tuple[int | None, str], Series]:
    """Every PDO value of ``frames`` (time, frame), by (node, name), as numbers; a
    ``network`` (a master's NetworkConfig) names and scales them as its signals. With
    ``wanted`` (signal names as :func:`pick` takes them) only those keep their samples;
    the others are listed without (a long trace, one signal asked for)."""
    decoder = Decoder(dictionaries, network=network)
    keys = None if wanted is None else [_key(text) for text in wanted]
    out: dict[tuple[int | None, str], Series] = {}
    keep: dict[tuple[int | None, str], bool] = {}
    for now, frame in frames:
        for rec in decoder.feed(frame, now):
            if not isinstance(rec, PdoRecord):
                continue
            for name, value in rec.values.items():
                series = out.get((rec.node, name))
                if series is None:
                    series = out[(rec.node, name)] = Series(rec.node, name)
                    keep[(rec.node, name)] = keys is None or any(
                        _matches(series, node, key) for node, key in keys
                    )
                if not keep[(rec.node, name)]:
                    continue
                number = _number(value)
                if number is None:
                    series.skipped += 1
                    continue
                series.times.append(now)
                series.values.append(number)
    return out


def _number(value: Any) -> float | None:
    if isinstance(value, bool):
        return float(value)
    if isinstance(value, int | float):
        number = float(value)
        return number if math.isfinite(number) else None
    return None


def _key(text: str) -> tuple[int | None, str]:
    """("NODE:NAME" or "NAME") -> (node or None, the name with case and separators ignored)."""
    node: int | None = None
    name = text
    head, sep, rest = text.partition(":")
    if sep and head.strip().isdigit():
        node, name = int(head), rest
    return node, normalize_name(name)


def _matches(s: Series, node: int | None, key: str) -> bool:
    return normalize_name(s.name) == key and (node is None or s.node == node)


def pick(found: Mapping[tuple[int | None, str], Series], wanted: Sequence[str]) -> list[Series]:
    """The series named by ``wanted`` ("NAME" or "NODE:NAME"; case, blanks, ``_`` and ``-``
    do not matter: ``position_actual_value`` finds "Position actual value")."""
    chosen: list[Series] = []
    for text in wanted:
        node, key = _key(text)
        hits = [s for s in found.values() if _matches(s, node, key)]
        if not hits:
            labels = sorted(s.label for s in found.values())
            close = difflib.get_close_matches(text, labels, n=3, cutoff=0.5)
            close += [
                label
                for label in labels
                if key in normalize_name(label) and label not in close and len(close) < 5
            ]
            hint = f"; did you mean {', '.join(close)}?" if close else ""
            if not labels:
                hint = (
                    "; the trace holds no PDO signal this decoder could name: give the "
                    "nodes' EDS (--eds NODE=FILE or --network FILE)"
                )
            raise SignalError(f"no signal {text!r} in the trace{hint}")
        if len(hits) > 1:
            raise SignalError(
                f"{text!r} is a signal of several nodes: write "
                + " or ".join(s.label for s in sorted(hits, key=lambda s: s.node or 0))
            )
        if not hits[0].values:
            raise SignalError(f"{hits[0].label} has no numeric samples (it is no number)")
        chosen.append(hits[0])
    return chosen


def window(s: Series, start: float | None = None, end: float | None = None) -> Series:
    """The part of ``s`` between ``start`` and ``end``: the samples inside, and the value
    held at ``start`` (the last sample before it) as a first point there."""
    times: list[float] = []
    values: list[float] = []
    before: float | None = None
    for t, v in zip(s.times, s.values, strict=True):
        if start is not None and t < start:
            before = v
            continue
        if end is not None and t > end:
            break
        times.append(t)
        values.append(v)
    if before is not None and start is not None and (not times or times[0] > start):
        times.insert(0, start)
        values.insert(0, before)
    return Series(s.node, s.name, times, values, s.skipped)


def plot(
    series: Sequence[Series],
    output: Path,
    title: str = "",
    start: float | None = None,
    end: float | None = None,
) -> Path:
    """Draw ``series`` (one panel each, shared time axis from ``start`` to ``end``) into
    ``output`` (PNG; another suffix matplotlib knows, e.g. .svg or .pdf, picks that format;
    none gets .png). A PDO holds its value until the next, so each value is drawn as a
    step to the next sample or to ``end``. Returns the file written; :class:`SignalError`
    when a signal has no value in the window."""
    try:
        from matplotlib.figure import Figure
    except ImportError:  # pragma: no cover - the plot extra is part of the dev install
        raise SignalError("cobus plot needs matplotlib: pip install 'cobus[plot]'") from None
    if not output.suffix:
        output = output.with_suffix(".png")
    shown = [window(s, start, end) for s in series]
    left = start if start is not None else min(s.times[0] for s in shown if s.times)
    right = end if end is not None else max((s.times[-1] for s in shown if s.times), default=left)
    for s in shown:
        if not s.times:
            raise SignalError(f"{s.label} has no value between {left:g} s and {right:g} s")
    fig = Figure(figsize=(10, 1.0 + 2.2 * len(shown)), layout="constrained")
    axes = fig.subplots(len(shown), 1, sharex=True, squeeze=False)[:, 0]
    for ax, s in zip(axes, shown, strict=True):
        line = ax.step([*s.times, right], [*s.values, s.values[-1]], where="post", linewidth=1.2)[0]
        ax.plot(s.times, s.values, ".", markersize=3, color=line.get_color())
        ax.set_ylabel(s.label, rotation=0, ha="right", va="center")
        ax.grid(True, alpha=0.3)
    axes[-1].set_xlabel("time (s from the trace's first frame)")
    if right > left:
        axes[-1].set_xlim(left, right)
    if title:
        fig.suptitle(title)
    fig.savefig(output, dpi=100)
    return output


# ---------------------------------------------------------------------------- command


def register(sub: Any) -> None:
    """Add ``cobus plot``."""
    from cobus.trace._cli import add_decoder_options

    p = sub.add_parser(
        "plot",
        help="PDO signals over time from a trace file, to a PNG (matplotlib)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("file", type=Path, help="a trace file (.asc .blf .log .trc .csv .pcap ...)")
    p.add_argument("signal", nargs="*", help="NAME or NODE:NAME of a PDO-mapped object")
    add_decoder_options(p)
    p.add_argument("-o", "--output", type=Path, help="the PNG (default: the trace's name .png)")
    p.add_argument("--from", dest="start", type=seconds_or_zero, help="first second shown")
    p.add_argument("--to", dest="end", type=seconds_or_zero, help="last second shown")
    p.add_argument("--list", action="store_true", help="list the signals the trace holds")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.set_defaults(handler=_run)


def _fail(message: str, code: int = 1) -> int:
    print(f"cobus plot: {message}", file=sys.stderr)
    return code


def frames_of(path: Path) -> Iterator[tuple[float, Frame]]:
    """The classic CAN frames of a trace file, with seconds from its first message."""
    from cobus.runtime.bus import message_to_frame
    from cobus.trace.files import open_trace

    reader = open_trace(path)
    first: float | None = None
    try:
        for msg in reader:
            stamp = float(msg.timestamp)
            first = stamp if first is None else first
            frame = message_to_frame(msg)
            if frame is not None:
                yield stamp - first, frame
    finally:
        stop = getattr(reader, "stop", None)
        if stop is not None:
            stop()


def _run(args: argparse.Namespace) -> int:
    from cobus.trace.monitor import _inputs

    if not args.list and not args.signal:
        return _fail("name the signals to plot, or --list the trace's signals", 2)
    if args.start is not None and args.end is not None and args.end <= args.start:
        return _fail(f"--to {args.end} is not after --from {args.start}", 2)
    try:
        dictionaries, network = _inputs(args)
    except Exception as exc:  # a network file or EDS that cannot be read
        return _fail(str(exc), 2)
    if not args.file.is_file():
        return _fail(f"{args.file}: no such file")
    try:
        wanted = None if args.list else args.signal
        found = collect(frames_of(args.file), dictionaries, network, wanted)
    except Exception as exc:  # python-can's readers raise their own kinds (BLF, zlib...)
        from cobus.trace._cli import _unreadable

        return _fail(_unreadable(args.file, exc))
    if args.list:
        return _list(found, args.json)
    try:
        chosen = pick(found, args.signal)
    except SignalError as exc:
        return _fail(str(exc))
    last = max((s.times[-1] for s in found.values() if s.times), default=0.0)
    if args.start is not None and args.start > last:
        return _fail(f"--from {args.start:g}: the trace's last PDO came at {last:g} s")
    end = args.end if args.end is not None else last  # a value holds to the trace's end
    output = args.output or args.file.with_suffix(".png")
    try:
        output = plot(chosen, output, title=args.file.name, start=args.start, end=end)
    except SignalError as exc:
        return _fail(str(exc))
    except (OSError, ValueError) as exc:
        return _fail(f"cannot write {output}: {exc}")
    if args.json:
        shown = [window(s, args.start, args.end) for s in chosen]
        print(json.dumps({"output": str(output), "signals": [_summary(s) for s in shown]}))
    else:
        print(f"{len(chosen)} signal(s) plotted to {output}", file=sys.stderr)
    return 0


def _summary(s: Series) -> dict[str, Any]:
    return {
        "node": s.node,
        "name": s.name,
        "samples": len(s.values),
        "min": min(s.values) if s.values else None,
        "max": max(s.values) if s.values else None,
        "first": s.times[0] if s.times else None,
        "last": s.times[-1] if s.times else None,
        "not_numbers": s.skipped,
    }


def _list(found: Mapping[tuple[int | None, str], Series], as_json: bool) -> int:
    ordered = sorted(found.values(), key=lambda s: (s.node or 0, s.name))
    if as_json:
        print(json.dumps([_summary(s) for s in ordered]))
        return 0
    from cobus._console import print_table
    from cobus._console import table as new_table

    table = new_table("node", "signal", "samples", "min", "max", title="PDO signals in the trace")
    for s in ordered:
        low = f"{min(s.values):g}" if s.values else "-"
        high = f"{max(s.values):g}" if s.values else "-"
        table.add_row(
            str(s.node if s.node is not None else "-"), s.name, str(len(s.values)), low, high
        )
    print_table(table)
    if not ordered:
        print(
            "no PDO signal could be named: give the nodes' EDS (--eds NODE=FILE, --network FILE)",
            file=sys.stderr,
        )
    return 0
