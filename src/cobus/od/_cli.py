"""``cobus eds check|show|doc FILE``: lint, list and document an EDS/DCF file."""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Iterable
from typing import Any

from cobus.od._checks import RPDO_MAPPING, TPDO_MAPPING, mapping_entries
from cobus.od._eds import load
from cobus.od._errors import EdsError, Severity
from cobus.od._model import Array, ObjectDictionary, Record, Variable
from cobus.od._types import DataType
from cobus.od._values import format_value

__all__ = ["register", "render_markdown", "render_table"]


def register(sub: Any) -> None:
    """Add ``cobus eds ...`` to the top-level sub-command parser."""
    eds: argparse.ArgumentParser = sub.add_parser(
        "eds", help="check, show or document an EDS/DCF file (CiA 306)"
    )
    eds.set_defaults(handler=lambda _args: _usage(eds))
    cmds = eds.add_subparsers(dest="eds_command", metavar="ACTION")

    check = cmds.add_parser(
        "check",
        help="report problems like a compiler; exit 0 clean, 1 warnings, 2 errors",
    )
    check.add_argument("file", help="EDS or DCF file")
    check.add_argument("--node-id", type=int, default=None, help="resolve $NODEID with this id")
    check.set_defaults(handler=_check)

    show = cmds.add_parser("show", help="print a table of the objects")
    show.add_argument("file", help="EDS or DCF file")
    show.add_argument("--node-id", type=int, default=None, help="resolve $NODEID with this id")
    show.set_defaults(handler=_show)

    doc = cmds.add_parser("doc", help="print a Markdown reference of the device")
    doc.add_argument("file", help="EDS or DCF file")
    doc.add_argument("--node-id", type=int, default=None, help="resolve $NODEID with this id")
    doc.set_defaults(handler=_doc)

    convert = cmds.add_parser(
        "convert",
        help="write an EDS as a DCF for a node (or a DCF back as an EDS), by OUT's suffix",
    )
    convert.add_argument("file", help="EDS or DCF file")
    convert.add_argument("out", help="the file to write: .dcf or .eds")
    convert.add_argument("--node-id", type=int, default=None, help="the node-ID (for a DCF)")
    convert.add_argument("--bitrate", type=int, default=None, help="bit/s (for a DCF)")
    convert.add_argument(
        "--force", action="store_true", help="overwrite OUT if it exists (a link is replaced)"
    )
    convert.set_defaults(handler=_convert)


def _usage(parser: argparse.ArgumentParser) -> int:
    parser.print_help()
    return 2


def _load(args: argparse.Namespace, *, usable: bool = True) -> ObjectDictionary | None:
    """The file's dictionary; ``usable``: refused when it has no object, its first error
    said once (show, doc, convert), else as it is (check lists every finding itself)."""
    try:
        if usable:
            from cobus._args import load_eds

            od: ObjectDictionary = load_eds(
                args.file, f"eds {args.eds_command}", node_id=args.node_id
            )
            return od
        return load(args.file, node_id=args.node_id)
    except EdsError as exc:
        print(f"{exc} (error)", file=sys.stderr)
        return None


def _check(args: argparse.Namespace) -> int:
    od = _load(args, usable=False)
    if od is None:
        return 2
    for finding in od.findings:
        print(finding)
    errors = len(od.errors)
    warnings = len(od.warnings)
    print(
        f"{args.file}: {len(od)} objects, {errors} error(s), {warnings} warning(s)",
        file=sys.stderr,
    )
    if errors:
        return 2
    return 1 if warnings else 0


def _show(args: argparse.Namespace) -> int:
    od = _load(args)
    if od is None:
        return 2
    print(render_table(od), end="")
    return 0


def _convert(args: argparse.Namespace) -> int:
    from cobus._files import refusal, replace_file

    od = _load(args)
    if od is None:
        return 2
    suffix = os.path.splitext(args.out)[1].lower()
    if suffix not in (".eds", ".dcf"):
        what = "an XDD/XDC (CiA 311) is not written" if suffix in (".xdd", ".xdc") else ""
        print(
            f"cobus eds convert: {args.out}: name the file .eds or .dcf, the formats this "
            f"writes" + (f"; {what}" if what else ""),
            file=sys.stderr,
        )
        return 2
    to_dcf = suffix == ".dcf"
    node_id = args.node_id if args.node_id is not None else od.node_id
    if to_dcf and node_id is None:
        print("a DCF is for one node: give --node-id", file=sys.stderr)
        return 2
    if node_id is not None and not 1 <= node_id <= 127:
        print(f"--node-id {node_id}: 1-127", file=sys.stderr)
        return 2
    refused = refusal(args.out, args.force)
    if refused is not None:
        print(f"cobus eds convert: {refused}", file=sys.stderr)
        return 2
    try:
        text = od.to_dcf(node_id, args.bitrate) if to_dcf else od.to_eds()
        replace_file(args.out, text.replace("\n", "\r\n").encode("utf-8"))
    except (OSError, ValueError) as exc:
        print(f"cannot write {args.out}: {exc}", file=sys.stderr)
        return 2
    kind = f"DCF for node {node_id}" if to_dcf else "EDS"
    print(f"{args.out}: {kind}, {len(od)} objects", file=sys.stderr)
    return 0


def _doc(args: argparse.Namespace) -> int:
    od = _load(args)
    if od is None:
        return 2
    print(render_markdown(od), end="")
    return 0


# --- rendering ---------------------------------------------------------------------------------


def _shown(var: Variable, value: Any, raw: str | None) -> str:
    """A value for people: the resolved value, or the file's text when it has none."""
    if value is None:
        return raw or ""
    if var.data_type is DataType.BOOLEAN:
        return "true" if value else "false"
    if isinstance(value, str):
        return repr(value) if value != value.strip() or not value else value
    if isinstance(value, bytes):
        return value.hex(" ").upper() if value else "(empty)"
    return format_value(var.data_type, value)


def _type_name(var: Variable) -> str:
    if var.declared_type is not None:
        return f"0x{var.declared_type:04X}?"
    return var.data_type.name


def _kind(obj: Variable | Record | Array) -> str:
    return obj.object_type.name


#: The widest a column is padded to: a longer cell (a 100 kB default value) runs past its
#: column in its own row, whole, instead of padding every row of the table to its width.
_MAX_WIDTH = 60


def _table(header: list[str], rows: Iterable[list[str]]) -> list[str]:
    rows = list(rows)
    widths = [len(h) for h in header]
    for row in rows:
        for i, cell in enumerate(row):
            widths[i] = max(widths[i], min(len(cell), _MAX_WIDTH))
    lines = ["  ".join(h.ljust(w) for h, w in zip(header, widths, strict=True)).rstrip()]
    lines.append("  ".join("-" * w for w in widths))
    lines.extend(
        "  ".join(c.ljust(w) for c, w in zip(row, widths, strict=True)).rstrip() for row in rows
    )
    return lines


def render_table(od: ObjectDictionary) -> str:
    """One line per object and per sub-object: address, name, type, access, PDO, values."""
    with_param = any(v.parameter_value is not None for v in od.variables())
    header = ["Index", "Sub", "Name", "Type", "Access", "PDO", "Default"]
    if with_param:
        header.append("Value")
    rows: list[list[str]] = []

    def var_row(var: Variable, sub: str) -> list[str]:
        row = [
            f"0x{var.index:04X}",
            sub,
            var.name,
            _type_name(var),
            var.access.value,
            "yes" if var.pdo_mappable else "",
            _shown(var, var.default, var.default_raw),
        ]
        if with_param:
            row.append(_shown(var, var.parameter_value, var.parameter_value_raw))
        return row

    for obj in od:
        if isinstance(obj, Variable):
            rows.append(var_row(obj, ""))
            continue
        rows.append(
            [f"0x{obj.index:04X}", "", obj.name, _kind(obj), "", "", ""]
            + ([""] if with_param else [])
        )
        rows.extend(var_row(var, str(var.subindex)) for var in obj)
    title = od.device_info.product_name or od.path or "object dictionary"
    lines = [f"{title}: {len(od)} objects", ""]
    lines.extend(_table(header, rows))
    return "\n".join(lines) + "\n"


def _md(text: object) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def _md_table(header: list[str], rows: Iterable[list[str]]) -> list[str]:
    out = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    out.extend("| " + " | ".join(_md(c) for c in row) + " |" for row in rows)
    return out


def _value_of(od: ObjectDictionary, index: int, sub: int) -> Any:
    var = od.get_variable(index, sub)
    return None if var is None else var.value


def _hex(value: Any, width: int = 8) -> str:
    return f"0x{value:0{width}X}" if isinstance(value, int) else "—"


_PROFILES = {
    301: "CiA 301 (no device profile)",
    401: "CiA 401 generic I/O",
    402: "CiA 402 drives and motion control",
    404: "CiA 404 measuring devices and closed-loop controllers",
    406: "CiA 406 encoders",
    408: "CiA 408 fluid power (hydraulic) devices",
    410: "CiA 410 inclinometers",
    418: "CiA 418 battery modules",
    419: "CiA 419 battery chargers",
}


def _identity(od: ObjectDictionary) -> list[str]:
    info = od.device_info
    file = od.file_info
    device_type = _value_of(od, 0x1000, 0)
    profile = ""
    if isinstance(device_type, int):
        number = device_type & 0xFFFF
        profile = _PROFILES.get(number, f"profile {number}")
    rates = ", ".join(str(r) for r in sorted(info.baud_rates)) or "—"
    rows = [
        ["Vendor", f"{info.vendor_name or '—'} ({_hex(info.vendor_number)})"],
        ["Product", f"{info.product_name or '—'} ({_hex(info.product_number)})"],
        ["Revision", _hex(info.revision_number)],
        ["Order code", info.order_code or "—"],
        ["Device type (0x1000)", f"{_hex(device_type)} {profile}".strip()],
        ["Bit rates (kbit/s)", rates],
        [
            "PDOs",
            f"{info.nr_of_rx_pdo if info.nr_of_rx_pdo is not None else '?'} RPDO, "
            f"{info.nr_of_tx_pdo if info.nr_of_tx_pdo is not None else '?'} TPDO",
        ],
        ["LSS", {True: "supported", False: "not supported", None: "—"}[info.lss_supported]],
        [
            "Source file",
            f"{file.file_name or od.path or '—'} (version {file.file_version or '?'}."
            f"{file.file_revision or '?'}, EDS {file.eds_version or '?'})",
        ],
        [
            "Created",
            " ".join(x for x in (file.creation_date, file.creation_time, file.created_by) if x)
            or "—",
        ],
    ]
    if od.commissioning is not None or od.node_id is not None:
        rows.append(["Node id", str(od.node_id) if od.node_id is not None else "—"])
    return _md_table(["Field", "Value"], rows)


_TRANSMISSION = {
    0: "synchronous (acyclic)",
    254: "event-driven (manufacturer)",
    255: "event-driven",
}


def _transmission(value: Any) -> str:
    if not isinstance(value, int):
        return "—"
    if value in _TRANSMISSION:
        return f"{value}: {_TRANSMISSION[value]}"
    if 1 <= value <= 240:
        return f"{value}: synchronous, every {value} SYNC"
    if value in (252, 253):
        return f"{value}: remote request only"
    return str(value)


def _pdos(od: ObjectDictionary) -> list[str]:
    out: list[str] = []
    for kind, comm_base, mapping in (
        ("RPDO", 0x1400, RPDO_MAPPING),
        ("TPDO", 0x1800, TPDO_MAPPING),
    ):
        for number, index in enumerate(mapping, 1):
            obj = od.get(index)
            comm = od.get(comm_base + number - 1)
            if not isinstance(obj, (Record, Array)) and not isinstance(comm, (Record, Array)):
                continue
            out.append(f"### {kind} {number}")
            out.append("")
            if isinstance(comm, (Record, Array)):
                cob = comm.get(1)
                details = []
                if cob is not None:
                    cob_text = _shown(cob, cob.value, cob.parameter_value_raw or cob.default_raw)
                    if cob.relative and cob.value is not None and cob.parameter_value is None:
                        cob_text += f" ({cob.default_raw})"
                    if isinstance(cob.value, int) and cob.value & 0x80000000:
                        cob_text += " (disabled)"
                    details.append(f"COB-ID {cob_text}")
                details.append(f"transmission type {_transmission(_value_of(od, comm.index, 2))}")
                inhibit = _value_of(od, comm.index, 3)
                if isinstance(inhibit, int) and inhibit:
                    details.append(f"inhibit time {inhibit * 100} µs")
                timer = _value_of(od, comm.index, 5)
                if isinstance(timer, int) and timer:
                    details.append(f"event timer {timer} ms")
                out.append(f"Communication 0x{comm.index:04X}: " + ", ".join(details) + ".")
                out.append("")
            if isinstance(obj, (Record, Array)):
                rows = []
                bits = 0
                for entry, index_, sub, length in mapping_entries(obj):
                    target = od.get_variable(index_, sub)
                    name = target.name if target is not None else "(not in the dictionary)"
                    rows.append(
                        [str(entry.subindex), f"0x{index_:04X}sub{sub:X}", name, str(length)]
                    )
                    bits += length
                if rows:
                    out.append(f"Default mapping 0x{obj.index:04X} ({bits} bits):")
                    out.append("")
                    out.extend(_md_table(["#", "Object", "Name", "Bits"], rows))
                else:
                    out.append(f"Default mapping 0x{obj.index:04X}: nothing mapped.")
                out.append("")
    return out or ["No PDOs.", ""]


def render_markdown(od: ObjectDictionary) -> str:
    """A datasheet-like Markdown reference: identity, PDOs with their mapping, all objects."""
    info = od.device_info
    title = info.product_name or od.file_info.file_name or od.path or "Device"
    lines = [f"# {title}", ""]
    if info.vendor_name:
        lines += [f"by {info.vendor_name}", ""]
    if od.file_info.description:
        lines += [od.file_info.description, ""]
    lines += ["## Identity", "", *_identity(od), ""]
    if od.comments:
        lines += ["## Comments", ""] + [f"> {_md(c)}" for c in od.comments] + [""]
    lines += ["## PDOs", "", *_pdos(od)]
    lines += ["## Objects", ""]
    rows = []
    for obj in od:
        vars_: list[tuple[Variable, str]]
        if isinstance(obj, Variable):
            vars_ = [(obj, "")]
        else:
            rows.append([f"0x{obj.index:04X}", "", obj.name, _kind(obj), "", "", "", "", ""])
            vars_ = [(v, str(v.subindex)) for v in obj]
        for var, sub in vars_:
            limits = ""
            if var.low_limit is not None or var.high_limit is not None:
                low = _shown(var, var.low_limit, None) or "…"
                high = _shown(var, var.high_limit, None) or "…"
                limits = f"{low} … {high}"
            rows.append(
                [
                    f"0x{var.index:04X}",
                    sub,
                    var.name,
                    _type_name(var),
                    var.access.value,
                    "yes" if var.pdo_mappable else "",
                    _shown(var, var.default, var.default_raw),
                    limits,
                    var.unit or "",
                ]
            )
    header = ["Index", "Sub", "Name", "Type", "Access", "PDO", "Default", "Limits", "Unit"]
    lines += [*_md_table(header, rows), ""]
    problems = od.findings
    if problems:
        errors = sum(1 for f in problems if f.severity is Severity.ERROR)
        lines += [
            "## Notes",
            "",
            f"`cobus eds check` reports {errors} error(s) and {len(problems) - errors} "
            "warning(s) in this file.",
            "",
        ]
    return "\n".join(lines)
