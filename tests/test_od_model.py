"""The object dictionary model built in code: lookups, limits, node ids, comparison."""

import pytest

from cobus.errors import CobusError
from cobus.od import (
    Access,
    Array,
    DataType,
    DataTypeError,
    NodeRelative,
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


def _relative(var: Variable) -> tuple[bool, str | None]:
    return var.relative, var.default_raw


def _cob_id(default=None, **kw) -> Variable:
    return Variable(0x1014, 0, "COB-ID EMCY", DataType.UNSIGNED32, default=default, **kw)


def test_a_node_relative_default_built_in_code_follows_the_node_id():
    emcy = _cob_id(NodeRelative(0x80))
    assert emcy.relative and [emcy.default] == [None]  # in no dictionary yet
    assert emcy.default_raw == "$NODEID+0x80" == str(NodeRelative(0x80))
    od = _od()
    od.node_id = 5
    od.add(emcy)
    assert emcy.default == 0x85 and emcy.value == 0x85  # resolved when added
    od.node_id = 0x7F
    assert emcy.default == 0xFF
    eds = od.to_eds()
    assert "DefaultValue=$NODEID+0x80" in eds
    again = loads(eds, node_id=0x7F)
    assert again.findings == [] and again.diff(od) == []
    again_var = _var(again, 0x1014)
    assert again_var.relative and again_var.default == 0xFF
    assert _var(loads(eds), 0x1014).default is None  # no node-ID in the file
    emcy.default = 0x90  # a plain value again
    assert _relative(emcy) == (False, None)
    od.node_id = 3
    assert emcy.default == 0x90


def test_node_relative_values_set_on_objects_already_in_a_dictionary():
    od = _od()
    od.node_id = 10
    pdo = Record(0x1800, "TPDO 1")
    od.add(pdo)
    cob_id = Variable(0x1800, 1, "COB-ID", DataType.UNSIGNED32, default=NodeRelative(0x180))
    pdo.add(cob_id)
    assert cob_id.default == 0x18A  # resolved when added to a record in the dictionary
    speed = _var(od, 0x2000)
    speed.parameter_value = NodeRelative(1)
    assert speed.value == 11 and speed.parameter_value_raw == "$NODEID+0x1" and speed.default == 5
    vendor = _var(od, 0x1018, 1)
    vendor.low_limit = NodeRelative(0)
    vendor.high_limit = NodeRelative(0x100)
    assert (vendor.low_limit, vendor.high_limit) == (10, 0x10A)
    od.node_id = 1
    assert (speed.value, vendor.low_limit, vendor.high_limit, cob_id.default) == (
        2,
        1,
        0x101,
        0x181,
    )
    again = loads(od.to_eds(), node_id=1)
    assert again.diff(od) == []
    removed = od.remove(0x2000)
    assert isinstance(removed, Variable)
    removed.default = NodeRelative(2)
    assert removed.default is None  # in no dictionary: no node-ID to follow


def test_node_relative_values_that_cannot_follow_the_node_id_are_refused():
    for bad in (-1, True, 128.0):
        with pytest.raises(ValueRangeError, match="must be an int >= 0"):
            NodeRelative(bad)  # type: ignore[arg-type]
    real = Variable(0x2100, 0, "r", DataType.REAL32)
    with pytest.raises(ValueRangeError, match="REAL32: only integer values"):
        real.default = NodeRelative(1)
    small = Variable(0x2101, 0, "u8", DataType.UNSIGNED8, default=3)
    with pytest.raises(ValueRangeError, match=r"does not fit UNSIGNED8 \(0\.\.255\)"):
        small.default = NodeRelative(200)
    assert small.default == 3 and not small.relative


def test_dummy_usage_set_in_code():
    od = _od()
    od.set_dummy_usage(5)
    od.set_dummy_usage(6, False)
    dummy = _var(od, 5)
    assert dummy.object_type is ObjectType.DEFTYPE and dummy.data_type is DataType.UNSIGNED8
    assert od.dummy_usage == {5: True, 6: False} and 6 not in od
    eds = od.to_eds()
    assert "Dummy0005=1" in eds and "Dummy0006=0" in eds and "[0005]" not in eds
    assert loads(eds).diff(od) == []
    od.set_dummy_usage(5, False)
    assert 5 not in od and od.dummy_usage == {5: False, 6: False}
    with pytest.raises(DataTypeError, match="0x0020: only the basic data types"):
        od.set_dummy_usage(0x20)


def test_a_variable_takes_its_access_by_value_and_refuses_an_unknown_one():
    assert Variable(0x2000, 0, "x", DataType.UNSIGNED8, access="ro").access is Access.RO  # type: ignore[arg-type]
    with pytest.raises(ObjectDictionaryError, match="access 'read' is none of ro, wo"):
        Variable(0x2000, 0, "x", DataType.UNSIGNED8, access="read")  # type: ignore[arg-type]
    var = Variable(0x2001, 0, "y", DataType.UNSIGNED8)
    var.access = "ro"  # later too: a device would have served a bare string read-write
    assert var.access is Access.RO and not var.writable
    with pytest.raises(ObjectDictionaryError, match="0x2001:00 'y': access 'read' is none of"):
        var.access = "read"
    assert var.access is Access.RO  # unchanged
    var.access = Access.CONST
    assert var.access is Access.CONST
