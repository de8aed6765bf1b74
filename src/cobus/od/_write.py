"""Writing an :class:`ObjectDictionary` as CiA 306 EDS/DCF text.

Values keep the text the file had (``$NODEID+0x180`` stays as written) unless they were
changed in code. Object lists are derived from the objects. Unknown keys and sections are
written back, and so are the file's whole-line ``;``/``#`` comments, each in its section after
the key it followed. Reading the output gives an equal dictionary, and writing that again
gives the same text.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from typing import Any

from cobus.od._model import (
    REL_PARAM,
    STANDARD_BAUD_RATES,
    Array,
    Commissioning,
    DeviceInfo,
    FileInfo,
    ObjectDictionary,
    Record,
    Variable,
)
from cobus.od._types import DataType, same_value
from cobus.od._values import format_value

__all__ = ["write"]

_FILE_INFO_KEYS = {
    "file_name": "FileName",
    "file_version": "FileVersion",
    "file_revision": "FileRevision",
    "eds_version": "EDSVersion",
    "description": "Description",
    "creation_time": "CreationTime",
    "creation_date": "CreationDate",
    "created_by": "CreatedBy",
    "modification_time": "ModificationTime",
    "modification_date": "ModificationDate",
    "modified_by": "ModifiedBy",
    "last_eds": "LastEDS",
}
_DEVICE_INFO_KEYS = {
    "vendor_name": "VendorName",
    "vendor_number": "VendorNumber",
    "product_name": "ProductName",
    "product_number": "ProductNumber",
    "revision_number": "RevisionNumber",
    "order_code": "OrderCode",
    "simple_boot_up_master": "SimpleBootUpMaster",
    "simple_boot_up_slave": "SimpleBootUpSlave",
    "granularity": "Granularity",
    "dynamic_channels_supported": "DynamicChannelsSupported",
    "group_messaging": "GroupMessaging",
    "nr_of_rx_pdo": "NrOfRXPDO",
    "nr_of_tx_pdo": "NrOfTXPDO",
    "lss_supported": "LSS_Supported",
    "compact_pdo": "CompactPDO",
}
_HEX_FIELDS = {"vendor_number", "product_number", "revision_number", "lss_serial_number"}
_COMMISSIONING_KEYS = {
    "node_id": "NodeID",
    "node_name": "NodeName",
    "baudrate": "Baudrate",
    "net_number": "NetNumber",
    "network_name": "NetworkName",
    "canopen_manager": "CANopenManager",
    "lss_serial_number": "LSS_SerialNumber",
}


def _text(attr: str, value: Any) -> str:
    if isinstance(value, bool):
        return "1" if value else "0"
    if isinstance(value, int) and attr in _HEX_FIELDS:
        return f"0x{value:08X}"
    return str(value)


def _typed_section(out: list[str], name: str, obj: Any, keys: dict[str, str]) -> None:
    out.append(f"[{name}]")
    for attr, key in keys.items():
        value = getattr(obj, attr)
        if value is not None:
            out.append(f"{key}={_text(attr, value)}")


def _raw_or(raw: str | None, dt: DataType, value: Any) -> str | None:
    if raw is not None:
        return raw
    if value is None:
        return None
    return format_value(dt, value)


def _var_keys(var: Variable, *, with_param: bool = True) -> list[str]:
    """The value keys of a VAR (or the shared part of a compact object)."""
    dt = var.data_type
    code = var.declared_type if var.declared_type is not None else int(dt)
    out = [f"DataType=0x{code:04X}", f"AccessType={var.access.value}"]
    default = _raw_or(var._default_raw, dt, var._default)
    if default is not None:
        out.append(f"DefaultValue={default}")
    out.append(f"PDOMapping={int(var.pdo_mappable)}")
    low = _raw_or(var._low_raw, dt, var._low)
    if low is not None:
        out.append(f"LowLimit={low}")
    high = _raw_or(var._high_raw, dt, var._high)
    if high is not None:
        out.append(f"HighLimit={high}")
    if with_param:
        param = _raw_or(var._param_raw, dt, var._param)
        if param is not None:
            out.append(f"ParameterValue={param}")
    return out


def _annotations(out: list[str], item: Variable | Record | Array) -> None:
    if item.denotation is not None:
        out.append(f"Denotation={item.denotation}")
    if item.description is not None:
        out.append(f"Description={item.description}")
    if isinstance(item, Variable):
        if item.unit is not None:
            out.append(f"Unit={item.unit}")
        if item.factor is not None:
            out.append(f"Factor={item.factor!r}")
    if item.obj_flags is not None:
        out.append(f"ObjFlags=0x{item.obj_flags:X}")
    if item.extra:
        out.extend(f"{k}={v}" for k, v in item.extra.items())


def _variable(out: list[str], var: Variable, section: str) -> None:
    out.append(f"[{section}]")
    out.append(f"ParameterName={var.name}")
    out.append(f"ObjectType=0x{int(var.object_type):X}")
    out.extend(_var_keys(var))
    _annotations(out, var)
    out.append("")


_SHARED = (
    "data_type",
    "declared_type",
    "access",
    "pdo_mappable",
    "_default",
    "_default_raw",
    "_low",
    "_low_raw",
    "_high",
    "_high_raw",
    "unit",
    "factor",
    "obj_flags",
    "description",
    "extra",
)


def _compact_ok(obj: Record | Array) -> bool:
    """Whether the sub-objects still fit the CompactSubObj description they were read from."""
    count = obj.compact
    subs = obj.subindices
    if not count or set(subs) != set(range(count + 1)):
        return False
    sub0 = subs[0]
    if (
        sub0.name != "NrOfObjects"
        or sub0.data_type is not DataType.UNSIGNED8
        or sub0.default != count
        or sub0.parameter_value is not None
        or sub0.access.value != "ro"
        or sub0.pdo_mappable
        or sub0.extra
        or sub0.low_limit is not None
        or sub0.high_limit is not None
    ):
        return False
    first = subs[1]
    for sub in range(2, count + 1):
        other = subs[sub]
        if (first._rel | REL_PARAM) != (other._rel | REL_PARAM):
            return False
        for attr in _SHARED:
            if not same_value(getattr(first, attr), getattr(other, attr)):
                return False
    return first.description is None and first.obj_flags is None and not first.extra


def _compact(out: list[str], obj: Record | Array) -> None:
    index = obj.index
    first = obj.subindices[1]
    out.append(f"[{index:04X}]")
    out.append(f"ParameterName={obj.name}")
    out.append(f"ObjectType=0x{int(obj.object_type):X}")
    out.extend(_var_keys(first, with_param=False))
    if first.unit is not None:
        out.append(f"Unit={first.unit}")
    if first.factor is not None:
        out.append(f"Factor={first.factor!r}")
    out.append(f"CompactSubObj={obj.compact}")
    _annotations(out, obj)
    out.append("")
    count = obj.compact or 0
    entries = [obj.subindices[s] for s in range(1, count + 1)]
    names = [(v.subindex, v.name) for v in entries if v.name != f"{obj.name}{v.subindex}"]
    values = [
        (v.subindex, _raw_or(v._param_raw, v.data_type, v._param))
        for v in entries
        if v._param_raw is not None or v._param is not None
    ]
    denotations = [(v.subindex, v.denotation) for v in entries if v.denotation is not None]
    for suffix, items in (("Name", names), ("Value", values), ("Denotation", denotations)):
        if items:
            out.append(f"[{index:04X}{suffix}]")
            out.append(f"NrOfEntries={len(items)}")
            out.extend(f"{sub}={text}" for sub, text in items)
            out.append("")


def _composite(out: list[str], obj: Record | Array) -> None:
    if obj.compact is not None and _compact_ok(obj):
        _compact(out, obj)
        return
    index = obj.index
    out.append(f"[{index:04X}]")
    out.append(f"ParameterName={obj.name}")
    out.append(f"ObjectType=0x{int(obj.object_type):X}")
    out.append(f"SubNumber=0x{len(obj.subindices):X}")
    _annotations(out, obj)
    out.append("")
    for var in obj:
        _variable(out, var, f"{index:04X}sub{var.subindex:X}")


def _object(out: list[str], obj: Variable | Record | Array) -> None:
    if isinstance(obj, Variable):
        _variable(out, obj, f"{obj.index:04X}")
    else:
        _composite(out, obj)


def _list_of(index: int) -> int:
    if index in (0x1000, 0x1001, 0x1018):
        return 0
    if 0x2000 <= index <= 0x5FFF:
        return 2
    return 1


def write(
    od: ObjectDictionary,
    *,
    dcf: bool,
    node_id: int | None = None,
    bitrate: int | None = None,
    file_info: FileInfo | None = None,
    device_info: DeviceInfo | None = None,
    dummy_usage: Mapping[int, bool] | None = None,
) -> str:
    """The text of ``od``; ``file_info``, ``device_info`` and ``dummy_usage`` replace the
    dictionary's own sections when given."""
    out: list[str] = []
    file = od.file_info if file_info is None else file_info
    _typed_section(out, "FileInfo", file, _FILE_INFO_KEYS)
    out.extend(f"{k}={v}" for k, v in file.extra.items())
    out.append("")

    info = od.device_info if device_info is None else device_info
    _typed_section(out, "DeviceInfo", info, _DEVICE_INFO_KEYS)
    for rate in sorted(set(STANDARD_BAUD_RATES) | info.baud_rates):
        out.append(f"BaudRate_{rate}={int(rate in info.baud_rates)}")
    out.extend(f"{k}={v}" for k, v in info.extra.items())
    out.append("")

    com: Commissioning | None = od.commissioning
    if dcf:
        chosen = node_id if node_id is not None else od.node_id
        bit_rate = bitrate if bitrate is not None else od.bitrate
        if com is not None or chosen is not None or bit_rate is not None:
            com = replace(com) if com is not None else Commissioning()
            com.extra = dict(com.extra)
            if chosen is not None:
                com.node_id = chosen
            if bit_rate is not None:
                com.baudrate = bit_rate // 1000
    if com is not None:
        _typed_section(out, com.section, com, _COMMISSIONING_KEYS)
        out.extend(f"{k}={v}" for k, v in com.extra.items())
        out.append("")

    dummies = od.dummy_usage if dummy_usage is None else dummy_usage
    if dummies or od.dummy_usage_extra or "DUMMYUSAGE" in od.file_comments:
        out.append("[DummyUsage]")
        out.extend(f"Dummy{code:04X}={int(on)}" for code, on in sorted(dummies.items()))
        out.extend(f"{k}={v}" for k, v in od.dummy_usage_extra.items())
        out.append("")

    if od.comments or od.comments_extra or "COMMENTS" in od.file_comments:
        out.append("[Comments]")
        out.append(f"Lines={len(od.comments)}")
        out.extend(f"Line{i}={text}" for i, text in enumerate(od.comments, 1))
        out.extend(f"{k}={v}" for k, v in od.comments_extra.items())
        out.append("")

    groups: list[list[Variable | Record | Array]] = [[], [], []]
    for obj in od:
        if obj.index in od._dummies:
            continue
        groups[_list_of(obj.index)].append(obj)
    for title, group in zip(
        ("MandatoryObjects", "OptionalObjects", "ManufacturerObjects"), groups, strict=True
    ):
        out.append(f"[{title}]")
        out.append(f"SupportedObjects={len(group)}")
        out.extend(f"{i}=0x{obj.index:04X}" for i, obj in enumerate(group, 1))
        out.append("")
        for obj in group:
            _object(out, obj)

    for name, items in od.extra_sections:
        out.append(f"[{name}]")
        out.extend(f"{k}={v}" for k, v in items)
        out.append("")
    if od.file_comments:
        out = _with_comments(out, od.file_comments)
    return "\n".join(out)


def _with_comments(
    lines: list[str], comments: dict[str, list[tuple[str | None, str]]]
) -> list[str]:
    """``lines`` with the file's comment lines put back: each in its section, after the key it
    followed (keys match without regard to case), those of a key no longer written at the end
    of their section. Read again, each comment follows the key it follows here, so writing the
    result again gives the same text.
    """
    out = [text for _, text in comments.get("", ())]
    pending: dict[str | None, list[str]] = {}  # the current section's comments not yet out
    for line in lines:
        if line[:1] == "[":
            for texts in pending.values():
                out.extend(texts)
            pending = {}
            out.append(line)
            for after, text in comments.get(line[1:-1].upper(), ()):
                pending.setdefault(None if after is None else after.lower(), []).append(text)
            out.extend(pending.pop(None, []))
        elif not pending:
            out.append(line)
        elif line:
            out.append(line)
            key = line.partition("=")[0].lower()
            if key in pending:
                out.extend(pending.pop(key))
        else:  # the blank line that ends the section
            for texts in pending.values():
                out.extend(texts)
            pending = {}
            out.append(line)
    for texts in pending.values():
        out.extend(texts)
    return out
