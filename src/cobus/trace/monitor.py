"""cobus monitor: the live bus, decoded, with a table of its nodes.

    cobus monitor -i socketcan -c can0 -b 500000 --eds 10=servo.eds
    cobus monitor --network line.yml --filter sdo,emcy        # EDS files from the network file
    cobus monitor -i remote -c ws://127.0.0.1:54701/          # beside `cobus sim thesis`

``--raw``: the bus by CAN identifier instead, as python-can's viewer shows it (count,
period, last data), with what each identifier carries (heartbeat node 10, pdo node 9...).

On a terminal: the node table (NMT state, heartbeats with period, jitter and missed beats,
emergencies and the last one, SDO answer latency), frames/s and bus load, and the newest
decoded records; ``p`` or space pauses the display (decoding goes on), ``q`` quits. Piped or
with ``--json``: one line per record, and the node table at the end. A bus error is said and
the bus opened again (until it opens); ``--duration S`` stops by itself. When decoding
cannot keep up with the bus, frames are dropped and counted (in the node table's title,
the JSON's last line and at the end) instead of queueing without end. python-can's
``virtual`` bus is private to one process: to watch a bench run by another process, share
it (``python -m can_remote -i virtual -c bench -H 127.0.0.1`` and ``-i remote -c
ws://127.0.0.1:54701/``) or use ``-i udp_multicast``. Exit codes: 0 done, 1 the bus cannot
be opened, 2 bad usage.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import queue
import sys
import threading
import time
from collections import deque
from collections.abc import Iterator
from typing import Any

from cobus._args import add_bus_options, bus_options, node_id, seconds

__all__ = ["register"]

_REOPEN = 1.0  # seconds before a failed bus is opened again


def register(sub: Any) -> None:
    """Add ``cobus monitor``."""
    from cobus.trace._cli import _kinds, add_decoder_options

    p = sub.add_parser(
        "monitor",
        help="the live bus decoded, with a node table and the bus load",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_decoder_options(p)
    p.add_argument("--filter", type=_kinds, help="only these kinds (nmt,hb,sync,sdo,pdo,...)")
    p.add_argument("--node", type=node_id, help="only records of this node-ID (1-127)")
    p.add_argument("--duration", type=seconds, help="seconds to run (default: until q/Ctrl-C)")
    p.add_argument("--json", action="store_true", help="one JSON object per record")
    p.add_argument(
        "--raw",
        action="store_true",
        help="the bus by CAN identifier: count, period, last data, and what it carries",
    )
    add_bus_options(p)
    p.set_defaults(handler=_run)


def _fail(message: str, code: int = 1) -> int:
    print(f"cobus monitor: {message}", file=sys.stderr)
    return code


def _inputs(args: argparse.Namespace) -> tuple[dict[int, Any], Any]:
    """The dictionaries of ``--eds NODE=FILE`` and the network of ``--network FILE`` (its
    nodes' EDS, and its PDO signals with their names, scales and units)."""
    from cobus._args import load_eds
    from cobus.od import EdsError

    network = None
    if getattr(args, "network", None) is not None:
        from cobus.master import load_network

        network = load_network(args.network)
    out: dict[int, Any] = {}
    for node, path in args.eds:
        try:
            out[node] = load_eds(path, args.command, node_id=node)
        except (OSError, EdsError) as exc:
            raise ValueError(str(exc)) from None
    return out, network


class _Keys:
    """Single key presses on a terminal (p/space: pause, q: quit); nothing elsewhere."""

    def __init__(self) -> None:
        self._saved: Any = None
        self.paused = False
        self.quit = False

    def __enter__(self) -> _Keys:
        if sys.stdin.isatty():
            with contextlib.suppress(ImportError, OSError):
                import termios
                import tty

                self._saved = termios.tcgetattr(sys.stdin)
                tty.setcbreak(sys.stdin.fileno())
        return self

    def poll(self) -> None:
        if self._saved is None:
            return
        import select

        while select.select([sys.stdin], [], [], 0)[0]:
            key = sys.stdin.read(1)
            if key in ("p", " "):
                self.paused = not self.paused
            elif key in ("q", "Q"):
                self.quit = True

    def __exit__(self, *exc: object) -> None:
        if self._saved is not None:
            import termios

            termios.tcsetattr(sys.stdin, termios.TCSADRAIN, self._saved)


def _running(
    items: Iterator[tuple[Any, float] | None], keys: _Keys, deadline: float | None
) -> Iterator[tuple[Any, float] | None]:
    """``items`` (of :func:`_frames`) until q is pressed or the deadline passes; the keys
    are read before each (the decoded and the raw view share this loop)."""
    for item in items:
        keys.poll()
        if keys.quit or (deadline is not None and time.monotonic() >= deadline):
            return
        yield item


class BusReader:
    """Reads a bus in a thread of its own into a queue of at most ``room`` frames: when
    decoding falls behind (a full bus, a slow terminal), the frames that do not fit are
    dropped and counted (:attr:`dropped`) instead of piling up in memory. A bus that fails
    is said (``say``, from the reading thread) and opened again every second.

    >>> with BusReader(dict(interface="virtual", channel="bench"), print) as reader:
    ...     for item in reader.items():     # (frame, time), or None each 0.1 s without
    ...         ...
    """

    def __init__(self, options: dict[str, Any], say: Any, room: int = 10_000) -> None:
        self.options = options
        self.say = say
        #: Frames read from the bus, and those dropped for want of room.
        self.received = 0
        self.dropped = 0
        #: Error frames seen (said at most once a second).
        self.error_frames = 0
        self._errors_said = 0
        self._errors_said_at = -1e9
        self._queue: queue.Queue[tuple[Any, float]] = queue.Queue(maxsize=room)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._bus: Any = None

    def __enter__(self) -> BusReader:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def open(self) -> None:
        """Open the bus (``ConnectionError`` when it cannot be) and start reading."""
        self._bus = self._open()
        self._thread = threading.Thread(target=self._read, name="cobus-monitor-bus", daemon=True)
        self._thread.start()

    def _open(self) -> Any:
        """The bus (:func:`cobus.runtime.bus.open_bus`: udp_multicast without a group stays
        on this host); ``ConnectionError`` when it cannot be opened."""
        from cobus.runtime.bus import open_bus
        from cobus.runtime.errors import BusOpenError

        try:
            return open_bus(**self.options)
        except (BusOpenError, OSError, ValueError, ImportError) as exc:
            raise ConnectionError(str(exc)) from None

    def close(self) -> None:
        """Stop reading and close the bus. Frames read but not taken yet count as dropped
        (they were never decoded)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        self.dropped += self._queue.qsize()
        self._queue = queue.Queue()
        if self.error_frames > self._errors_said:
            self._say_errors()
        if self._bus is not None:
            with contextlib.suppress(Exception):
                self._bus.shutdown()
            self._bus = None

    def _say_errors(self) -> None:
        count = self.error_frames - self._errors_said
        self._errors_said, self._errors_said_at = self.error_frames, time.monotonic()
        self.say("error frame on the bus" if count == 1 else f"{count} error frames on the bus")

    def items(self) -> Iterator[tuple[Any, float] | None]:
        """The frames read, with their time; None about every 0.1 s without one."""
        get = self._queue.get
        while True:
            try:
                yield get(timeout=0.1)
            except queue.Empty:
                yield None

    def _read(self) -> None:
        import can

        from cobus.runtime.bus import message_to_frame

        put = self._queue.put_nowait
        while not self._stop.is_set():
            bus = self._bus
            if bus is None:
                try:
                    bus = self._bus = self._open()
                except ConnectionError as exc:
                    self.say(f"the bus cannot be opened again: {exc}; next try in {_REOPEN:g} s")
                    self._stop.wait(_REOPEN)
                    continue
            try:
                msg = bus.recv(0.1)
            except (can.CanError, OSError) as exc:
                self.say(f"bus error: {exc}; opening the bus again in {_REOPEN:g} s")
                with contextlib.suppress(Exception):
                    bus.shutdown()
                self._bus = None
                self._stop.wait(_REOPEN)
                continue
            if msg is None:
                continue
            self.received += 1
            if msg.is_error_frame:  # (a storm: a line a second, not a line a frame)
                self.error_frames += 1
                if time.monotonic() - self._errors_said_at >= 1.0:
                    self._say_errors()
                continue
            frame = message_to_frame(msg)
            if frame is None:  # a CAN FD frame: CANopen (CiA 301) has none
                self.say(f"frame {msg.arbitration_id:03X} skipped: not a classic CAN frame")
                continue
            try:
                put((frame, float(msg.timestamp or time.time())))
            except queue.Full:
                self.dropped += 1


def _frames(
    args: argparse.Namespace, say: Any, reader: list[BusReader] | None = None
) -> Iterator[tuple[Any, float] | None]:
    """Frames from the bus with their time (None about every 0.1 s without one), read by
    a :class:`BusReader` (given back in ``reader``, for its counts)."""
    options = {k: v for k, v in bus_options(args).items() if v is not None}
    bus = BusReader(options, say)
    if reader is not None:
        reader.append(bus)
    with bus:
        yield from bus.items()


def _table(decoder: Any, rate: float, load: float | None, dropped: int = 0) -> Any:
    from cobus._console import table as new_table

    shown = f"{rate:,.0f} frames/s" + ("" if load is None else f", bus load {load:.1f} %")
    if dropped:
        shown += f", {dropped:,} dropped (decoding fell behind)"
    table = new_table(title=f"nodes — {shown}")
    columns = (
        "node",
        "state",
        "drive",
        "beats",
        "period",
        "jitter",
        "missed",
        "toggle",
        "EMCY",
        "last error",
    )
    for column in (*columns, "SDO latency"):
        table.add_column(column)
    for node in sorted(decoder.stats):
        s = decoder.stats[node]
        period, jitter, latency = s.heartbeat_period, s.jitter, s.sdo_latency
        table.add_row(
            str(node),
            s.state or "",
            s.drive_state or "",
            str(s.heartbeats),
            "" if period is None else f"{period * 1000:.0f} ms",
            "" if jitter is None else f"{jitter * 1000:.1f} ms",
            str(s.missed_beats),
            str(s.toggle_errors),
            str(s.emcy_count),
            s.last_emcy or "",
            "" if latency is None else f"{latency[1] * 1000:.1f} ms",
        )
    return table


def _run(args: argparse.Namespace) -> int:
    from rich.console import Console, Group
    from rich.live import Live
    from rich.markup import escape
    from rich.text import Text

    from cobus.proto.frame import frame_bits
    from cobus.trace.decoder import Decoder

    try:
        dictionaries, network = _inputs(args)
        decoder = Decoder(dictionaries, network=network)
    except Exception as exc:  # a network file or EDS that cannot be read
        return _fail(str(exc), 2)
    if args.raw:
        if args.filter is not None or args.node is not None:
            return _fail("--raw shows every identifier: --filter and --node do not apply", 2)
        from cobus.trace._raw import run_raw

        return run_raw(args, decoder)
    live_view = sys.stdout.isatty() and not args.json
    console = Console(highlight=False)  # (the live view's: on a terminal)
    newest: deque[str] = deque(maxlen=500)
    window: deque[tuple[float, int]] = deque()  # (time, bits) of the last second
    first: float | None = None
    deadline = None if args.duration is None else time.monotonic() + args.duration

    def say(text: str) -> None:
        if live_view:
            newest.append(f"[yellow]{escape(text)}[/]")
        else:
            print(f"# {text}", file=sys.stderr)

    def figures() -> tuple[float, float | None]:
        now = time.monotonic()
        while window and window[0][0] < now - 1.0:
            window.popleft()
        bits = sum(b for _, b in window)
        load = 100.0 * bits / args.bitrate if args.bitrate else None
        return float(len(window)), load

    readers: list[BusReader] = []

    def dropped() -> int:
        return readers[0].dropped if readers else 0

    def view() -> Any:
        rate, load = figures()
        table = _table(decoder, rate, load, dropped())
        # The records that fit below the node table as the terminal draws it (rows wrap).
        height = len(console.render_lines(table, console.options, pad=False))
        room = max(3, console.size.height - height - 1)
        shown = list(newest)[-room:]
        lines = Text.from_markup("\n".join(shown) or "(nothing decoded yet)", overflow="crop")
        lines.no_wrap = True
        return Group(table, lines)

    drawn = [0.0]

    def redraw(live: Any, force: bool = False) -> None:
        """At most 10 pictures a second: a loaded bus brings thousands of frames."""
        now = time.monotonic()
        if live is not None and (force or now - drawn[0] >= 0.1):
            drawn[0] = now
            live.update(view(), refresh=True)

    display: Any = (
        Live(view(), console=console, auto_refresh=False) if live_view else contextlib.nullcontext()
    )
    try:
        with _Keys() as keys, display as live:
            for item in _running(_frames(args, say, readers), keys, deadline):
                if item is None:
                    if not keys.paused:
                        redraw(live)
                    continue
                frame, stamp = item
                first = stamp if first is None else first
                arrived = time.monotonic()
                window.append((arrived, frame_bits(frame)))
                while window[0][0] < arrived - 1.0:  # (the last second only: memory stays)
                    window.popleft()
                for rec in decoder.feed(frame, stamp - first):
                    if args.filter is not None and rec.kind not in args.filter:
                        continue
                    if args.node is not None and not rec.concerns(args.node):
                        continue
                    if args.json:
                        print(json.dumps({"time": rec.time, "kind": rec.kind, "text": str(rec)}))
                    elif live_view:
                        newest.append(f"{rec.time:10.3f}  {escape(str(rec))}")
                    else:
                        print(f"{rec.time:12.6f}  {rec}", flush=True)
                if not keys.paused:
                    redraw(live)
            if not keys.paused:
                redraw(live, force=True)  # the last records before the view is left
    except BrokenPipeError:
        raise  # (the reader went away, `| head`: cobus.cli ends quietly)
    except ConnectionError as exc:
        return _fail(f"cannot open the bus: {exc}")
    except KeyboardInterrupt:
        pass
    if not live_view and not args.json:
        from cobus._console import print_table

        rate, load = figures()
        print_table(_table(decoder, rate, load, dropped()))
    elif args.json:
        nodes = [decoder.stats[n].summary() for n in sorted(decoder.stats)]
        print(json.dumps({"nodes": nodes, "dropped": dropped()}))
    if dropped():
        print(
            f"cobus monitor: {dropped():,} frames dropped: decoding could not keep up "
            "(--filter, --node or a file: cobus record, then cobus decode)",
            file=sys.stderr,
        )
    return 0
