"""``cobus config check FILE`` and ``cobus config dcf FILE OUTDIR``: the network description."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from cobus.master.config import NetworkConfig, check_network
from cobus.master.errors import ConfigProblem, Severity

__all__ = ["register"]


def register(sub: Any) -> None:
    """Add ``cobus config ...`` to the top-level sub-command parser."""
    config: argparse.ArgumentParser = sub.add_parser(
        "config", help="check a network description (YAML) or write its DCFs"
    )
    config.set_defaults(handler=lambda _args: _usage(config))
    cmds = config.add_subparsers(dest="config_command", metavar="ACTION")

    check = cmds.add_parser(
        "check",
        help="report problems with file, line, node and key; exit 0 clean, 1 warnings, 2 errors",
    )
    check.add_argument("file", help="network description (YAML)")
    check.add_argument(
        "-v", "--verbose", action="store_true", help="also list each node's start-up SDOs"
    )
    check.set_defaults(handler=_check)

    dcf = cmds.add_parser(
        "dcf", help="write <node>.dcf and the concise <node>.bin of every node into OUTDIR"
    )
    dcf.add_argument("file", help="network description (YAML)")
    dcf.add_argument("outdir", help="directory to write into (created if missing)")
    dcf.add_argument(
        "--force",
        action="store_true",
        help="overwrite the files there (a link is replaced, never written through)",
    )
    dcf.set_defaults(handler=_dcf)


def _usage(parser: argparse.ArgumentParser) -> int:
    parser.print_help()
    return 2


def _report(problems: list[ConfigProblem]) -> tuple[int, int]:
    for problem in problems:
        print(problem)
    errors = sum(1 for p in problems if p.severity is Severity.ERROR)
    return errors, len(problems) - errors


def _listing(cfg: NetworkConfig) -> None:
    for node in cfg.nodes.values():
        print(f"{node.name} (node {node.node_id}, {node.eds_path.name}):")
        for entry in [*node.startup, *node.error_control_entries()]:
            print(f"  {entry}")
        for layout in (*node.tpdos, *node.rpdos):
            names = ", ".join(s.name for s in layout.signals) or "-"
            print(
                f"  {layout.direction.upper()} {layout.number} 0x{layout.cob_id:X} "
                f"type {layout.transmission_type}: {names}"
            )


def _check(args: argparse.Namespace) -> int:
    cfg, problems = check_network(args.file)
    errors, warnings = _report(problems)
    if cfg is not None and args.verbose:
        _listing(cfg)
    nodes = len(cfg.nodes) if cfg is not None else 0
    print(
        f"{args.file}: {nodes} node(s), {errors} error(s), {warnings} warning(s)", file=sys.stderr
    )
    if errors:
        return 2
    return 1 if warnings else 0


def _dcf(args: argparse.Namespace) -> int:
    cfg, problems = check_network(args.file)
    errors, _warnings = _report(problems)
    if cfg is None or errors:
        print(f"{args.file}: {errors} error(s); nothing written", file=sys.stderr)
        return 2
    from cobus._files import refusal

    refused = [r for p in cfg.dcf_files(args.outdir) if (r := refusal(p, args.force))]
    if refused:
        for reason in refused:
            print(f"cobus config dcf: {reason}", file=sys.stderr)
        print(f"{args.file}: nothing written", file=sys.stderr)
        return 2
    try:
        written = cfg.write_dcfs(args.outdir)
    except OSError as exc:
        print(f"cannot write into {args.outdir}: {exc}", file=sys.stderr)
        return 2
    for path in written:
        print(path)
    return 0
