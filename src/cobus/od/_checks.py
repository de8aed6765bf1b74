"""Checks that need the whole dictionary: PDO mapping entries (CiA 301 §7.5.2.36 ff.)."""

from __future__ import annotations

from collections.abc import Callable

from cobus.od._errors import Finding, Severity
from cobus.od._model import Array, ObjectDictionary, Record, Variable

__all__ = ["Report", "check_dictionary", "mapping_entries", "validate"]

#: ``report(severity, object_or_variable, key_or_None, reason)``
Report = Callable[[Severity, object, "str | None", str], None]
Locate = Callable[[object, "str | None"], "tuple[int | None, str | None]"]

#: RPDO and TPDO mapping parameter ranges.
RPDO_MAPPING = range(0x1600, 0x1800)
TPDO_MAPPING = range(0x1A00, 0x1C00)
MAX_PDO_BITS = 64


def mapping_entries(obj: Record | Array) -> list[tuple[Variable, int, int, int]]:
    """The active entries of a PDO mapping object: ``(entry, index, subindex, bits)``.

    Sub-index 0 (its ParameterValue, else its default) says how many entries are active;
    without it every entry that maps something counts.
    """
    count_var = obj.subindices.get(0)
    count = count_var.value if count_var is not None else None
    out = []
    subs = obj.subindices
    # (only the sub-indexes that exist: a damaged count of 4 billion must not loop 4 billion
    # times - the fuzzer's mapping whose sub 0 became a huge number took 97 s)
    last = count if isinstance(count, int) else max(subs, default=0)
    for sub in sorted(k for k in subs if 1 <= k <= last):
        var = subs[sub]
        value = var.value
        if not isinstance(value, int) or (value == 0 and not isinstance(count, int)):
            continue
        out.append((var, (value >> 16) & 0xFFFF, (value >> 8) & 0xFF, value & 0xFF))
    return out


def _key(var: Variable) -> str:
    return "DefaultValue" if var.parameter_value is None else "ParameterValue"


def check_dictionary(od: ObjectDictionary, report: Report, locate: Locate | None = None) -> None:
    """Report what is wrong with the PDO mapping objects of ``od``."""
    del locate
    for obj in od:
        index = obj.index
        if index < 0x1600 or not (index in RPDO_MAPPING or index in TPDO_MAPPING):
            continue
        if isinstance(obj, Variable):
            report(
                Severity.ERROR,
                obj,
                None,
                f"PDO mapping object 0x{index:04X} must be a RECORD with sub-objects",
            )
            continue
        _check_mapping(od, obj, report)


def _check_mapping(od: ObjectDictionary, obj: Record | Array, report: Report) -> None:
    receive = obj.index in RPDO_MAPPING
    kind = "RPDO" if receive else "TPDO"
    count_var = obj.subindices.get(0)
    count = count_var.value if count_var is not None else None
    if isinstance(count, int):
        if count > 0x40:
            assert count_var is not None
            report(
                Severity.ERROR,
                count_var,
                _key(count_var),
                f"{kind} mapping counts {count} entries; a PDO maps at most 64",
            )
            return
        for sub in range(1, count + 1):
            if sub not in obj.subindices:
                assert count_var is not None
                report(
                    Severity.ERROR,
                    count_var,
                    _key(count_var),
                    f"sub-index 0 counts {count} mapped objects but entry {sub} is not defined",
                )
                return
    total = 0
    for entry, index, subindex, bits in mapping_entries(obj):
        where = f"0x{index:04X}sub{subindex:X}"
        key = _key(entry)
        if index == 0 and subindex == 0 and bits == 0:
            report(
                Severity.WARNING,
                entry,
                key,
                f"entry {entry.subindex} maps nothing (0) but sub-index 0 counts it",
            )
            continue
        total += bits
        target = od.get_variable(index, subindex)
        if target is None:
            hint = ""
            if index < 0x20:
                hint = f" (a dummy entry needs Dummy{index:04X}=1 in [DummyUsage])"
            report(
                Severity.ERROR,
                entry,
                key,
                f"{kind} mapping entry {entry.subindex} maps {where}, which is not in the "
                f"dictionary{hint}",
            )
            continue
        if not target.pdo_mappable:
            report(
                Severity.ERROR,
                entry,
                key,
                f"{kind} mapping entry {entry.subindex} maps {where} ({target.name!r}), which "
                "is not PDO-mappable (PDOMapping=0)",
            )
            continue
        expected = target.bit_length
        if expected is not None and bits != expected:
            report(
                Severity.ERROR,
                entry,
                key,
                f"{kind} mapping entry {entry.subindex} maps {where} with {bits} bits but it is "
                f"{target.data_type.name} ({expected} bits)",
            )
        elif receive and not target.access.writable:
            report(
                Severity.WARNING,
                entry,
                key,
                f"RPDO mapping entry {entry.subindex} maps {where}, which is not writable "
                f"({target.access})",
            )
        elif not receive and not target.access.readable:
            report(
                Severity.WARNING,
                entry,
                key,
                f"TPDO mapping entry {entry.subindex} maps {where}, which is not readable "
                f"({target.access})",
            )
    if total > MAX_PDO_BITS:
        target_var = count_var if count_var is not None else next(iter(obj))
        report(
            Severity.ERROR,
            target_var,
            _key(target_var),
            f"{kind} mapping 0x{obj.index:04X} maps {total} bits; a PDO carries at most 64",
        )


def validate(od: ObjectDictionary) -> list[Finding]:
    """Check a dictionary built or changed in code (PDO mappings); the findings, line-less
    unless the objects came from a file."""
    path = od.path or "<dictionary>"
    out: list[Finding] = []

    def report(severity: Severity, obj: object, key: str | None, reason: str) -> None:
        del key
        section = None
        if isinstance(obj, Variable):
            section = f"{obj.index:04X}" + ("" if obj.parent is None else f"sub{obj.subindex:X}")
        out.append(Finding(path, getattr(obj, "line", None), section, severity, reason))

    check_dictionary(od, report)
    return out
