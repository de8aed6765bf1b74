"""What we read from each corpus file agrees with python-canopen (a test-only peer).

For every file: the same object indices, the same kind of object (VAR/RECORD/ARRAY), and for
every variable python-canopen has, the same data type, access type, default and
ParameterValue. Where the two disagree because python-canopen (2.4) reads the file wrongly,
the difference is listed below, one rule per known difference with its reason; the test
checks that every difference is explained and that every rule listed for a file is needed.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from cobus.od import DataType, ObjectDictionary, Variable, load
from tests.conftest import EDS_DIR, corpus_files
from tests.util import need_module

canopen = need_module("canopen", "python-canopen (the interoperability peer) is not installed")
pytestmark = pytest.mark.interop


@dataclass(frozen=True)
class Seen:
    """One disagreement: ``field`` of ``ours`` is ``mine`` here and ``theirs`` in canopen."""

    od: ObjectDictionary
    index: int
    ours: Variable | None
    field: str
    mine: Any
    theirs: Any


@dataclass(frozen=True)
class Known:
    reason: str
    applies: Callable[[Seen], bool]


def _raw(seen: Seen) -> str:
    var = seen.ours
    assert var is not None
    text = var.default_raw if seen.field == "default" else var.parameter_value_raw
    return (text or "").strip()


def _compact_sub0(s: Seen) -> bool:
    var = s.ours
    return (
        var is not None
        and var.parent is not None
        and var.parent.compact is not None
        and var.subindex == 0
        and (
            (s.field == "access" and s.theirs == "rw" and s.mine == "ro")
            or (s.field == "default" and s.theirs is None and s.mine == var.parent.compact)
        )
    )


def _value_section(s: Seen) -> bool:
    var = s.ours
    return (
        s.field == "value"
        and var is not None
        and var.parent is not None
        and var.parent.compact is not None
        and s.theirs is None
        and s.mine is not None
    )


def _signed_hex(s: Seen) -> bool:
    var = s.ours
    if var is None or s.field not in ("default", "value") or not var.data_type.is_signed:
        return False
    bits = var.data_type.bit_length
    assert bits is not None
    return _raw(s).lower().startswith("0x") and s.theirs == s.mine + (1 << bits)


def _hex_prefixed_octets(s: Seen) -> bool:
    var = s.ours
    return (
        var is not None
        and var.data_type in (DataType.DOMAIN, DataType.OCTET_STRING)
        and s.theirs is None
        and _raw(s).lower().startswith("0x")
        and s.mine == bytes.fromhex(_raw(s)[2:])
    )


def _real_bits(s: Seen) -> bool:
    var = s.ours
    return (
        var is not None
        and var.data_type.is_real
        and s.theirs is None
        and _raw(s).lower().startswith("0x")
    )


def _quoted(s: Seen) -> bool:
    return isinstance(s.mine, str) and s.theirs == f'"{s.mine}"'


def _time_text(s: Seen) -> bool:
    var = s.ours
    return (
        var is not None
        and var.data_type in (DataType.TIME_OF_DAY, DataType.TIME_DIFFERENCE)
        and s.theirs == int(_raw(s).replace(" ", ""))
    )


def _extended_dummies(s: Seen) -> bool:
    return (
        s.field == "index"
        and s.theirs is None
        and 0x08 <= s.index <= 0x1B
        and s.od.dummy_usage.get(s.index) is True
    )


KNOWN: dict[str, Known] = {
    "compact-sub0": Known(
        "sub-index 0 of a CompactSubObj object: python-canopen makes it rw without a default; "
        "CiA 306 makes it NrOfObjects, ro, DefaultValue = the CompactSubObj count",
        _compact_sub0,
    ),
    "value-section": Known(
        "python-canopen ignores [xxxxValue] sections (CiA 306 ParameterValue of compact "
        "sub-objects in a DCF)",
        _value_section,
    ),
    "signed-hex": Known(
        "a DefaultValue/ParameterValue of a signed type written as hex bits (0xFF9C for "
        "INTEGER16): python-canopen keeps the unsigned number, which the type cannot hold "
        "(it converts only LowLimit/HighLimit)",
        _signed_hex,
    ),
    "0x-octets": Known(
        "DOMAIN/OCTET_STRING bytes written with a 0x prefix: bytes.fromhex fails in "
        "python-canopen, which drops the value",
        _hex_prefixed_octets,
    ),
    "real-bits": Known(
        "REAL32/REAL64 written as raw IEEE bits in hex (Lely): float() fails in "
        "python-canopen, which drops the value",
        _real_bits,
    ),
    "quoted-string": Known(
        'a quoted string ("Hello, World!", Lely): python-canopen keeps the quotes',
        _quoted,
    ),
    "time-text": Known(
        'TIME_OF_DAY/TIME_DIFFERENCE "days ms": python-canopen deletes the space and reads '
        "one integer",
        _time_text,
    ),
    "dummies-above-7": Known(
        "[DummyUsage] entries Dummy0008..Dummy001B: python-canopen only reads Dummy0001.."
        "Dummy0007, so it lacks the dummy objects of the longer types",
        _extended_dummies,
    ),
}

# Which known differences each file shows (a file not listed agrees completely).
EXPECTED_RULES: dict[str, set[str]] = {
    "canopen-python_sample.eds": {"compact-sub0"},
    "lely_co-sdev.dcf": {"real-bits", "quoted-string", "time-text"},
    "lely_coctl.dcf": {"compact-sub0", "dummies-above-7"},
    "roscanopen_master.dcf": {"compact-sub0", "value-section", "dummies-above-7"},
    "sevcon_gen4.eds": {"signed-hex", "0x-octets"},
    "sevcon_2019-06-24-moteur-uk0319-55-110v-300a-s4-gen4-config-origine.dcf": {
        "signed-hex",
        "0x-octets",
    },
}

# Files python-canopen cannot load at all: the smallest edits that let it, and why.
PATCHES: dict[str, tuple[list[tuple[str, str]], str]] = {
    "canopennode_ds301_profile.eds": (
        [("VendorNumber=\n", ""), ("ProductNumber=\n", "")],
        "[DeviceInfo] VendorNumber= and ProductNumber= are empty: int('', 0) raises",
    ),
    "canopennode_io.eds": (
        [("line5=", "Line5=")],
        "[Comments] key line5 is lowercase: python-canopen looks up Line5 case-sensitively",
    ),
    "lely_coctl.dcf": (
        [("[DummyUsage]\n", "[DummyUsage]\nDummy0001=0\n")],
        "[DummyUsage] lacks Dummy0001: python-canopen requires all of Dummy0001..0007",
    ),
}


def _canopen_source(path: Path, tmp_path: Path) -> Path:
    patch = PATCHES.get(path.name)
    if patch is None:
        return path
    edits, _reason = patch
    text = path.read_text(encoding="latin-1").replace("\r\n", "\n")
    for old, new in edits:
        assert text.count(old) == 1, f"the patch of {path.name} no longer applies"
        text = text.replace(old, new)
    copy = tmp_path / path.name
    copy.write_text(text, encoding="latin-1")
    return copy


def _their_vars(obj: Any) -> dict[int, Any]:
    if isinstance(obj, canopen.objectdictionary.ODVariable):
        return {0: obj}
    return dict(obj.subindices)


def _kind(obj: Any) -> str:
    return {
        canopen.objectdictionary.ODVariable: "Variable",
        canopen.objectdictionary.ODRecord: "Record",
        canopen.objectdictionary.ODArray: "Array",
    }[type(obj)]


def _same(a: Any, b: Any) -> bool:
    return bool(a == b) or (a != a and b != b)  # NaN


def disagreements(path: Path, tmp_path: Path) -> tuple[list[Seen], int, int]:
    """Every disagreement of the object sets, object kinds and canopen's variables, and the
    object counts (ours, canopen's)."""
    ours = load(path)
    logging.disable(logging.WARNING)
    try:
        theirs = canopen.import_od(str(_canopen_source(path, tmp_path)), node_id=ours.node_id)
    finally:
        logging.disable(logging.NOTSET)
    assert len(theirs) > 20
    seen: list[Seen] = []
    mine_indices = {obj.index for obj in ours}
    for index in sorted(mine_indices ^ set(theirs.indices)):
        seen.append(Seen(ours, index, None, "index", index in mine_indices, None))
    for index in sorted(mine_indices & set(theirs.indices)):
        their_obj = theirs.indices[index]
        my_obj = ours[index]
        if type(my_obj).__name__ != _kind(their_obj):
            seen.append(Seen(ours, index, None, "kind", type(my_obj).__name__, _kind(their_obj)))
            continue
        for sub, their in _their_vars(their_obj).items():
            mine = ours.get_variable(index, sub)
            if mine is None:
                seen.append(Seen(ours, index, None, f"sub {sub}", None, their.name))
                continue
            for field, a, b in (
                ("data_type", int(mine.data_type), their.data_type),
                ("access", mine.access.value, their.access_type),
                ("default", mine.default, their.default),
                ("value", mine.parameter_value, their.value),
            ):
                if not _same(a, b):
                    seen.append(Seen(ours, index, mine, field, a, b))
    return seen, len(ours), len(theirs)


@pytest.mark.parametrize("path", corpus_files(), ids=lambda p: p.name)
def test_agrees_with_python_canopen(path: Path, tmp_path: Path):
    used: set[str] = set()
    unexplained = []
    found, count, their_count = disagreements(path, tmp_path)
    extra_dummies = sum(1 for seen in found if _extended_dummies(seen))
    assert count == their_count + extra_dummies
    for seen in found:
        rules = [name for name, known in KNOWN.items() if known.applies(seen)]
        if not rules:
            where = f"0x{seen.index:04X}" + (
                f"sub{seen.ours.subindex}" if seen.ours is not None else ""
            )
            unexplained.append(
                f"{where} {seen.field}: cobus {seen.mine!r}, canopen {seen.theirs!r}"
            )
        used.update(rules)
    assert unexplained == []
    assert used == EXPECTED_RULES.get(path.name, set())


def test_patches_are_needed():
    """python-canopen really fails on the unpatched files (else drop the patch)."""
    for name in PATCHES:
        logging.disable(logging.WARNING)
        try:
            with pytest.raises(Exception):  # noqa: B017 - whatever python-canopen raises
                canopen.import_od(str(EDS_DIR / name))
        finally:
            logging.disable(logging.NOTSET)
