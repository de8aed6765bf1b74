"""One defect per file in tests/data/broken_eds: the exact error each one produces.

Every broken file is ``valid.eds`` with one thing broken, so each must produce exactly one
finding: an error at the stated line and section with the stated reason, raised as an
:class:`EdsError` in strict mode and recorded in ``od.findings`` in lenient mode.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from cobus.od import EdsError, Severity, load

BROKEN = Path(__file__).parent / "data" / "broken_eds"

# file -> (line, section, reason)
EXPECTED: dict[str, tuple[int, str | None, str]] = {
    "duplicate_sub_object.eds": (
        73,
        "1018sub1",
        "section [1018sub1] appears again (first at line 66); remove or merge the duplicate "
        "— this copy is ignored",
    ),
    "duplicate_object.eds": (
        133,
        "2001",
        "section [2001] appears again (first at line 125); remove or merge the duplicate "
        "— this copy is ignored",
    ),
    "duplicate_key.eds": (
        124,
        "2000",
        "key DefaultValue appears twice in the section (first at line 123); keep one — "
        "the first value is used",
    ),
    "missing_sub_object.eds": (
        57,
        "1018",
        "missing sub-object: SubNumber=4 declares 4 sub-objects but 3 are defined "
        "(after sub-index 2)",
    ),
    "sub_number_mismatch.eds": (
        57,
        "1018",
        "SubNumber mismatch: SubNumber=2 but 3 sub-objects are defined; set SubNumber=3",
    ),
    "orphan_sub_object.eds": (
        133,
        "2002sub1",
        "sub-object 0x2002sub1 has no object section [2002]; add the object or remove the "
        "sub-object",
    ),
    "value_out_of_range.eds": (
        131,
        "2001",
        "DefaultValue: '0x100' = 256 is out of range for UNSIGNED8 (0..255)",
    ),
    "default_outside_limits.eds": (123, "2000", "DefaultValue 1500 is above HighLimit 1000"),
    "limits_swapped.eds": (121, "2000", "LowLimit 1000 is above HighLimit 0"),
    "unknown_data_type.eds": (
        128,
        "2001",
        "unknown data type 0x0040: CiA 301 basic types are 0x0001..0x001B (handled as DOMAIN, "
        "raw bytes)",
    ),
    "missing_data_type.eds": (
        125,
        "2001",
        "DataType is missing: add e.g. DataType=0x0007 for UNSIGNED32 (handled as DOMAIN, "
        "raw bytes)",
    ),
    "unknown_access_type.eds": (
        129,
        "2001",
        "AccessType 'readonly' is unknown: use ro, wo, rw, rwr, rww or const (read as rw)",
    ),
    "bad_number_literal.eds": (
        123,
        "2000",
        "DefaultValue: bad number '5OO': expected a decimal, 0x-hex or 0-octal integer literal",
    ),
    "bad_octal_literal.eds": (
        123,
        "2000",
        "DefaultValue: bad number '0900': a leading 0 makes it octal (CiA 306), and 8 and 9 "
        "are not octal digits; drop the leading zeros for a decimal number",
    ),
    "bad_nodeid_expression.eds": (
        44,
        "1000",
        "DefaultValue: bad $NODEID expression '$NODEID*2': only $NODEID+offset is allowed",
    ),
    "malformed_section_header.eds": (
        133,
        None,
        "malformed section header '[2002': write it as [name] on its own line",
    ),
    "pdo_not_mappable.eds": (
        108,
        "1A00sub2",
        "TPDO mapping entry 2 maps 0x2001sub0 ('Status'), which is not PDO-mappable (PDOMapping=0)",
    ),
    "pdo_not_mappable_sub.eds": (
        108,
        "1A00sub2",
        "TPDO mapping entry 2 maps 0x1018sub2 ('Product code'), which is not PDO-mappable "
        "(PDOMapping=0)",
    ),
    "pdo_over_64_bits.eds": (
        94,
        "1A00sub0",
        "TPDO mapping 0x1A00 maps 72 bits; a PDO carries at most 64",
    ),
    "pdo_wrong_length.eds": (
        108,
        "1A00sub2",
        "TPDO mapping entry 2 maps 0x2001sub0 with 16 bits but it is UNSIGNED8 (8 bits)",
    ),
    "pdo_unknown_object.eds": (
        108,
        "1A00sub2",
        "TPDO mapping entry 2 maps 0x2002sub0, which is not in the dictionary",
    ),
}

# What the reported line says: the finding points at the defect itself.
AT_LINE = {
    "bad_nodeid_expression.eds": "DefaultValue=$NODEID*2",
    "bad_number_literal.eds": "DefaultValue=5OO",
    "bad_octal_literal.eds": "DefaultValue=0900",
    "default_outside_limits.eds": "DefaultValue=1500",
    "duplicate_key.eds": "DefaultValue=600",
    "duplicate_object.eds": "[2001]",
    "duplicate_sub_object.eds": "[1018sub1]",
    "limits_swapped.eds": "LowLimit=1000",
    "malformed_section_header.eds": "[2002",
    "missing_data_type.eds": "[2001]",
    "missing_sub_object.eds": "SubNumber=4",
    "orphan_sub_object.eds": "[2002sub1]",
    "pdo_not_mappable.eds": "DefaultValue=0x20010008",
    "pdo_not_mappable_sub.eds": "DefaultValue=0x10180220",
    "pdo_over_64_bits.eds": "DefaultValue=3",
    "pdo_unknown_object.eds": "DefaultValue=0x20020008",
    "pdo_wrong_length.eds": "DefaultValue=0x20010010",
    "sub_number_mismatch.eds": "SubNumber=2",
    "unknown_access_type.eds": "AccessType=readonly",
    "unknown_data_type.eds": "DataType=0x0040",
    "value_out_of_range.eds": "DefaultValue=0x100",
}


def test_every_broken_file_is_listed_and_small():
    files = {p.name for p in BROKEN.glob("*.eds")}
    assert files == {*EXPECTED, "valid.eds"} and set(AT_LINE) == set(EXPECTED)
    for path in BROKEN.glob("*.eds"):
        assert path.stat().st_size < 4000, path.name


def test_the_base_file_is_clean():
    od = load(BROKEN / "valid.eds", strict=True)
    assert od.findings == []
    assert len(od) == 7 and od.get_variable(0x1A00, 2) is not None


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_lenient_reports_exactly_the_defect(name: str):
    path = BROKEN / name
    line, section, reason = EXPECTED[name]
    od = load(path)
    assert [(f.line, f.section, f.severity, f.reason) for f in od.findings] == [
        (line, section, Severity.ERROR, reason)
    ]
    header = f"[{section}] " if section else ""
    assert str(od.findings[0]) == f"{path}:{line}: {header}error: {reason}"
    assert path.read_text().splitlines()[line - 1] == AT_LINE[name]


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_strict_raises_the_defect(name: str):
    path = BROKEN / name
    line, section, reason = EXPECTED[name]
    with pytest.raises(EdsError) as info:
        load(path, strict=True)
    err = info.value
    assert (err.path, err.line, err.section, err.reason) == (str(path), line, section, reason)
    assert str(err) == f"{path}:{line}: " + (f"[{section}] " if section else "") + reason
