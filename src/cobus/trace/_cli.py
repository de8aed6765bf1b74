"""cobus decode / cobus record: CANopen trace files.

    cobus record bench.asc --duration 10 -i socketcan -c can0   # any format python-can writes
    cobus record bench.pcapng --duration 10                     # Wireshark opens it
    cobus decode bench.asc --eds 10=servo.eds                   # every record, in words
    cobus decode bench.log --filter sdo,emcy --node 10 --json
    cobus decode bench.blf --summary --bitrate 250000            # load, periods, latencies
    cobus decode bench.blf --eds 10=servo.eds --to parquet out/  # tables for pandas, DuckDB
    cobus replay bench.asc -i socketcan -c can0                   # back onto a bus, timed

Formats are python-can's, chosen by the file's suffix: candump .log, Vector .asc and .blf,
PCAN .trc, .csv (and what else the installed python-can reads/writes), and pcap/pcapng with
the SocketCAN link type, which Wireshark and tcpdump read and write (see cobus.trace.pcap; in
tshark: -d can.subdissector,canopen). Exit codes: 0 done, 1 the file or the bus cannot be used,
2 bad usage.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import signal
import sys
import time
from pathlib import Path
from typing import Any

from cobus._args import add_bus_options, bus_options, node_id, seconds

__all__ = ["register"]

_KINDS = ("nmt", "hb", "sync", "time", "emcy", "sdo", "pdo", "lss", "other")


def _eds(text: str) -> tuple[int, Path]:
    node, sep, path = text.partition("=")
    if not sep or not node.isdigit() or not 1 <= int(node) <= 127:
        raise argparse.ArgumentTypeError(f"{text!r}: write NODE=FILE, e.g. 10=servo.eds")
    return int(node), Path(path)


def _kinds(text: str) -> set[str]:
    kinds = {k.strip() for k in text.split(",") if k.strip()}
    unknown = kinds - set(_KINDS)
    if unknown:
        raise argparse.ArgumentTypeError(
            f"{', '.join(sorted(unknown))}: choose from {','.join(_KINDS)}"
        )
    return kinds


def add_decoder_options(parser: argparse.ArgumentParser) -> None:
    """``--eds NODE=FILE`` (repeatable) and ``--network FILE``: what the decoder names,
    types and scales by (decode, monitor and plot take the same)."""
    parser.add_argument(
        "--eds",
        type=_eds,
        action="append",
        default=[],
        metavar="NODE=FILE",
        help="a node's EDS/DCF: names, types, PDO mappings (repeatable)",
    )
    parser.add_argument(
        "--network", type=Path, help="a network description: its nodes' EDS and PDO signals"
    )


def register(sub: Any) -> None:
    """Add ``cobus decode`` and ``cobus record``."""
    decode = sub.add_parser(
        "decode",
        help="decode a trace file into CANopen records (NMT, SDO, PDO, EMCY...)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    decode.add_argument("file", type=Path, help="a trace file python-can reads")
    add_decoder_options(decode)
    decode.add_argument("--filter", type=_kinds, help=f"only these kinds ({','.join(_KINDS)})")
    decode.add_argument("--node", type=node_id, help="only records of this node-ID (1-127)")
    decode.add_argument("--json", action="store_true", help="one JSON object per line")
    decode.add_argument(
        "--summary",
        action="store_true",
        help="what the trace shows instead of its records: bus load, frames per COB-ID and "
        "node, heartbeat and SYNC periods and jitter, PDO age after SYNC, SDO latency and "
        "aborts, emergencies, NMT time line (--json: one object; the channels of a "
        "trace of several buses are counted as one)",
    )
    decode.add_argument(
        "--to",
        nargs=2,
        metavar=("FORMAT", "DIR"),
        help="write the records as tables into DIR instead: parquet (pyarrow) or csv, one "
        "file per kind of record and per PDO, its values as typed columns by name (pandas, "
        "polars, DuckDB read them); --filter and --node keep some, --json lists the files",
    )
    decode.add_argument(
        "--bitrate",
        type=_bitrate,
        default=500_000,
        metavar="BPS",
        help="the bus's bit rate, for --summary's bus load (500000)",
    )
    decode.add_argument(
        "--window",
        type=seconds,
        default=1.0,
        metavar="S",
        help="--summary's bus load per this many seconds (1)",
    )
    decode.add_argument(
        "--absolute",
        action="store_true",
        help="the date and time of day of each record (local time), not seconds from the "
        "trace's first frame",
    )
    decode.set_defaults(handler=_decode)
    record = sub.add_parser(
        "record",
        help="record the bus into a trace file (any format python-can writes)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    record.add_argument(
        "file", type=Path, help="the trace file (.asc, .blf, .log, .trc, .csv, .pcap, .pcapng)"
    )
    record.add_argument("--duration", type=seconds, help="seconds to record (default: Ctrl-C)")
    record.add_argument(
        "--force", action="store_true", help="overwrite FILE if it exists (a link is replaced)"
    )
    add_bus_options(record)
    record.set_defaults(handler=_record)
    replay = sub.add_parser(
        "replay",
        help="send a recording back onto a bus with its timing",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    replay.add_argument("file", type=Path, help="a trace file python-can reads")
    replay.add_argument(
        "--skip", type=seconds, default=60.0, help="longest pause kept, seconds (60)"
    )
    add_bus_options(replay)
    replay.set_defaults(handler=_replay)


def _fail(message: str, code: int = 1) -> int:
    print(f"cobus: {message}", file=sys.stderr)
    return code


def _unreadable(path: Path, exc: BaseException) -> str:
    """Why ``path`` cannot be read, naming it once (the pcap reader names it already)."""
    text = str(exc) or type(exc).__name__
    if not isinstance(exc, ValueError | OSError):
        text = f"{type(exc).__name__}: {text}"
    return text if text.startswith(path.name) else f"cannot read {path}: {text}"


def _plain(value: Any) -> Any:
    if isinstance(value, bytes):
        return value.hex(" ")
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, int | float | str | bool) or value is None:
        return value
    return str(value)


def _inputs_of(args: argparse.Namespace) -> tuple[Any, Any] | int:
    """The dictionaries and network ``--eds``/``--network`` give, or the exit code of what
    cannot be read (those, or the trace file)."""
    from cobus.trace.monitor import _inputs

    try:
        found = _inputs(args)
    except Exception as exc:  # a network file or EDS that cannot be read
        return _fail(str(exc), 2)
    if not args.file.is_file():
        return _fail(f"{args.file}: no such file")
    return found


def _bitrate(text: str) -> int:
    if not text.isdigit() or not 1_000 <= int(text) <= 8_000_000:
        raise argparse.ArgumentTypeError(f"{text!r}: a bit rate in bit/s, e.g. 250000")
    return int(text)


def _summary(args: argparse.Namespace) -> int:
    from cobus.trace.blocks import blocks
    from cobus.trace.summary import TraceSummary

    for given, name in ((args.filter, "--filter"), (args.node, "--node")):
        if given is not None:
            return _fail(f"{name} does not go with --summary (it sums up the whole trace)", 2)
    if args.absolute:
        return _fail("--absolute does not go with --summary (times count from the start)", 2)
    inputs = _inputs_of(args)
    if isinstance(inputs, int):
        return inputs
    dictionaries, network = inputs
    try:
        summary = TraceSummary(args.bitrate, args.window, dictionaries, network)
    except ValueError as exc:
        return _fail(f"--window: {exc}", 2)
    try:
        summary.feed(blocks(args.file))
    except BrokenPipeError:
        raise
    except Exception as exc:  # a damaged file, whatever the reader raises for it
        return _fail(_unreadable(args.file, exc))
    if args.json:
        print(json.dumps(summary.result()))
    else:
        print("\n".join(summary.lines()))
    return 0


def _export(args: argparse.Namespace) -> int:
    from cobus.trace.batch import BatchDecoder
    from cobus.trace.blocks import blocks
    from cobus.trace.export import ExportError, TraceExport

    fmt, folder = args.to[0].lower(), Path(args.to[1])
    for given, name in ((args.summary, "--summary"), (args.absolute, "--absolute")):
        if given:
            return _fail(f"{name} does not go with --to (tables count times from the start)", 2)
    inputs = _inputs_of(args)
    if isinstance(inputs, int):
        return inputs
    dictionaries, network = inputs
    try:
        export = TraceExport(
            folder,
            fmt,
            BatchDecoder(dictionaries, network),
            kinds=args.filter,
            node=args.node,
            source=str(args.file),
        )
    except ExportError as exc:
        return _fail(str(exc), 2)
    suffix = ".parquet" if fmt == "parquet" else ".csv"
    # Ctrl-C or SIGTERM: the tables end at the block under way, all of them, every file
    # finished (a Parquet file without its footer is unreadable)
    asked: list[int] = []
    previous: dict[int, Any] = {}
    for signum in (signal.SIGINT, getattr(signal, "SIGTERM", None)):
        if signum is None:
            continue
        try:
            previous[signum] = signal.signal(signum, lambda n, _: asked.append(n))
        except ValueError:  # (not the main thread: signals are not this thread's)
            break
    failure: str | None = None
    try:
        export.write(blocks(args.file), stop=lambda: bool(asked))
    except ExportError as exc:
        failure = str(exc)
    except KeyboardInterrupt:
        asked.append(signal.SIGINT)
        export.stopped = True
    except Exception as exc:  # a damaged file, whatever the reader raises for it
        failure = _unreadable(args.file, exc)
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
    files = {name: str(folder / f"{name}{suffix}") for name in export.rows}
    if args.json:
        print(json.dumps({n: {"file": files[n], "rows": r} for n, r in export.rows.items()}))
    else:
        for name, rows in export.rows.items():
            print(f"{files[name]}  {rows} rows")
    left = [
        f"{count} {what}"
        for count, what in (
            (export.error_frames, "error frames"),
            (export.fd_frames, "CAN FD or longer frames (no CANopen)"),
        )
        if count
    ]
    if left:
        print(f"# not in the tables: {', '.join(left)}", file=sys.stderr)
    upto = f"{export.frames} frames, to {export.end:.6f} s"
    tables = (
        f"{len(files)} table written holds"
        if len(files) == 1
        else f"{len(files)} tables written hold"
    )
    if failure is not None:
        if export.rows:
            failure += f" (the {tables} the trace's first {upto})"
        return _fail(failure)
    if export.stopped:
        if asked and asked[0] != signal.SIGINT:
            return _fail(f"terminated: the {tables} the trace's first {upto}", 143)
        return _fail(f"interrupted: the {tables} the trace's first {upto}", 130)
    if not export.rows:
        print(f"cobus: {args.file}: no records to write", file=sys.stderr)
    return 0


def _decode(args: argparse.Namespace) -> int:
    if args.to is not None:
        return _export(args)
    if args.summary:
        return _summary(args)

    from cobus.trace._lines import block_lines
    from cobus.trace.batch import BatchDecoder
    from cobus.trace.blocks import blocks

    inputs = _inputs_of(args)
    if isinstance(inputs, int):
        return inputs
    dictionaries, network = inputs
    batch = BatchDecoder(dictionaries, network)
    first: float | None = None
    now = 0.0
    absolute = args.absolute
    options: dict[str, Any] = {}
    if absolute and args.file.suffix.lower() == ".asc":
        options["relative_timestamp"] = False  # (the date of its header, not 0)

    def stamp(seconds: float, *, zone: bool = False) -> str:
        """Seconds from the first frame; with --absolute the local date and time (and, for
        JSON, its offset from UTC)."""
        if not absolute:
            return f"{seconds:12.6f}"
        moment = dt.datetime.fromtimestamp((first or 0.0) + seconds)
        if zone:
            moment = moment.astimezone()
        return moment.isoformat(sep=" ", timespec="microseconds")

    def line(rec: Any) -> str | None:
        if args.filter is not None and rec.kind not in args.filter:
            return None
        if args.node is not None and not rec.concerns(args.node):
            return None
        if args.json:
            body = {k: _plain(v) for k, v in vars(rec).items()}
            if absolute:
                body["datetime"] = stamp(rec.time, zone=True)
            return json.dumps({"kind": rec.kind, "text": str(rec), **body})
        return f"{stamp(rec.time)}  {rec}"

    out = sys.stdout
    error_frames = args.filter is None and args.node is None and not args.json
    try:
        for block in blocks(args.file, **options):
            if not len(block):
                continue
            if first is None:
                first = float(block.time[0])
                if absolute and first < _YEAR_2000:
                    absolute = False
                    print(
                        f"# {args.file}: its times count from its start and carry no date: "
                        "shown in seconds",
                        file=sys.stderr,
                    )
            now = float(block.time[-1])
            decoded = batch.decode(block, first)
            for skipped in decoded.time[decoded.skipped].tolist():  # CAN FD: CiA 301 has none
                print(f"# {skipped:.6f}: frame skipped: not a classic CAN frame", file=sys.stderr)
            lines = block_lines(
                decoded,
                line,
                as_json=args.json,
                kinds=args.filter,
                node=args.node,
                error_frames=error_frames,
                stamp=stamp if absolute else None,
            )
            if lines:
                out.write("\n".join(lines) + "\n")
        for rec in batch.flush(0.0 if first is None else now - first):
            text = line(rec)  # transfers the trace ended in
            if text is not None:
                out.write(text + "\n")
    except BrokenPipeError:
        raise
    except Exception as exc:  # a damaged file, whatever the reader raises for it
        return _fail(_unreadable(args.file, exc))
    return 0


_YEAR_2000 = 946_684_800.0  # (a trace's first time below it is no date: seconds from its start)


def _record(args: argparse.Namespace) -> int:
    import can

    from cobus._files import refusal
    from cobus.runtime.bus import open_bus

    refused = refusal(args.file, args.force)
    if refused is not None:
        return _fail(refused, 2)
    try:
        bus = open_bus(**{k: v for k, v in bus_options(args).items() if v is not None})
    except Exception as exc:  # (BusOpenError, an interface's own)
        return _fail(f"cannot open the bus: {exc}")
    try:
        if args.file.is_symlink():  # (--force: the link goes, what it points to is not written)
            args.file.unlink()
        logger = can.Logger(str(args.file))
    except (ValueError, OSError, ImportError) as exc:
        bus.shutdown()
        return _fail(f"cannot write {args.file}: {exc}", 2)
    count = 0
    deadline = None if args.duration is None else time.monotonic() + args.duration
    try:
        while deadline is None or time.monotonic() < deadline:
            wait = 0.1 if deadline is None else max(0.0, min(0.1, deadline - time.monotonic()))
            msg = bus.recv(wait)
            if msg is not None:
                logger(msg)
                count += 1
    except KeyboardInterrupt:
        pass
    finally:
        logger.stop()
        bus.shutdown()
    print(f"{count} frames written to {args.file}", file=sys.stderr)
    return 0


def _replay(args: argparse.Namespace) -> int:
    import can

    if not args.file.is_file():
        return _fail(f"{args.file}: no such file")
    try:
        from cobus.trace.files import open_trace

        reader = open_trace(args.file)
    except Exception as exc:  # python-can's readers raise their own kinds (BLF, zlib...)
        return _fail(_unreadable(args.file, exc))
    from cobus.runtime.bus import open_bus

    try:
        bus = open_bus(**{k: v for k, v in bus_options(args).items() if v is not None})
    except Exception as exc:  # (BusOpenError, an interface's own)
        return _fail(f"cannot open the bus: {exc}")
    sent = skipped = 0
    try:
        for msg in can.MessageSync(reader, timestamps=True, skip=args.skip):
            if msg.is_error_frame:
                skipped += 1
                continue
            try:
                bus.send(msg)
                sent += 1
            except can.CanError as exc:
                skipped += 1
                print(f"# frame {msg.arbitration_id:03X} not sent: {exc}", file=sys.stderr)
    except KeyboardInterrupt:
        pass
    except Exception as exc:  # a damaged file, whatever the reader raises for it
        return _fail(_unreadable(args.file, exc))
    finally:
        bus.shutdown()
        stop = getattr(reader, "stop", None)
        if stop is not None:
            stop()
    print(f"{sent} frames sent" + (f", {skipped} skipped" if skipped else ""), file=sys.stderr)
    return 0
