"""A node's start-up SDO list: what the master writes at its boot, derived from its dictionary.

Every writable object whose configured value differs from the EDS default, then the PDOs in
the order of CiA 301's mapping procedure as :func:`cobus.proto.pdo.in_remap_order` gives it
(disable, clear, map, count, enable); a device with direct mapping gets every entry written.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from cobus.errors import CobusError
from cobus.master.config.model import ERROR_CONTROL, INVALID, RESTORE, SAVE, NodeConfig, SdoEntry
from cobus.od import (
    Array,
    Record,
    ValueRangeError,
    Variable,
    encode,
)
from cobus.proto.pdo import (
    RemapStep,
    in_remap_order,
)

__all__ = ["direct_mapping", "startup_list", "sub_value"]


def sub_value(obj: Record | Array, sub: int, default: int) -> int:
    """The integer value of ``obj``'s sub-index ``sub`` (``default`` if it has none)."""
    var = obj.get(sub)
    value = var.value if var is not None else None
    return value if isinstance(value, int) else default


def direct_mapping(mapping: Record | Array) -> bool:
    """Whether a PDO mapping is written directly: sub-index 0 is a read-only constant count
    and every entry is writable (0 = unused), as the STÖBER MDS 5000 of seed 004 does."""
    count = mapping.get(0)
    entries = [v for v in mapping if v.subindex]
    if count is None or count.writable or not entries:
        return False
    return all(v.writable for v in entries)


def _differs(var: Variable) -> bool:
    return var.parameter_value is not None and var.parameter_value != var.default


#: ``bad(variable, value, error, fatal)``: a value the object cannot hold (fatal) or that
#: lies outside its EDS limits (written anyway).
_Bad_value = Callable[[Variable, Any, Exception, bool], None]


class _Writes:
    """Collects start-up writes; a value the object cannot hold is reported, not written."""

    def __init__(self, bad: _Bad_value) -> None:
        self.entries: list[SdoEntry] = []
        self._bad = bad

    def add(self, var: Variable, value: Any, name: str) -> None:
        try:
            data = var.encode(value)
        except ValueRangeError as exc:
            try:  # within the type but outside the EDS limits: the device decides
                data = encode(var.data_type, value)
            except CobusError:
                self._bad(var, value, exc, True)
                return
            self._bad(var, value, exc, False)
        except CobusError as exc:
            self._bad(var, value, exc, True)
            return
        self.entries.append(SdoEntry(var.index, var.subindex, data, value, name))


def startup_list(
    cfg: NodeConfig,
    yaml_set: set[tuple[int, int]],
    explicit: list[SdoEntry],
    bad: _Bad_value,
) -> list[SdoEntry]:
    """The start-up SDO list of a node (see the module text)."""
    od = cfg.od
    skip = {(e.index, e.subindex) for e in explicit}

    def wanted(var: Variable) -> bool:
        if (var.index, var.subindex) in skip or not var.writable:
            return False
        if not cfg.sdo_from_dcf and (var.index, var.subindex) not in yaml_set:
            return False
        return _differs(var)

    plain: list[Variable] = []
    for var in od.variables():
        index = var.index
        if index < 0x1000 or 0x1400 <= index <= 0x1BFF:
            continue
        if index in (SAVE, RESTORE) or index in ERROR_CONTROL:
            continue
        if wanted(var):
            plain.append(var)
    # 1019h may only change while 1006h is 0: write it first
    plain.sort(key=lambda v: (0x1005 if v.index == 0x1019 else v.index, v.index, v.subindex))
    writes = _Writes(bad)
    for var in plain:
        writes.add(var, var.value, var.name)
    for comm_base, map_base, kind in ((0x1400, 0x1600, "RPDO"), (0x1800, 0x1A00, "TPDO")):
        for number in range(1, 513):
            comm = od.get(comm_base + number - 1)
            mapping = od.get(map_base + number - 1)
            if not isinstance(comm, Record | Array):
                continue
            _pdo_steps(cfg, comm, mapping, f"{kind} {number}", wanted, writes)
    return [*writes.entries, *explicit]


def _pdo_steps(
    cfg: NodeConfig,
    comm: Record | Array,
    mapping: Any,
    label: str,
    wanted: Callable[[Variable], bool],
    writes: _Writes,
) -> None:
    """The writes that (re)configure one PDO in the order CiA 301 wants: disable, clear the
    mapping, map, count, communication parameters, enable."""
    all_pdo = cfg.sdo_all_pdo
    comm_subs = [comm.get(s) for s in (2, 3, 5, 6)]
    map_vars = list(mapping) if isinstance(mapping, Record | Array) else []
    cob = comm.get(1)
    map_changed = all_pdo or any(wanted(v) for v in map_vars)
    comm_changed = all_pdo or any(v is not None and wanted(v) for v in comm_subs)
    cob_changed = cob is not None and (all_pdo or wanted(cob))
    if not (map_changed or comm_changed or cob_changed) or cob is None:
        return
    final = cob.value
    if not isinstance(final, int):
        return
    step = RemapStep
    steps: list[tuple[RemapStep, tuple[Variable, int, str]]] = []
    if cob.writable:
        steps.append((step.DISABLE, (cob, final | INVALID, f"{label}: disable")))
    if map_changed and isinstance(mapping, Record | Array):
        count_var = mapping.get(0)
        count = count_var.value if count_var is not None else None
        if count_var is not None and count_var.writable and isinstance(count, int):
            steps.append((step.CLEAR_MAPPING, (count_var, 0, f"{label}: clear mapping")))
            for sub in sorted(k for k in mapping.subindices if 1 <= k <= count):
                var = mapping.get(sub)  # (the sub-indexes there are: a count may be damaged)
                if var is not None and isinstance(var.value, int):
                    steps.append((step.MAP, (var, var.value, f"{label}: map")))
            steps.append((step.COUNT, (count_var, count, f"{label}: mapped objects")))
        elif direct_mapping(mapping):
            for var in map_vars:
                if var.subindex and isinstance(var.value, int):
                    steps.append((step.MAP, (var, var.value, f"{label}: map")))
    for var in comm_subs:
        if var is None or not var.writable or not isinstance(var.value, int):
            continue
        if all_pdo or wanted(var):
            steps.append((step.COMMUNICATION, (var, var.value, f"{label}: {var.name}")))
    if cob.writable and not final & INVALID:
        steps.append((step.ENABLE, (cob, final, f"{label}: enable")))
    for var, value, name in in_remap_order(steps):
        writes.add(var, value, name)
