"""Reading and writing CiA 306 EDS/DCF: syntax variants, the corpus, round trips."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cobus.od import (
    Access,
    Array,
    DataType,
    DeviceInfo,
    EdsError,
    FileInfo,
    ObjectDictionary,
    ObjectType,
    Record,
    Severity,
    TimeDifference,
    TimeOfDay,
    Variable,
    load,
    loads,
    validate,
)
from tests.conftest import EDS_DIR, corpus_files


def var(od: ObjectDictionary, index: int, sub: int = 0) -> Variable:
    found = od.get_variable(index, sub)
    assert found is not None, f"0x{index:04X}sub{sub} missing"
    return found


def composite(od: ObjectDictionary, index: int) -> Record | Array:
    obj = od[index]
    assert isinstance(obj, (Record, Array))
    return obj


def reasons(od: ObjectDictionary) -> list[str]:
    return [f.reason for f in od.findings]


VAR_1000 = "[1000]\nParameterName=Device type\nDataType=0x0007\nAccessType=ro\n"


# --- syntax -------------------------------------------------------------------------------------


def test_nodeid_expressions_and_number_literals():
    text = (
        "[DeviceComissioning]\nNodeID=0x10\n\n"
        "[1800sub1]\n"  # sub-object before its object: order does not matter
        "ParameterName=COB-ID\nDataType=0x0007\nAccessType=rw\nDefaultValue=$NODEID+0x180\n"
        "[1800]\nParameterName=TPDO1\nObjectType=0x9\nSubNumber=2\n"
        "[1800sub0]\nParameterName=n\nDataType=0x0005\nAccessType=ro\nDefaultValue=1\n"
        "[1014]\nParameterName=EMCY\nDataType=7\nAccessType=rw\nDefaultValue=0x80 + $nodeid\n"
        "[1400]\nParameterName=x\nDataType=0x0007\nAccessType=rw\nDefaultValue=$NODEID+1024\n"
        "[2000]\nParameterName=dec\nDataType=0x0006\nAccessType=rw\nDefaultValue=1000\n"
        "[2001]\nParameterName=oct\nDataType=0x0006\nAccessType=rw\nDefaultValue=0017\n"
        "[2002]\nParameterName=neg\nDataType=0x0003\nAccessType=rw\nDefaultValue=-0x7f\n"
        "[2003]\nParameterName=bits\nDataType=0x0003\nAccessType=rw\nDefaultValue=0xFF9C\n"
        "[2004]\nParameterName=zeros\nDataType=0x001B\nAccessType=rw\nDefaultValue=000000\n"
        "[2005]\nParameterName=hi\nDataType=0x0007\nAccessType=rw\n"
        "DefaultValue=$NODEID+0x80000200\n"
    )
    od = loads(text)
    assert od.findings == []
    assert od.node_id == 0x10
    assert var(od, 0x1800, 1).default == 0x190
    assert var(od, 0x1014).default == 0x90
    assert var(od, 0x1400).default == 1024 + 16
    assert [var(od, i).default for i in range(0x2000, 0x2005)] == [1000, 15, -127, -100, 0]
    assert var(od, 0x2005).default == 0x80000210
    assert loads(text, node_id=3).get_variable(0x1800, 1).default == 0x183  # type: ignore[union-attr]


def test_values_of_every_type():
    body = {
        "0x0001": ("1", True),
        "0x0008": ("0x40490FDB", 3.1415927410125732),  # REAL as raw IEEE bits
        "0x0011": ("2.5", 2.5),
        "0x0009": ('"  padded "', "  padded "),  # quotes keep the spaces
        "0x000A": ("0123456789abcdef", bytes.fromhex("0123456789abcdef")),
        "0x000B": ("Grüße", "Grüße"),
        "0x000C": ("365 43200000", TimeOfDay(365, 43_200_000)),
        "0x000D": ("2 1000", TimeDifference(2, 1000)),
        "0x000F": ("0x0A0B", b"\x0a\x0b"),
        "0x0010": ("-0x7fffff", -0x7FFFFF),
        "0x0012": ("0xFFFFFFFFFF", -1),
        "0x001A": ("0x7fffffffffffff", 0x7FFFFFFFFFFFFF),
    }
    text = "".join(
        f"[{0x2000 + i:04X}]\nParameterName=p{i}\nDataType={dt}\nAccessType=rw\n"
        f"ParameterValue={raw}\n"
        for i, (dt, (raw, _)) in enumerate(body.items())
    )
    od = loads(text)
    assert od.findings == []
    for i, (_, expected) in enumerate(body.values()):
        got = var(od, 0x2000 + i).parameter_value
        assert got == expected and type(got) is type(expected)
    assert math.isnan(loads(text.replace("2.5", "nan")).get_variable(0x2002).value)  # type: ignore[union-attr]


def test_compact_sub_objects_with_name_and_value_sections():
    text = (
        "[1016]\nParameterName=Consumer heartbeat time\nObjectType=0x8\nDataType=0x0007\n"
        "AccessType=rw\nDefaultValue=0\nPDOMapping=0\nCompactSubObj=3\n"
        "[1016Name]\nNrOfEntries=1\n2=Heartbeat of node 5\n"
        "[1016Value]\nNrOfEntries=2\n1=0x000503E8\n3=$NODEID+5\n"
        "[1016Denotation]\nNrOfEntries=1\n1=Drive\n"
    )
    od = loads(text, node_id=2)
    assert od.findings == []
    arr = composite(od, 0x1016)
    assert isinstance(arr, Array) and arr.compact == 3
    sub0 = arr[0]
    assert (sub0.name, sub0.data_type, sub0.access, sub0.default) == (
        "NrOfObjects",
        DataType.UNSIGNED8,
        Access.RO,
        3,
    )
    assert [v.name for v in arr] == [
        "NrOfObjects",
        "Consumer heartbeat time1",
        "Heartbeat of node 5",
        "Consumer heartbeat time3",
    ]
    assert arr["Heartbeat of node 5"].subindex == 2
    assert [v.parameter_value for v in arr] == [None, 0x503E8, None, 7]
    assert all(v.default == 0 and v.access is Access.RW for v in list(arr)[1:])
    assert arr[1].denotation == "Drive"
    # Written back compactly, and read back equal.
    eds = od.to_eds()
    assert "CompactSubObj=3" in eds and "[1016Name]" in eds and "[1016sub1]" not in eds
    assert loads(eds, node_id=2) == od
    # Changing one entry's type breaks the shared description: written out in full.
    arr[2].access = Access.RO
    eds = od.to_eds()
    assert "CompactSubObj" not in eds and "[1016sub2]" in eds
    assert loads(eds, node_id=2) == od


def test_commissioning_spellings():
    classic = loads("[DeviceComissioning]\nNodeID=5\nBaudrate=500\nNetNumber=1\nNodeRefd=x\n")
    correct = loads("[DeviceCommissioning]\nNodeId=0x05\nBaudRate=500\nNetNumber=1\nNodeRefd=x\n")
    for od in (classic, correct):
        assert od.node_id == 5 and od.bitrate == 500_000
        assert od.commissioning is not None
        assert od.commissioning.net_number == 1 and od.commissioning.extra == {"NodeRefd": "x"}
    assert classic == correct
    assert correct.commissioning is not None
    assert "[DeviceCommissioning]" in correct.to_dcf()  # the spelling is kept
    assert loads("[DeviceComissioning]\nNodeID=5\n", node_id=9).node_id == 9  # argument wins


def test_objflags_dummy_usage_denotation_and_case():
    text = (
        "[dummyusage]\ndummy0005=1\nDummy0006=0\n"
        "[1a00]\nparametername=TPDO map\nobjecttype=0x9\nsubnumber=2\n"
        "[1A00SUB0]\nParameterName=n\nDataType=0x0005\naccesstype=RW\nDefaultValue=1\n"
        "[1a00sub1]\nParameterName=e\nDataType=0x0007\nAccessType=rw\nDefaultValue=0x00050008\n"
        "ObjFlags=0x3\nDenotation=pad\n"
    )
    od = loads(text)
    assert od.findings == []  # the mapping of dummy 0x0005 (UNSIGNED8, 8 bits) is valid
    assert od.dummy_usage == {5: True, 6: False}
    dummy = var(od, 5)
    assert dummy.object_type is ObjectType.DEFTYPE and dummy.data_type is DataType.UNSIGNED8
    entry = var(od, 0x1A00, 1)
    assert entry.obj_flags == 3 and entry.denotation == "pad" and entry.access is Access.RW
    # Dummies are written as [DummyUsage], not as objects.
    eds = od.to_eds()
    assert "[0005]" not in eds and "Dummy0005=1" in eds
    assert loads(eds) == od
    undeclared = loads(text.replace("dummy0005=1", "dummy0005=0"))
    assert undeclared.errors[0].reason == (
        "TPDO mapping entry 1 maps 0x0005sub0, which is not in the dictionary "
        "(a dummy entry needs Dummy0005=1 in [DummyUsage])"
    )


def test_comments_bom_crlf_and_missing_optional_keys():
    text = (
        "\ufeff; written by hand\r\n# hash comments too\r\n\r\n[Comments]\r\nLines=2\r\n"
        "Line1=first\r\nline2=second\r\n\r\n[1001]\r\nParameterName=Error register\r\n"
        "DataType=0x0005\r\nAccessType=ro\r\n"
    )
    od = loads(text)
    assert od.findings == []
    assert od.comments == ["first", "second"]
    assert od.file_comments == {"": [(None, "; written by hand"), (None, "# hash comments too")]}
    reg = var(od, 0x1001)
    assert reg.object_type is ObjectType.VAR  # no ObjectType key: VAR (CiA 306)
    assert not reg.pdo_mappable and reg.default is None and reg.low_limit is None


def test_layout_variants():
    text = (
        "[1000]\nParameterName=a\nDataType=7\nAccessType=ro\n"
        "  [1001]  ; indented header with a comment\n ParameterName = b \nDataType=0x0005\n"
        "AccessType=ro\nDefaultValue=0x100\n\n"
        "[2000]\nParameterName=c\nDataType=5\nAccessType=rw\nDefaultValue=300"  # no final EOL
    )
    od = loads(text)
    assert var(od, 0x1001).name == "b" and len(od) == 3
    assert [(f.line, f.section) for f in od.findings] == [(9, "1001"), (15, "2000")]
    assert loads(text.replace("\n", "\r")).diff(od) == []  # old Mac line ends


def test_unknown_keys_and_sections_are_kept_and_written_back():
    text = (
        "[FileInfo]\nFileName=x.eds\nMyTool=3\n"
        "[DeviceInfo]\nVendorName=ACME\nVendorNumber=0x42\nBaudRate_83=1\nSpecial=yes\n"
        "[PreDefines]\ncsp=\npp=1\n"
        "[2000]\nParameterName=p\nDataType=0x0007\nAccessType=rw\nCategory=Motor\n"
        "Unit=mV\nFactor=0.1\nDescription=scaled\n"
        "[2001]\nParameterName=r\nObjectType=0x9\nSubNumber=1\nRecordTag=vendor\n"
        "[2001sub0]\nParameterName=n\nDataType=0x0005\nAccessType=ro\nDefaultValue=0\n"
    )
    od = loads(text)
    assert od.findings == []
    assert od.file_info.extra == {"MyTool": "3"}
    assert od.device_info.vendor_number == 0x42 and od.device_info.baud_rates == {83}
    assert od.device_info.extra == {"Special": "yes"}
    assert od.extra_sections == [("PreDefines", [("csp", ""), ("pp", "1")])]
    p = var(od, 0x2000)
    assert p.extra == {"Category": "Motor"} and p.unit == "mV" and p.factor == 0.1
    assert p.description == "scaled"
    assert composite(od, 0x2001).extra == {"RecordTag": "vendor"}
    eds = od.to_eds()
    for line in ("MyTool=3", "Special=yes", "[PreDefines]", "pp=1", "Category=Motor"):
        assert line in eds
    assert loads(eds) == od


COMMENTED = """; made by hand
[FileInfo]
; about the file
FileName=x.eds
;after the name
[DummyUsage]
Dummy0005=1
Vendor=7
;why 7
Dummy0007=oops
[Comments]
Lines=1
Line1=first
Author=me
[1000]
DefaultValue=0x191
;SEVCONFIELD OBJECT=DEVICE_TYPE
;SEVCONFIELD SPLIT=0
ParameterName=Device type
DataType=0x0007
;StorageLocation=RAM
AccessType=ro
[1018]
ParameterName=Identity
ObjectType=0x9
SubNumber=1
[1018sub00]
ParameterName=n
;before the type
DataType=0x0005
AccessType=ro
DefaultValue=0
; [1018sub1] left out
[1016]
ParameterName=Consumers
ObjectType=0x8
DataType=0x0007
AccessType=rw
DefaultValue=0
CompactSubObj=2
[1016Name]
NrOfEntries=1
; named by hand
1=Drive
[PreDefines]
# a tool's section
pp=1
"""


def test_comment_lines_are_kept_where_they_are_and_written_back():
    od = loads(COMMENTED)
    assert [f.reason for f in od.findings] == [
        "key Vendor is not DummyNNNN; it is kept as written",
        "Dummy0007: bad number 'oops': expected a decimal, 0x-hex or 0-octal integer literal; "
        "it is kept as written",
        "key Author is not LineN; it is kept as written",
    ]
    assert od.dummy_usage == {5: True} and od.dummy_usage_extra == {
        "Vendor": "7",
        "Dummy0007": "oops",
    }
    assert od.comments == ["first"] and od.comments_extra == {"Author": "me"}
    assert od.file_comments == {
        "": [(None, "; made by hand")],
        "FILEINFO": [(None, "; about the file"), ("FileName", ";after the name")],
        "DUMMYUSAGE": [("Vendor", ";why 7")],
        "1000": [
            ("DefaultValue", ";SEVCONFIELD OBJECT=DEVICE_TYPE"),
            ("DefaultValue", ";SEVCONFIELD SPLIT=0"),
            ("DataType", ";StorageLocation=RAM"),
        ],
        "1018SUB0": [
            ("ParameterName", ";before the type"),
            ("DefaultValue", "; [1018sub1] left out"),
        ],
        "1016NAME": [("NrOfEntries", "; named by hand")],
        "PREDEFINES": [(None, "# a tool's section")],
    }
    eds = od.to_eds()
    # each comment follows its key, in the order the writer writes the keys
    for block in (
        "; made by hand\n[FileInfo]\n; about the file\nFileName=x.eds\n;after the name\n",
        "[DummyUsage]\nDummy0005=1\nVendor=7\n;why 7\nDummy0007=oops\n",
        "[Comments]\nLines=1\nLine1=first\nAuthor=me\n",
        "DataType=0x0007\n;StorageLocation=RAM\nAccessType=ro\n"
        "DefaultValue=0x191\n;SEVCONFIELD OBJECT=DEVICE_TYPE\n;SEVCONFIELD SPLIT=0\nPDOMapping=0\n",
        "[1018sub0]\nParameterName=n\n;before the type\n",
        "DefaultValue=0\n; [1018sub1] left out\nPDOMapping=0\n",
        "[1016Name]\nNrOfEntries=1\n; named by hand\n1=Drive\n",
        "[PreDefines]\n# a tool's section\npp=1\n",
    ):
        assert block in eds
    again = loads(eds)
    assert again.diff(od) == [] and again.to_eds() == eds


def test_comments_go_with_their_object_and_stay_with_an_empty_section():
    od = loads(COMMENTED)
    od.remove(0x1018)
    od.remove(0x1016)
    assert set(od.file_comments) == {"", "FILEINFO", "DUMMYUSAGE", "1000", "PREDEFINES"}
    only_comment = loads("[DummyUsage]\n; none are used\n" + VAR_1000)
    assert only_comment.dummy_usage == {}
    eds = only_comment.to_eds()
    assert "[DummyUsage]\n; none are used\n" in eds and loads(eds).diff(only_comment) == []
    duplicate = loads(VAR_1000 + "; first\n" + VAR_1000 + "; of the ignored copy\n")
    assert duplicate.file_comments == {"1000": [("AccessType", "; first")]}
    # a comment after a key that is not written back closes its section
    unwritten = loads("[DeviceInfo]\nBaudRate_83=0\n; after 83\nVendorName=x\n" + VAR_1000)
    eds = unwritten.to_eds()
    assert "BaudRate_83" not in eds and "BaudRate_1000=0\n; after 83\n\n[Mandatory" in eds
    assert loads(eds).to_eds() == eds
    changed = loads(COMMENTED)
    changed.file_comments["1000"].append(("ParameterName", "; new"))
    (line,) = changed.diff(loads(COMMENTED))
    assert line.startswith("comments of [1000]: {") and "'parametername': ['; new']" in line


def test_lenient_and_strict():
    text = VAR_1000 + "DefaultValue=0x1FFFFFFFF\n"
    od = loads(text, path="dev.eds")
    assert var(od, 0x1000).default is None and var(od, 0x1000).default_raw == "0x1FFFFFFFF"
    (finding,) = od.findings
    assert finding.severity is Severity.ERROR
    assert str(finding) == (
        "dev.eds:5: [1000] error: DefaultValue: '0x1FFFFFFFF' = 8589934591 is out of range "
        "for UNSIGNED32 (0..4294967295)"
    )
    assert "DefaultValue=0x1FFFFFFFF" in od.to_eds()  # the text is kept
    with pytest.raises(EdsError) as info:
        loads(text, path="dev.eds", strict=True)
    err = info.value
    assert (err.path, err.line, err.section) == ("dev.eds", 5, "1000")
    assert str(err).startswith("dev.eds:5: [1000] DefaultValue:")


def test_warnings_do_not_stop_strict_loading():
    text = "[MandatoryObjects]\nSupportedObjects=2\n1=0x1000\n" + VAR_1000
    od = loads(text, strict=True)
    assert [str(f) for f in od.findings] == [
        "<string>:2: [MandatoryObjects] warning: SupportedObjects=2 but 1 objects are listed"
    ]


def test_findings_are_in_line_order():
    od = load(EDS_DIR / "canopen-python_sample.eds")
    lines = [f.line for f in od.findings if f.line is not None]
    assert lines == sorted(lines) and len(lines) > 10


def test_load_reports_unreadable_files(tmp_path: Path):
    with pytest.raises(EdsError, match="cannot read the file"):
        load(tmp_path / "missing.eds")
    latin = tmp_path / "latin.eds"
    latin.write_bytes(b"[1000]\nParameterName=Ger\xe4t\nDataType=7\nAccessType=ro\n")
    od = load(latin)
    assert od[0x1000].name == "Gerät" and reasons(od) == ["not UTF-8; read as Latin-1"]


def test_to_dcf_sets_commissioning_and_save(tmp_path: Path):
    od = load(EDS_DIR / "canfestival_ds401_slave_gui.eds")
    assert od.commissioning is None
    dcf = loads(od.to_dcf(node_id=7, bitrate=250_000))
    assert dcf.node_id == 7 and dcf.bitrate == 250_000
    assert dcf.commissioning is not None and dcf.commissioning.node_id == 7
    target = tmp_path / "out.dcf"
    od.save(target, node_id=7)
    assert target.read_bytes().count(b"\r\n") > 100  # CRLF like the tools write
    again = load(target)
    assert again.node_id == 7 and again.findings == []
    eds_path = tmp_path / "out.eds"
    od.save(eds_path)
    assert load(eds_path) == od


def test_to_eds_and_to_dcf_write_given_sections_in_place_of_the_dictionarys():
    od = load(EDS_DIR / "canopen-python_sample.eds")
    before = od.to_eds()
    file_info = FileInfo(file_name="export.eds", created_by="a tool", extra={"Tag": "1"})
    device_info = DeviceInfo(vendor_name="ACME", baud_rates={125}, nr_of_tx_pdo=2)
    for text in (
        od.to_eds(file_info=file_info, device_info=device_info, dummy_usage={5: True, 7: False}),
        od.to_dcf(file_info=file_info, device_info=device_info, dummy_usage={5: True, 7: False}),
    ):
        again = loads(text)
        assert again.file_info == file_info and again.device_info == device_info
        assert again.dummy_usage == {5: True, 7: False} and var(again, 5).pdo_mappable
        objects = [line for line in again.diff(od) if line.startswith("0x")]
        assert objects == [  # the dummies of the [DummyUsage] written and of the file's
            "0x0005: only in the first dictionary",
            "0x0003: only in the second dictionary",
        ]
    assert loads(od.to_dcf(3, dummy_usage={})).dummy_usage == {}  # none at all
    assert od.to_eds() == before  # the dictionary itself is not changed
    assert od.file_info.file_name != "export.eds" and od.dummy_usage != {5: True, 7: False}


def test_validate_a_dictionary_built_in_code():
    od = loads(
        "[1A00]\nParameterName=map\nObjectType=0x9\nSubNumber=2\n"
        "[1A00sub0]\nParameterName=n\nDataType=0x0005\nAccessType=rw\nDefaultValue=1\n"
        "[1A00sub1]\nParameterName=e\nDataType=0x0007\nAccessType=rw\nDefaultValue=0x20000010\n"
    )
    assert [f.reason for f in od.findings] == [
        "TPDO mapping entry 1 maps 0x2000sub0, which is not in the dictionary"
    ]
    od.add(Variable(0x2000, 0, "Speed", DataType.UNSIGNED16, Access.RO, pdo_mappable=True))
    assert validate(od) == []
    var(od, 0x2000).pdo_mappable = False
    (finding,) = validate(od)
    assert "not PDO-mappable" in finding.reason
    assert (finding.line, finding.section) == (10, "1A00sub1")


_TEXT_VALUES = {
    **{
        d: st.integers(*d.range)  # type: ignore[misc]
        for d in DataType
        if d.is_integer
    },
    DataType.BOOLEAN: st.booleans(),
    DataType.REAL32: st.floats(width=32, allow_nan=False),
    DataType.REAL64: st.floats(allow_nan=False),
    DataType.VISIBLE_STRING: st.text(st.characters(min_codepoint=0x20, max_codepoint=0x7E)),
    DataType.UNICODE_STRING: st.text(
        st.characters(blacklist_categories=("Cs", "Cc", "Zl", "Zp"), blacklist_characters="\x85")
    ),
    DataType.OCTET_STRING: st.binary(max_size=16),
    DataType.DOMAIN: st.binary(max_size=16),
    DataType.TIME_OF_DAY: st.builds(TimeOfDay, st.integers(0, 0xFFFF), st.integers(0, 86_399_999)),
    DataType.TIME_DIFFERENCE: st.builds(
        TimeDifference, st.integers(0, 0xFFFF), st.integers(0, 0x0FFFFFFF)
    ),
}


def test_every_type_has_a_text_value_strategy():
    assert set(_TEXT_VALUES) == set(DataType)


@pytest.mark.parametrize("dt", list(DataType), ids=lambda d: d.name)
@settings(max_examples=25, deadline=None)
@given(data=st.data())
def test_values_survive_the_file_text(dt: DataType, data: st.DataObject):
    """A value set in code is written as CiA 306 text and read back identical."""
    value = data.draw(_TEXT_VALUES[dt])
    od = ObjectDictionary()
    od.add(Variable(0x2000, 0, "v", dt, default=value, parameter_value=value))
    again = loads(od.to_dcf())
    assert again.findings == []
    got = var(again, 0x2000)
    assert got.default == value and type(got.default) is type(value)
    assert got.parameter_value == value


# --- the corpus ----------------------------------------------------------------------------------

CORPUS = corpus_files()


def test_corpus_is_there():
    assert len(CORPUS) == 18


def _comment_lines(text: str) -> list[str]:
    return sorted(s for line in text.splitlines() if (s := line.strip())[:1] in (";", "#"))


@pytest.mark.parametrize("path", CORPUS, ids=lambda p: p.name)
def test_corpus_round_trip(path: Path):
    od = load(path)
    assert len(od) > 20
    eds = od.to_eds()
    # every whole-line comment survives, and load -> write -> load -> write is text-stable
    original = path.read_bytes().decode("utf-8", errors="replace")
    assert _comment_lines(eds) == _comment_lines(original)
    assert loads(eds).to_eds() == eds
    for text in (eds, od.to_dcf()):
        again = loads(text, path="written")
        assert again.diff(od) == []
        # What we write is clean of the syntax problems the original may have had.
        assert not [f for f in again.findings if "section" in f.reason.split(":")[0]]
        assert loads(again.to_eds()).to_eds() == again.to_eds()  # writing is stable


def test_corpus_facts():
    sample = load(EDS_DIR / "canopen-python_sample.eds")
    assert sample.node_id == 0x10 and sample.bitrate == 500_000
    assert 3 not in composite(sample, 0x1018)  # [1018sub3] is left out in the file
    assert var(sample, 0x1400, 1).default == 0x210  # $NODEID+512
    assert var(sample, 0x1403, 1).default == 0x510  # 1280+$NODEID
    assert var(sample, 0x3030).low_limit == -(2**31)  # two's complement hex limits
    assert var(sample, 0x3031).low_limit == -1  # INTEGER24
    assert var(sample, 0x3002).default == 5.2 and var(sample, 0x3002).value == 5.2
    assert var(sample, 0x3063).object_type is ObjectType.DOMAIN
    assert var(sample, 0x2020).declared_type == 0x40
    assert var(sample, 0x3050, 2).extra == {"Factor": "ERROR"}
    assert sample.comments == ["|-------------|", "| Don't panic |", "|-------------|"]

    oresat = load(EDS_DIR / "oresat_battery.dcf")
    assert oresat.node_id == 4 and oresat.bitrate is None  # NodeId=4, BaudRate=0
    assert oresat.commissioning is not None
    assert oresat.commissioning.section == "DeviceCommissioning"
    assert var(oresat, 0x1800, 1).default == 0x40000184  # 0x40000180+$NODEID

    sdev = load(EDS_DIR / "lely_co-sdev.dcf")
    assert var(sdev, 0x2009).value == "Hello, World!"
    assert var(sdev, 0x200C).value == TimeOfDay(365, 43_200_000)
    assert var(sdev, 0x2015).value == -0x7FFFFFFFFFFFFFFF
    assert var(sdev, 0x2011).value == math.pi

    coctl = load(EDS_DIR / "lely_coctl.dcf")
    assert coctl.device_info.nr_of_rx_pdo == 4 and coctl.device_info.compact_pdo == 0x3F
    assert sorted(coctl.dummy_usage) == [*range(2, 8), 0x10, *range(0x12, 0x17), *range(0x18, 0x1C)]
    assert var(coctl, 0x1B).data_type is DataType.UNSIGNED64  # Dummy001B
    assert len(composite(coctl, 0x1003)) == 255  # CompactSubObj=254

    master = load(EDS_DIR / "roscanopen_master.dcf")
    assert [v.parameter_value for v in composite(master, 0x1F81)][2:4] == [5, 5]

    io = load(EDS_DIR / "canopennode_io.eds")
    assert io.comments[4] == "http://canopennode.sourceforge.net/"  # lowercase line5=
    assert var(io, 0x1000).default is not None

    sevcon = load(EDS_DIR / "sevcon_gen4.eds")
    assert var(sevcon, 0x1000).default == 0xFFFF0192
    assert sevcon.device_info.order_code == "TODO"
    systec = load(EDS_DIR / "systec_iox1_16di_8do.eds")
    assert systec.device_info.baud_rates  # "Baudrate_10" with a lowercase r
    e35 = load(EDS_DIR / "canopen-python_e35.eds")
    assert 0x100A in e35  # out of order near the end of the file
    kaco = load(EDS_DIR / "kacanopen_406.eds")
    assert kaco.file_info.creation_date == "07-Feb-2016"
    elmo = load(EDS_DIR / "elmo_elmo.eds")
    name, keys = elmo.extra_sections[0]
    assert name == "PreDefines" and dict(keys)["pp"] == "1" and dict(keys)["csp"] == ""


def test_benchmark_input_is_a_clean_5000_object_eds():
    from benchmarks.bench_od import generated_eds

    od = loads(generated_eds(5000))
    assert len(od) == 5000 and od.findings == []
    assert len(composite(od, 0x2004)) == 4 and var(od, 0x2003).default == 3
