"""Parameter sets: which value each parameter of a node should hold, read from a file.

A set is a table of (object, set-point) and how the node saves (1010h). Three sources:

- YAML, objects by EDS name or address, in the order they are written::

    eds: zapi.eds                    # names, types, limits (when the node gives no EDS)
    save: {subindex: 0}              # 1010h sub 0 "save", as the ZAPI wants; false: never save
    parameters:
      main_contactor_voltage: 100
      "0x20A8:00": 100
      "0x2001:00": {value: 5, type: UNSIGNED8}   # without an EDS the type is needed

- CSV with a header: ``object,value[,type]`` or ``index,subindex,value[,type]`` (more columns,
  e.g. ``comment``, are ignored);
- a DCF: every writable object with a ParameterValue (:meth:`ParameterSet.from_dcf`).

Every problem is collected with its file, line and key and raised at once as
:class:`ParameterFileError`: an object the EDS lacks (with close names), a read-only object,
a value out of the type's range or the EDS limits, a missing type.
"""

from __future__ import annotations

import csv
import io
import math
import os
import re
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from cobus._files import replace_file
from cobus._yaml import DataFileError, FileProblem, LineMap, line_of, read_yaml
from cobus.master.config import ObjectIndex
from cobus.od import (
    CommandObjects,
    DataType,
    EdsError,
    ObjectDictionary,
    Variable,
    data_type_named,
    decode,
    encode,
    load,
)

__all__ = [
    "SAVE_SIGNATURE",
    "Parameter",
    "ParameterFileError",
    "ParameterProblem",
    "ParameterSet",
    "SaveCommand",
    "load_parameters",
    "loads_parameters",
]

#: "save" as CiA 301 1010h wants it (65766173h, little-endian).
SAVE_SIGNATURE = b"save"

_MAX_TEXT = 64  # characters of a value shown in a message


class ParameterProblem(FileProblem):
    """One problem of a parameter file: where (file, line, key) and why."""


class ParameterFileError(DataFileError):
    """A parameter file that cannot be used; ``problems`` lists every one found."""

    what = "the parameter file"


@dataclass(frozen=True)
class Parameter:
    """One set-point: the object (index, sub-index, type, name) and the value it should hold."""

    index: int
    subindex: int
    value: Any
    data_type: DataType
    name: str = ""
    #: Where the file sets it (None: not from a file).
    line: int | None = None
    #: False for a write-only object: it is written every time, never read or verified.
    readable: bool = True

    @property
    def address(self) -> str:
        """``0x20A8:00``."""
        return f"0x{self.index:04X}:{self.subindex:02X}"

    def __str__(self) -> str:
        name = f" {self.name}" if self.name else ""
        return f"{self.address}{name} = {show(self.value)}"

    def encode(self) -> bytes:
        """The set-point as the node takes it."""
        return encode(self.data_type, self.value)

    def decode(self, data: bytes) -> Any:
        """A value the node answered (integers: bytes beyond the type's size, as an expedited
        answer without size indication has, are dropped; a shorter answer is extended).
        :class:`~cobus.od.DataLengthError` when the length does not fit the type."""
        size = self.data_type.size
        if size is not None and len(data) != size and self.data_type.is_integer and data:
            if len(data) > size:  # an expedited answer without size: 4 bytes
                data = data[:size]
            else:  # a device answering fewer bytes than its type takes
                fill = b"\xff" if self.data_type.is_signed and data[-1] & 0x80 else b"\0"
                data = data + fill * (size - len(data))
        return decode(self.data_type, data)

    def holds(self, value: Any) -> bool:
        """Whether ``value`` (as read) is the set-point (compared as encoded, so a REAL32 is
        compared at its own precision)."""
        try:
            if encode(self.data_type, value) == self.encode():
                return True
        except (ValueError, TypeError):
            return False
        return bool(self.data_type.is_real and value == self.value)  # -0.0 and 0.0

    def matches(self, data: bytes) -> bool:
        """Whether the node's answer ``data`` holds the set-point (compared as encoded, so a
        REAL32 is compared at its own precision)."""
        try:
            return encode(self.data_type, self.decode(data)) == self.encode()
        except (ValueError, TypeError):
            return False


@dataclass(frozen=True)
class SaveCommand:
    """How the node is told to keep its parameters: ``signature`` to ``index`` sub
    ``subindex`` (CiA 301: 1010h sub 1 "save"; the ZAPI ACE2 wants sub 0)."""

    index: int = 0x1010
    subindex: int = 1
    signature: bytes = SAVE_SIGNATURE

    def __str__(self) -> str:
        return f"0x{self.index:04X}:{self.subindex:02X} = {self.signature!r}"


@dataclass
class ParameterSet:
    """The parameters a node should hold, in the order they are written, and its save
    command (None: the set is never saved)."""

    parameters: tuple[Parameter, ...]
    save: SaveCommand | None = field(default_factory=SaveCommand)
    #: The file it was read from, for messages.
    path: str | None = None
    #: The dictionary that named the objects (None: addresses and types only).
    od: ObjectDictionary | None = None
    #: What the source held that the set leaves out, each with why (a DCF's commands).
    left_out: tuple[tuple[Parameter, str], ...] = ()

    def __iter__(self) -> Iterator[Parameter]:
        return iter(self.parameters)

    def __len__(self) -> int:
        return len(self.parameters)

    def __getitem__(self, key: int | tuple[int, int]) -> Parameter:
        if isinstance(key, tuple):
            for p in self.parameters:
                if (p.index, p.subindex) == key:
                    return p
            raise KeyError(f"the set has no parameter 0x{key[0]:04X}:{key[1]:02X}")
        return self.parameters[key]

    @classmethod
    def from_dcf(
        cls,
        od: ObjectDictionary,
        *,
        save: SaveCommand | None = None,
        path: str | None = None,
        commands: bool = False,
    ) -> ParameterSet:
        """Every parameter of ``od`` with a ParameterValue (a DCF), in index order: readable
        and writable, without 1010h/1011h and the PDO parameters (the master's part). A
        command (a controlword, a mode, a set-point, an output, what the DCF maps to an
        RPDO: :class:`~cobus.od.CommandObjects`) is no parameter: it is left out and listed in
        ``left_out`` - unless ``commands``, when it is kept (and a manager applies it only
        with ``allow_commands``)."""
        from cobus.blocks.param_manager import is_parameter

        roles = CommandObjects(od)
        params = []
        left_out = []
        for var in od.variables():
            if var.parameter_value is None or not is_parameter(var):
                continue
            param = _parameter(var, var.parameter_value, None)
            why = roles.reason(var.index, var.subindex)
            if why is None or commands:
                params.append(param)
            else:
                left_out.append((param, why))
        chosen = save if save is not None else SaveCommand()
        return cls(tuple(params), chosen, path, od, tuple(left_out))

    def to_yaml(self) -> str:
        """The set as a YAML parameter file: each value with its type (the file reads the
        same with or without an EDS), names as comments where known."""
        lines = []
        if self.save is None:
            lines.append("save: false")
        else:
            s = self.save
            text = s.signature.decode("latin-1")
            number = int.from_bytes(s.signature, "little")
            sig = f"signature: {text}" if text.isalnum() else f"signature: 0x{number:08X}"
            lines.append(f"save: {{index: 0x{s.index:04X}, subindex: {s.subindex}, {sig}}}")
        lines.append("parameters:")
        for p in self.parameters:
            value = _yaml_value(p.value)
            typed = f"{{value: {value}, type: {p.data_type.name}}}"
            comment = f"  # {p.name}" if p.name else ""
            lines.append(f'  "{p.address}": {typed}{comment}')
        return "\n".join(lines) + "\n"

    def to_csv(self) -> str:
        """The set as CSV (``index,subindex,value,type,name``)."""
        out = io.StringIO()
        writer = csv.writer(out, lineterminator="\n")
        writer.writerow(["index", "subindex", "value", "type", "name"])
        for p in self.parameters:
            value = p.value.hex() if isinstance(p.value, bytes) else p.value
            writer.writerow(
                [f"0x{p.index:04X}", f"0x{p.subindex:02X}", value, p.data_type.name, p.name]
            )
        return out.getvalue()

    def write(self, path: str | os.PathLike[str]) -> None:
        """Write the set to ``path``: CSV for ``.csv``, YAML otherwise. The file is replaced
        whole or not at all (written beside it, then renamed; a link there is replaced, never
        written through)."""
        text = self.to_csv() if os.fspath(path).lower().endswith(".csv") else self.to_yaml()
        replace_file(path, text.encode("utf-8"))


def show(value: Any) -> str:
    """A value as a message shows it (long ones cut)."""
    text = value.hex(" ") if isinstance(value, bytes) else repr(value)
    return text if len(text) <= _MAX_TEXT else text[: _MAX_TEXT - 3] + "..."


def _yaml_value(value: Any) -> str:
    if isinstance(value, bytes):
        return f'"{value.hex(" ")}"'
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        return repr(value)
    dumped: str = yaml.safe_dump(value, default_style='"', width=1 << 20).strip()
    return dumped


def _parameter(var: Variable, value: Any, line: int | None) -> Parameter:
    return Parameter(var.index, var.subindex, value, var.data_type, var.name, line, var.readable)


# ------------------------------------------------------------------------------- reading


class _Reader:
    def __init__(self, path: str, od: ObjectDictionary | None, base_dir: Path) -> None:
        self.path = path
        self.od = od
        self.base_dir = base_dir
        self.problems: list[ParameterProblem] = []
        self.index: ObjectIndex | None = None

    def error(self, line: int | None, key: str | None, reason: str) -> None:
        self.problems.append(ParameterProblem(self.path, line, key, reason))

    def use_dictionary(self, od: ObjectDictionary, name: str) -> None:
        self.od = od
        self.index = ObjectIndex(od, name)

    def parameter(self, key: Any, value: Any, type_name: Any, line: int | None) -> Parameter | None:
        """One entry: the object ``key`` names, ``value`` (file text or YAML value) checked."""
        shown = str(key)
        var: Variable | None = None
        address: tuple[int, int] | None = None
        if self.index is not None:
            try:
                var = self.index.resolve(key)
            except ValueError as exc:
                self.error(line, shown, str(exc))
                return None
        else:
            address = _address(key)
            if address is None:
                looks = isinstance(key, str) and bool(_ADDRESS_LIKE.match(key.strip()))
                self.error(
                    line,
                    shown,
                    'not an address: index 0001h-FFFFh, sub-index 00h-FFh, e.g. "0x20A8:00"'
                    if looks
                    else 'without an EDS objects are named by address, e.g. "0x20A8:00"; add '
                    "'eds: FILE' to name them",
                )
                return None
        data_type: DataType | None = var.data_type if var is not None else None
        if type_name is not None:
            given = data_type_named(type_name)
            if given is None:
                names = ", ".join(t.name for t in DataType if t is not DataType.DOMAIN)
                self.error(line, shown, f"type {type_name!r} is not a CiA 301 type ({names})")
                return None
            if data_type is not None and given is not data_type:
                self.error(
                    line, shown, f"type {given.name} differs from the EDS's {data_type.name}"
                )
                return None
            data_type = given
        if data_type is None:
            self.error(line, shown, "no EDS gives the type: add 'type:' (e.g. UNSIGNED16)")
            return None
        if data_type is DataType.DOMAIN:
            self.error(line, shown, "a DOMAIN is data, not a parameter: leave it out")
            return None
        if var is not None and not var.writable:
            self.error(line, shown, f"{var.name!r} ({var.access}) cannot be written")
            return None
        try:
            parsed = _value(value, data_type)
            if var is not None:
                var.check(parsed)
            else:
                encode(data_type, parsed)
        except (ValueError, TypeError, OverflowError) as exc:
            self.error(line, shown, f"{show(value)} is not a valid {data_type.name}: {exc}")
            return None
        if var is not None:
            return _parameter(var, parsed, line)
        assert address is not None
        return Parameter(address[0], address[1], parsed, data_type, "", line)

    def save(self, raw: Any, line: int | None) -> SaveCommand | None:
        if raw is None or raw is False:
            return None
        if raw is True:
            return SaveCommand()
        if not isinstance(raw, Mapping):
            self.error(line, "save", "give false, true or {index:, subindex:, signature:}")
            return SaveCommand()
        unknown = set(raw) - {"index", "subindex", "signature"}
        if unknown:
            self.error(line, "save", f"unknown key(s) {sorted(map(str, unknown))}")
        index = raw.get("index", 0x1010)
        sub = raw.get("subindex", 1)
        signature = raw.get("signature", "save")
        if isinstance(index, bool) or not isinstance(index, int) or not 0 < index <= 0xFFFF:
            self.error(line_of(raw, "index"), "save.index", f"{index!r} is not an index")
            index = 0x1010
        if isinstance(sub, bool) or not isinstance(sub, int) or not 0 <= sub <= 0xFF:
            self.error(line_of(raw, "subindex"), "save.subindex", f"{sub!r} is not 0..255")
            sub = 1
        if isinstance(signature, str) and len(signature) == 4 and signature.isascii():
            sig = signature.encode("ascii")
        elif isinstance(signature, int) and not isinstance(signature, bool):
            if not 0 <= signature <= 0xFFFFFFFF:
                self.error(line_of(raw, "signature"), "save.signature", "not 32 bits")
                signature = 0
            sig = signature.to_bytes(4, "little")
        else:
            self.error(
                line_of(raw, "signature"),
                "save.signature",
                f"{signature!r}: give 4 ASCII characters (save) or a 32-bit number",
            )
            sig = SAVE_SIGNATURE
        return SaveCommand(index, sub, sig)

    def eds(self, raw: Any, line: int | None) -> None:
        if not isinstance(raw, str) or not raw:
            self.error(line, "eds", f"{raw!r} is not a file name")
            return
        path = Path(raw) if os.path.isabs(raw) else self.base_dir / raw
        try:
            od = load(path)
        except (OSError, EdsError) as exc:
            self.error(line, "eds", f"cannot read {path}: {exc}")
            return
        self.use_dictionary(od, str(path))


_ADDRESS_LIKE = re.compile(r"(?i)(0x)?[0-9a-f]+h?\s*(:|sub)")


def _address(key: Any) -> tuple[int, int] | None:
    if not isinstance(key, str):
        return None
    text = key.strip().lower()
    head, sep, tail = text.partition(":")
    if not sep:
        head, sep, tail = text.partition("sub")
    try:
        index = int(head.removesuffix("h"), 16)
        sub = int(tail.removesuffix("h"), 16) if sep else 0
    except ValueError:
        return None
    if not (0 < index <= 0xFFFF and 0 <= sub <= 0xFF):
        return None
    return index, sub


def _value(raw: Any, data_type: DataType) -> Any:
    """The value ``raw`` (a YAML value or CSV text) means for ``data_type``."""
    if data_type is DataType.BOOLEAN:
        if isinstance(raw, str):
            text = raw.strip().lower()
            if text in ("1", "true", "yes", "on"):
                return True
            if text in ("0", "false", "no", "off"):
                return False
            raise ValueError("write true or false")
        if isinstance(raw, bool | int) and raw in (0, 1):
            return bool(raw)
        raise ValueError("write true or false")
    if isinstance(raw, str) and not raw.strip() and data_type is not DataType.VISIBLE_STRING:
        raise ValueError("the value is missing")
    if data_type.is_integer:
        if isinstance(raw, str):
            text = raw.strip().replace("_", "")
            if len(text) > 40:
                raise ValueError("the number is too long")
            return int(text, 0)
        if isinstance(raw, bool) or not isinstance(raw, int):
            raise ValueError("give a whole number")
        return raw
    if data_type.is_real:
        value = float(raw.strip()) if isinstance(raw, str) else raw
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ValueError("give a number")
        if not math.isfinite(value):
            raise ValueError("give a finite number")
        return float(value)
    if data_type in (DataType.VISIBLE_STRING, DataType.UNICODE_STRING):
        if not isinstance(raw, str):
            raise ValueError("give text")
        return raw
    if data_type is DataType.OCTET_STRING:
        if not isinstance(raw, str):
            raise ValueError('give bytes in hex, e.g. "01 02 0a"')
        return bytes.fromhex(raw)
    raise ValueError(f"{data_type.name} values cannot be given in a parameter file")


def loads_parameters(
    text: str,
    *,
    od: ObjectDictionary | None = None,
    format: str = "yaml",
    path: str = "<string>",
    base_dir: str | os.PathLike[str] = ".",
) -> ParameterSet:
    """Read a parameter set from ``text`` (``format`` "yaml" or "csv"); names, types and
    limits come from ``od`` (or the YAML's ``eds:``). Raises :class:`ParameterFileError`."""
    reader = _Reader(path, od, Path(base_dir))
    if od is not None:
        reader.use_dictionary(od, "the EDS")
    if format == "csv":
        params = _read_csv(text, reader)
        save: SaveCommand | None = SaveCommand()
    elif format == "yaml":
        params, save = _read_yaml(text, reader)
    else:
        raise ValueError(f"format {format!r}: use 'yaml' or 'csv'")
    seen: dict[tuple[int, int], int | None] = {}
    for p in params:
        key = (p.index, p.subindex)
        if key in seen:
            first = seen[key]
            reader.error(
                p.line,
                p.address,
                "set twice" + (f" (first on line {first})" if first is not None else ""),
            )
        seen[key] = p.line
    if reader.problems:
        raise ParameterFileError(reader.problems)
    return ParameterSet(tuple(params), save, path, reader.od)


def _read_yaml(text: str, reader: _Reader) -> tuple[list[Parameter], SaveCommand | None]:
    data, problems = read_yaml(text)
    for problem in problems:
        reader.error(problem.line, problem.key, problem.reason)
    if data is None or problems:
        if not problems:
            reader.error(None, None, "the file is empty: give 'parameters:'")
        return [], None
    if not isinstance(data, LineMap):
        reader.error(None, None, "the file must be a mapping with 'parameters:'")
        return [], None
    for key in data:
        if key not in ("eds", "save", "parameters"):
            reader.error(line_of(data, key), str(key), "unknown key (eds, save, parameters)")
    if "eds" in data and reader.od is None:  # (a dictionary given by the caller comes first)
        reader.eds(data["eds"], line_of(data, "eds"))
    save = reader.save(data.get("save", True), line_of(data, "save"))
    raw = data.get("parameters")
    if not isinstance(raw, LineMap):
        reader.error(
            line_of(data, "parameters"),
            "parameters",
            "give a mapping of object name or address to value",
        )
        return [], save
    params = []
    for key, value in raw.items():
        line = line_of(raw, key)
        type_name = None
        if isinstance(value, Mapping):
            unknown = set(value) - {"value", "type"}
            if unknown or "value" not in value:
                reader.error(line, str(key), "write a value, or {value: V, type: T}")
                continue
            type_name = value.get("type")
            value = value["value"]
        param = reader.parameter(key, value, type_name, line)
        if param is not None:
            params.append(param)
    return params, save


def _read_csv(text: str, reader: _Reader) -> list[Parameter]:
    rows = csv.reader(io.StringIO(text))
    try:
        header = [h.strip().lower() for h in next(rows)]
    except StopIteration:
        reader.error(None, None, "the file is empty: give a header (object,value)")
        return []
    except csv.Error as exc:
        reader.error(1, None, f"not valid CSV: {exc}")
        return []
    named = "object" in header
    needed = ("object", "value") if named else ("index", "subindex", "value")
    missing = [c for c in needed if c not in header]
    if missing:
        reader.error(
            1,
            None,
            f"the header lacks {', '.join(missing)}: give object,value[,type] or "
            "index,subindex,value[,type]",
        )
        return []
    col = {name: header.index(name) for name in (*needed, "type") if name in header}
    params = []
    try:
        for row in rows:
            line = rows.line_num
            if not row or all(not cell.strip() for cell in row):
                continue
            if len(row) < len(header):
                row = row + [""] * (len(header) - len(row))
            if named:
                key: Any = row[col["object"]].strip()
            else:
                key = f"{row[col['index']].strip()}:{row[col['subindex']].strip()}"
                index_sub = _numbers(row[col["index"]], row[col["subindex"]])
                if index_sub is None:
                    reader.error(line, key, "index and subindex must be numbers (0x20A8, 0)")
                    continue
                key = f"0x{index_sub[0]:04X}:{index_sub[1]:02X}"
            type_name = row[col["type"]].strip() or None if "type" in col else None
            param = reader.parameter(key, row[col["value"]], type_name, line)
            if param is not None:
                params.append(param)
    except csv.Error as exc:
        reader.error(rows.line_num, None, f"not valid CSV: {exc}")
    return params


def _numbers(index: str, sub: str) -> tuple[int, int] | None:
    """The index (always hex: ``2001``, ``0x2001``, ``2001h``) and the sub-index (decimal,
    or hex with ``0x``/``h``)."""

    def number(text: str, hex_default: bool) -> int:
        text = text.strip().lower()
        if text.startswith("0x"):
            return int(text[2:], 16)
        if text.endswith("h"):
            return int(text[:-1], 16)
        return int(text, 16 if hex_default else 10)

    try:
        i, s = number(index, True), number(sub, False)
    except ValueError:
        return None
    if not (0 < i <= 0xFFFF and 0 <= s <= 0xFF):
        return None
    return i, s


_KEEP: Any = object()


def load_parameters(
    path: str | os.PathLike[str],
    *,
    od: ObjectDictionary | None = None,
    save: SaveCommand | None = _KEEP,
    commands: bool = False,
) -> ParameterSet:
    """Read a parameter file: ``.csv`` as CSV, ``.dcf`` as a DCF (its ParameterValues),
    anything else as YAML. ``save`` replaces the file's save command (None: never save; CSV
    and DCF files have none of their own: CiA 301's 1010h sub 1). A DCF's commands are left
    out unless ``commands`` (see :meth:`ParameterSet.from_dcf`). Raises
    :class:`ParameterFileError` with every problem."""
    pset = _load(path, od, commands)
    if save is not _KEEP:
        pset.save = save
    return pset


def _load(
    path: str | os.PathLike[str], od: ObjectDictionary | None, commands: bool = False
) -> ParameterSet:
    name = os.fspath(path)
    if name.lower().endswith(".dcf"):
        try:
            dcf = load(name)
        except (OSError, EdsError) as exc:
            raise ParameterFileError([ParameterProblem(name, None, None, str(exc))]) from None
        return ParameterSet.from_dcf(dcf, path=name, commands=commands)
    try:
        text = Path(name).read_text(encoding="utf-8-sig")  # (a BOM, as Excel writes it)
    except (OSError, UnicodeDecodeError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) else str(exc)
        raise ParameterFileError(
            [ParameterProblem(name, None, None, f"cannot read the file: {reason}")]
        ) from None
    return loads_parameters(
        text,
        od=od,
        format="csv" if name.lower().endswith(".csv") else "yaml",
        path=name,
        base_dir=Path(os.path.abspath(name)).parent,
    )


def parameters_of(
    od: ObjectDictionary, values: Iterable[tuple[Variable, Any]], path: str | None = None
) -> ParameterSet:
    """A set of (variable, value) pairs of ``od`` (what a snapshot captured)."""
    return ParameterSet(tuple(_parameter(v, value, None) for v, value in values), path=path, od=od)
