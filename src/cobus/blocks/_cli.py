"""cobus params: compare, apply and capture a node's parameters on a live bus.

    cobus params diff 8 zapi.yml                 # what differs from the file (nothing written)
    cobus params apply 8 zapi.yml                # write what differs, save, read back, verify
    cobus params snapshot 8 zapi-now.yml --eds zapi.eds   # the node's parameters to a file
    cobus params apply servo servo.yml --network line.yml  # a node by name, its EDS from there

The file is YAML (objects by EDS name or address), CSV or a DCF (its ParameterValues); see
``cobus.blocks.parameters``.

Parameters are configuration. A snapshot leaves out commands and process data - the CiA 402
controlword, modes and set-points, CiA 401 outputs, what the EDS maps to an RPDO or marks rww -
unless --objects names them; apply refuses a set that would write a command (it could switch
a drive on or move it) unless --allow-commands is given.

Names come from ``--eds``, the network file's EDS, or the file's own ``eds:``. The bus is
python-can's (``-i/--interface``, ``-c/--channel``, ``-b/--bitrate``, else its configuration).

Exit codes: 0 the node holds the set (diff: nothing differs; snapshot: every object read),
1 a transfer failed (no answer, refused, verify mismatch; snapshot: some objects left out),
2 bad usage or a bad file, 3 diff found differences.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from cobus._args import add_bus_options, bus_options, other_device, seconds

__all__ = ["register"]

_EXIT_OK, _EXIT_FAILED, _EXIT_USAGE, _EXIT_DIFFERS = 0, 1, 2, 3
_EXITS = (
    "exit codes: 0 the node holds the set (snapshot: every object read), 1 a transfer failed "
    "(snapshot: objects left out), 2 bad usage or file, 3 diff found differences"
)


def register(sub: Any) -> None:
    """Add ``cobus params ...`` to the top-level sub-command parser."""
    params: argparse.ArgumentParser = sub.add_parser(
        "params",
        help="compare, apply and capture a node's parameters (parameter manager)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    actions = params.add_subparsers(dest="action", metavar="ACTION", required=True)
    for name, help_text in (
        ("diff", "read the node and show what differs from FILE (writes nothing)"),
        ("apply", "bring the node to FILE: write what differs, save, read back, verify"),
        ("snapshot", "read the node's parameters into FILE (.yml or .csv)"),
    ):
        p = actions.add_parser(name, help=help_text, description=help_text, epilog=_EXITS)
        p.add_argument("node", help="node-ID 1-127 (or a node name with --network)")
        p.add_argument("file", type=Path, help="the parameter file")
        p.add_argument("--eds", type=Path, help="the node's EDS or DCF (names, types, limits)")
        p.add_argument("--network", type=Path, help="a network description naming the node")
        p.add_argument("--timeout", type=seconds, default=1.0, help="seconds per SDO answer")
        p.add_argument("--json", action="store_true", help="print the result as JSON")
        if name == "apply":
            p.add_argument("--no-save", action="store_true", help="do not send the save command")
            p.add_argument(
                "--save-subindex",
                type=int,
                choices=range(256),
                metavar="N",
                help="send 'save' to 1010h sub N (the ZAPI ACE2 wants 0; default: the file's, "
                "else 1)",
            )
            p.add_argument("--retries", type=int, default=2, help="tries again after a timeout")
            p.add_argument("--restarts", type=int, default=1, help="runs again after a failure")
            p.add_argument(
                "--allow-commands",
                action="store_true",
                help="also write the controlwords, modes, set-points and outputs the set holds "
                "(they can switch a drive on or move it; refused without this)",
            )
        if name == "snapshot":
            p.add_argument(
                "--objects",
                nargs="+",
                metavar="OBJ",
                help="objects by name, index (0x2001) or range (0x2000-0x5FFF); default: "
                "every read-write object from 2000h; a range, like the default, leaves out "
                "commands and process data, an object named on its own is read",
            )
            p.add_argument(
                "--communication",
                action="store_true",
                help="include the communication objects (1000h-1FFFh, not PDOs or 1010h/1011h)",
            )
        add_bus_options(p)
        p.set_defaults(handler=_run)


def _fail(message: str, code: int = _EXIT_USAGE, *, as_json: bool = False) -> int:
    """Say why on stderr (and, ``as_json``, as a JSON object on stdout); the exit code."""
    if as_json:
        print(json.dumps({"ok": False, "error": message, "exit": code}))
    print(f"cobus params: {message}", file=sys.stderr)
    return code


def _target(args: argparse.Namespace) -> tuple[int, Any]:
    """The node-ID and the dictionary the arguments name; ValueError says why not."""
    from cobus._args import load_eds
    from cobus.od import EdsError

    od = None
    node_id: int | None = None
    if args.network is not None:
        from cobus.master import NetworkConfigError, load_network

        try:
            network = load_network(args.network)
            cfg = network.node(int(args.node) if args.node.isdigit() else args.node)
        except (NetworkConfigError, KeyError) as exc:
            raise ValueError(str(exc)) from None
        node_id, od = cfg.node_id, cfg.od
    if args.eds is not None:
        try:
            od = load_eds(args.eds, "params")
        except (OSError, EdsError) as exc:
            raise ValueError(str(exc)) from None
    if node_id is None:
        if not args.node.isdigit() or not 1 <= int(args.node) <= 127:
            raise ValueError(f"node {args.node!r}: give a node-ID 1-127 (or --network FILE)")
        node_id = int(args.node)
    return node_id, od


def _run(args: argparse.Namespace) -> int:
    from cobus.blocks.param_manager import CommandsInSetError, ParameterManager
    from cobus.blocks.parameters import ParameterFileError, load_parameters
    from cobus.runtime import Network

    def fail(message: str, code: int = _EXIT_USAGE) -> int:
        return _fail(message, code, as_json=args.json)

    try:
        node_id, od = _target(args)
    except ValueError as exc:
        return fail(str(exc))
    pset = None
    if args.action != "snapshot":
        try:
            allowed = bool(getattr(args, "allow_commands", False))
            pset = load_parameters(args.file, od=od, commands=allowed)
        except ParameterFileError as exc:
            return fail(str(exc))
        if getattr(args, "save_subindex", None) is not None:
            from cobus.blocks.parameters import SaveCommand

            pset.save = SaveCommand(0x1010, args.save_subindex)
        od = od or pset.od
    elif od is None:
        return fail("a snapshot needs the node's EDS for names and types: give --eds FILE")
    options: dict[str, Any] = {}
    if args.action == "apply":
        options = {
            "retries": args.retries,
            "restarts": args.restarts,
            "save": not args.no_save,
            "allow_commands": args.allow_commands,
        }
    objects = None
    left_out: list[tuple[Any, str]] = []
    if args.action == "snapshot" and args.objects:
        try:
            objects = _objects(args.objects, od, left_out)
        except ValueError as exc:
            return fail(str(exc))
        if not objects and left_out:
            shown = ", ".join(f"0x{v.index:04X}:{v.subindex:02X} {v.name}" for v, _ in left_out)
            return fail(
                f"--objects: all are commands or process data ({shown}); name one on its own "
                "(--objects 0x6040) to read it"
            )
    if pset is not None and pset.left_out and not args.json:
        for param, why in pset.left_out:
            print(
                f"cobus params: {param} left out of {args.file}: {why} (--allow-commands "
                "applies it)",
                file=sys.stderr,
            )
    quiet = args.json or not sys.stderr.isatty()
    manager: Any = None
    with _Progress(quiet) as progress:
        try:
            with Network(**bus_options(args)) as net:
                node = net.add_remote(node_id, od, sdo_timeout=args.timeout)
                mismatch = other_device(node, od)
                if mismatch is not None:
                    if args.action == "apply":  # (names, types, commands would be misjudged)
                        return fail(f"{mismatch}; nothing written: give the node's own EDS")
                    print(f"cobus params: {mismatch}", file=sys.stderr)
                manager = ParameterManager(node, pset, progress=progress.update, **options)
                if args.action == "snapshot":
                    snap, failures = manager.snapshot(objects, communication=args.communication)
                    progress.stop()
                    if manager.stopped or not len(snap):
                        why = failures[-1] if failures else "nothing could be read"
                        return fail(f"{why}; {args.file} left as it was", _EXIT_FAILED)
                    snap.write(args.file)
                    left_out += manager.left_out
                    return _snapshot_done(args, snap, failures, left_out)
                report = manager.diff() if args.action == "diff" else manager.apply()
        except KeyboardInterrupt:
            progress.stop()
            return _interrupted(args, None if manager is None else manager.aio)
        except CommandsInSetError as exc:
            return fail(exc.describe("--allow-commands"))
        except BrokenPipeError:
            raise  # (the reader went away: cobus.cli ends quietly)
        except (OSError, ValueError) as exc:
            return fail(str(exc))
        except Exception as exc:  # the bus could not be opened (python-can's errors)
            if type(exc).__module__.startswith("can"):
                return fail(f"cannot open the bus: {exc}")
            raise
    return _report_done(args, report, pset.left_out if pset is not None else ())


def _interrupted(args: argparse.Namespace, manager: Any) -> int:
    """Ctrl-C: say so, and what the run had written (and whether it was saved)."""
    written = manager.written if manager is not None else []
    short = manager.cut_short if manager is not None else None
    step = short[0].name.lower().replace("_", " ") if short is not None else None
    cut = short[1] if short is not None and short[0].name == "WRITE" else None
    if args.json:
        print(
            json.dumps(
                {
                    "interrupted": True,
                    "step": step,
                    "written": [p.address for p in written],
                    "saved": not manager.unsaved if written else None,
                    "cut_short": None if cut is None else cut.address,
                }
            )
        )
    parts = ["interrupted" + (f" ({step})" if step else "")]
    if args.action == "apply":
        if written:
            shown = ", ".join(str(p) for p in written)
            parts.append(f"written before: {shown}")
            if manager.unsaved:
                parts.append("not saved: the node loses them at its next power-up")
        else:
            parts.append("nothing was written")
        if cut is not None:
            parts.append(f"the write of {cut} was cut short: the node may hold either value")
    else:
        parts.append("nothing was written" if args.action == "diff" else f"{args.file} not written")
    return _fail("; ".join(parts), 130)


def _objects(specs: list[str], od: Any, left_out: list[tuple[Any, str]]) -> list[Any]:
    """The objects ``--objects`` names: a range's parameters as (index, sub-index), its
    commands and process data added to ``left_out``; a name or index as given."""
    from cobus.blocks.param_manager import is_parameter
    from cobus.od import CommandObjects, process_data_of

    commands = CommandObjects(od)
    out: list[Any] = []
    for spec in specs:
        low, sep, high = spec.partition("-")
        try:
            if sep:
                lo, hi = int(low, 16), int(high, 16)
                for var in od.variables():
                    if not lo <= var.index <= hi or not is_parameter(var):
                        continue
                    why = process_data_of(var, commands)
                    if why is None:
                        out.append((var.index, var.subindex))
                    else:
                        left_out.append((var, why))
                continue
            key: Any = int(spec, 16) if spec.lower().startswith("0x") else spec
        except ValueError:
            raise ValueError(f"--objects {spec!r}: a name, 0x2001 or 0x2000-0x5FFF") from None
        if od.get(key) is None:
            raise ValueError(f"--objects {spec!r}: the EDS has no such object")
        out.append(key)
    return out


def _snapshot_done(
    args: argparse.Namespace, snap: Any, failures: list[Any], left_out: list[tuple[Any, str]]
) -> int:
    if args.json:
        print(
            json.dumps(
                {
                    "file": str(args.file),
                    "parameters": len(snap),
                    "left_out": [str(f) for f in failures],
                    "not_parameters": [
                        {"object": f"0x{v.index:04X}:{v.subindex:02X}", "name": v.name, "why": why}
                        for v, why in left_out
                    ],
                }
            )
        )
    else:
        from rich.markup import escape

        from cobus._console import console as new_console

        console = new_console()
        console.print(f"{len(snap)} parameters written to {escape(str(args.file))}")
        if left_out:
            console.print(
                f"{len(left_out)} object(s) left out as commands or process data "
                "(name one with --objects to read it):"
            )
            for var, why in left_out:
                console.print(f"  0x{var.index:04X}:{var.subindex:02X} {escape(var.name)}: {why}")
        for failure in failures:
            console.print(f"[yellow]left out:[/] {escape(str(failure))}")
    return _EXIT_FAILED if failures else _EXIT_OK


def _report_done(
    args: argparse.Namespace, report: Any, left_out: tuple[tuple[Any, str], ...] = ()
) -> int:
    if args.json:
        result = report.to_dict()
        result["left_out"] = [
            {"object": p.address, "name": p.name, "why": why} for p, why in left_out
        ]
        print(json.dumps(result, default=str))
    else:
        from rich.markup import escape

        from cobus._console import console as new_console
        from cobus._console import print_table
        from cobus._console import table as new_table

        console = new_console()
        if report.differences:
            table = new_table(
                "object",
                "name",
                "set-point",
                "node held",
                "written",
                title=f"{report.node}: {len(report.differences)} difference(s)",
            )
            written = {(p.index, p.subindex) for p in report.written}
            for param, held in report.differences:
                table.add_row(
                    param.address,
                    escape(param.name),
                    escape(repr(param.value)),
                    "unreadable" if held is None else escape(repr(held)),
                    "yes" if (param.index, param.subindex) in written else "",
                )
            print_table(table)
        for failure in report.failures:
            console.print(f"[red]failed:[/] {escape(str(failure))}")
        colour = "green" if report.ok else ("yellow" if report.dry_run else "red")
        console.print(f"[{colour}]{escape(report.summary)}[/]")
    if report.failures or report.aborted:
        return _EXIT_FAILED
    return _EXIT_DIFFERS if report.dry_run and report.differences else _EXIT_OK


class _Progress:
    """A rich progress bar on stderr fed by the manager's progress callback (any thread)."""

    def __init__(self, quiet: bool) -> None:
        self.quiet = quiet
        self._bar: Any = None
        self._task: Any = None

    def __enter__(self) -> _Progress:
        if not self.quiet:
            from rich.console import Console
            from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

            self._bar = Progress(
                TextColumn("{task.description:<10}"),
                BarColumn(),
                MofNCompleteColumn(),
                console=Console(stderr=True),
                transient=True,
            )
            self._bar.start()
            self._task = self._bar.add_task("read", total=None)
        return self

    def update(self, step: Any, done: int, total: int) -> None:
        if self._bar is not None:
            description = step.name.lower().replace("_", " ")
            self._bar.update(self._task, description=description, completed=done, total=total)

    def stop(self) -> None:
        if self._bar is not None:
            self._bar.stop()
            self._bar = None

    def __exit__(self, *exc: object) -> None:
        self.stop()
