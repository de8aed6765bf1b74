"""The object dictionary model built in code: lookups, limits, node ids, comparison."""

import pytest

from cobus.errors import CobusError
from cobus.od import (
    Access,
    Array,
    DataType,
    ObjectDictionary,
    ObjectDictionaryError,
    ObjectType,
    Record,
    TimeOfDay,
    ValueRangeError,
    Variable,
    loads,
)


def _var(od: ObjectDictionary, index: int, sub: int = 0) -> Variable:
    var = od.get_variable(index, sub)
    assert var is not None
    return var


def _rec(od: ObjectDictionary, index: int) -> Record:
    rec = od[index]
    assert isinstance(rec, Record)
    return rec


def _identity() -> Record:
    rec = Record(0x1018, "Identity object")
    rec.add(Variable(0x1018, 0, "Highest sub-index supported", DataType.UNSIGNED8, Access.CONST))
    rec.add(Variable(0x1018, 1, "Vendor-ID", DataType.UNSIGNED32, Access.RO, default=0x360))
    return rec


def _od() -> ObjectDictionary:
    od = ObjectDictionary()
    od.add(Variable(0x2000, 0, "Speed", DataType.INTEGER16, Access.RW, True, default=5))
    od.add(Variable(0x1000, 0, "Device type", DataType.UNSIGNED32, Access.RO, default=0x20192))
    od.add(_identity())
    return od


def test_access_types():
    assert [a.value for a in Access] == ["ro", "wo", "rw", "rwr", "rww", "const"]
    readable = {a for a in Access if a.readable}
    writable = {a for a in Access if a.writable}
    assert readable == {Access.RO, Access.RW, Access.RWR, Access.RWW, Access.CONST}
    assert writable == {Access.WO, Access.RW, Access.RWR, Access.RWW}


def test_object_type_codes():
    assert {o.name: int(o) for o in ObjectType} == {
        "NULL": 0,
        "DOMAIN": 2,
        "DEFTYPE": 5,
        "DEFSTRUCT": 6,
        "VAR": 7,
        "ARRAY": 8,
        "RECORD": 9,
    }


def test_lookup_by_number_and_name():
    od = _od()
    assert [o.index for o in od] == [0x1000, 0x1018, 0x2000]  # index order, not insertion
    assert len(od) == 3 and 0x1018 in od and "Speed" in od and 0x1234 not in od
    var = od[0x1000]
    assert isinstance(var, Variable) and var.default == 0x20192
    assert od.get_variable(0x1000, 0) is var
    assert od.get_variable(0x1000, 1) is None
    identity = od["Identity object"]
    assert isinstance(identity, Record)
    assert od.get_variable(0x1018, 1) is identity["Vendor-ID"]
    assert _rec(od, 0x1018)[1].default == 0x360
    assert od.get_variable(0x1234) is None
    assert [v.qualname for v in od.variables()] == [
        "0x1000",
        "0x1018sub0",
        "0x1018sub1",
        "0x2000",
    ]
    rec = od[0x1018]
    assert isinstance(rec, Record) and len(rec) == 2 and 1 in rec and "Vendor-ID" in rec
    assert [v.subindex for v in rec] == [0, 1]


def test_lookup_errors_are_typed_key_errors():
    od = _od()
    with pytest.raises(ObjectDictionaryError, match="no object 0x1234"):
        od[0x1234]
    with pytest.raises(KeyError):
        od["nothing"]
    with pytest.raises(ObjectDictionaryError, match="has no sub-object 7"):
        _rec(od, 0x1018)[7]
    with pytest.raises(ObjectDictionaryError, match="already has an object 0x1000"):
        od.add(Variable(0x1000, 0, "again", DataType.UNSIGNED8))
    with pytest.raises(ObjectDictionaryError, match="already has sub-index 1"):
        _rec(od, 0x1018).add(Variable(0x1018, 1, "again", DataType.UNSIGNED8))
    assert issubclass(ObjectDictionaryError, CobusError)


def test_ambiguous_names_say_which_indices():
    od = ObjectDictionary()
    od.add(Variable(0x5800, 0, "Remote PDO", DataType.UNSIGNED32))
    od.add(Variable(0x5801, 0, "Remote PDO", DataType.UNSIGNED32))
    with pytest.raises(ObjectDictionaryError, match="used by 0x5800, 0x5801; use the index"):
        od["Remote PDO"]
    od.remove(0x5801)
    assert od["Remote PDO"].index == 0x5800
    arr = Array(0x1003, "Errors")
    arr.add(Variable(0x1003, 1, "Error", DataType.UNSIGNED32))
    arr.add(Variable(0x1003, 2, "Error", DataType.UNSIGNED32))
    with pytest.raises(ObjectDictionaryError, match="sub-indices 1, 2"):
        arr["Error"]


def test_encode_checks_type_and_limits():
    var = Variable(0x2000, 0, "Speed", DataType.INTEGER16, low_limit=-100, high_limit=100)
    assert var.encode(-100) == b"\x9c\xff"
    assert var.decode(b"\x64\x00") == 100
    with pytest.raises(ValueRangeError, match=r"101 is above the HighLimit 100 of 'Speed'"):
        var.encode(101)
    with pytest.raises(ValueRangeError, match=r"-101 is below the LowLimit -100"):
        var.decode(b"\x9b\xff")
    with pytest.raises(ValueRangeError, match="INTEGER16"):
        var.check(40_000)
    var.check(0)
    assert var.bit_length == 16
    assert Variable(1, 0, "s", DataType.VISIBLE_STRING).bit_length is None


def test_default_and_parameter_value():
    var = Variable(0x2000, 0, "Speed", DataType.UNSIGNED8, default=3)
    before = var.parameter_value
    assert var.value == 3 and before is None
    var.value = 9
    assert var.parameter_value == 9 and var.value == 9 and var.default == 3
    with pytest.raises(ValueRangeError, match="UNSIGNED8"):
        var.default = 300
    var.high_limit = 10
    with pytest.raises(ValueRangeError, match="HighLimit 10"):
        var.value = 11


def test_node_id_resolves_relative_values():
    od = loads(
        "[1014]\nParameterName=COB-ID EMCY\nDataType=0x0007\nAccessType=rw\n"
        "DefaultValue=$NODEID+0x80\n"
    )
    var = od[0x1014]
    assert isinstance(var, Variable)
    unresolved, relative = var.default, var.relative
    assert od.node_id is None and unresolved is None and relative
    od.node_id = 5
    assert var.default == 0x85
    od.node_id = 0x7F
    assert var.default == 0xFF
    assert str(var.default_raw) == "$NODEID+0x80"
    with pytest.raises(ValueRangeError, match=r"node id 128 is outside 1\.\.127"):
        od.node_id = 128
    var.default = 0x123  # set in code: no longer relative
    raw_after, relative_after = var.default_raw, var.relative
    assert not relative_after and raw_after is None
    od.node_id = 1
    assert var.default == 0x123


def test_diff_and_equality():
    a, b = _od(), _od()
    assert a == b and a.diff(b) == []
    _var(b, 0x1018, 1).default = 0x361
    _var(b, 0x2000).access = Access.RO
    assert a != b
    assert a.diff(b) == [
        "0x1018sub1: default 864 != 865",
        "0x2000: access <Access.RW: 'rw'> != <Access.RO: 'ro'>",
    ]
    b.remove(0x2000)
    assert "0x2000: only in the first dictionary" in a.diff(b)
    nan_a, nan_b = ObjectDictionary(), ObjectDictionary()
    for od in (nan_a, nan_b):
        od.add(Variable(0x2100, 0, "x", DataType.REAL32, default=float("nan")))
    assert nan_a == nan_b  # NaN defaults compare equal


def test_a_dictionary_built_in_code_writes_and_reads_back():
    od = _od()
    od.add(Variable(0x2001, 0, "t", DataType.TIME_OF_DAY, default=TimeOfDay(1, 2)))
    od.add(Variable(0x2002, 0, "s", DataType.VISIBLE_STRING, default=" padded"))
    od.add(Variable(0x2003, 0, "f", DataType.REAL32, default=float("inf"), low_limit=0.0))
    od.add(Variable(0x2004, 0, "o", DataType.OCTET_STRING, default=b"\x01\x02"))
    od.add(Variable(0x2005, 0, "b", DataType.BOOLEAN, default=True))
    od.add(Variable(0x2006, 0, "u", DataType.UNICODE_STRING, default="ü"))
    again = loads(od.to_eds())
    assert again.findings == [] and again.diff(od) == []
    assert 'DefaultValue=" padded"' in od.to_eds()  # quoted: the spaces are the value
