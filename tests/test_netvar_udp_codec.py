"""Network variables over UDP (issue 46): telegrams, IEC types, lists cut into telegrams,
and .gvl files as CODESYS exports them — from the facts of the format, built in the test."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest

from cobus.blocks.gvl import (
    GvlError,
    declared_values,
    dumps_gvl,
    iec_time,
    load_gvl,
    loads_gvl,
    parse_st_types,
)
from cobus.blocks.netvar_udp import (
    MAX_DATA,
    REQUEST,
    Telegram,
    TelegramError,
    UdpVarList,
    iec_type,
    layout,
)

#: The example of the format's description: list 1, TRUE, 1234, 3.14 as BOOL, INT, REAL.
EXAMPLE = bytes.fromhex(
    "00 2D 53 33 00 00 00 00 01 00 00 00 03 00 1B 00 01 00 00 00 01 D2 04 C3 F5 48 40"
)


def _gvl(declarations: str, **settings: str) -> str:
    values = {
        "ListIdentifier": "1",
        "Pack": "True",
        "Checksum": "False",
        "Acknowledge": "False",
        "CyclicTransmission": "True",
        "TransmissionOnChange": "False",
        "TransmissionOnEvent": "False",
        "Interval": "T#1000ms",
        "MinGap": "T#1000ms",
        "EventVariable": "\n    ",
        **settings,
    }
    inner = "\n".join(f"    <{k}>{v}</{k}>" for k, v in values.items())
    return (
        f"<GVL>\n  <Declarations><![CDATA[{declarations}]]></Declarations>\n"
        f'  <NetvarSettings Protocol="UDP">\n{inner}\n    <ProtocolSettings>\n'
        '      <ProtocolSetting Name="Broadcast Adr." Value="192.168.56.1" />\n'
        '      <ProtocolSetting Name="Port" Value="1202" />\n'
        "    </ProtocolSettings>\n  </NetvarSettings>\n</GVL>"
    )


def test_the_example_telegram_byte_for_byte() -> None:
    lst = loads_gvl(_gvl("VAR_GLOBAL\n\tflag : BOOL;\n\tcount : INT;\n\tratio : REAL;\nEND_VAR"))
    payload = lst.pack_values({"flag": True, "count": 1234, "ratio": 3.14})
    (telegram,) = lst.telegrams(payload, counter=1)
    assert telegram.to_bytes() == EXAMPLE
    parsed = Telegram.parse(EXAMPLE)
    assert (parsed.list_id, parsed.sub_index, parsed.count, parsed.counter) == (1, 0, 3, 1)
    values = lst.unpack(parsed.data)
    assert values["flag"] is True and values["count"] == 1234
    assert values["ratio"] == pytest.approx(3.14, rel=1e-7)


def test_junk_datagrams_say_why() -> None:
    for junk, why in (
        (b"", "shorter than a header"),
        (EXAMPLE[:19], "shorter than a header"),
        (b"\x00-S4" + EXAMPLE[4:], "identity"),
        (EXAMPLE[:-1], "length field 27, datagram 26"),
        (EXAMPLE + b"\0", "length field 27, datagram 28"),
        (EXAMPLE[:4] + b"\x05\0\0\0" + EXAMPLE[8:], "type 5"),
    ):
        with pytest.raises(TelegramError, match=why):
            Telegram.parse(junk)
    big = Telegram(1, 0, 1, 0, bytes(257))
    with pytest.raises(TelegramError, match="257 data bytes"):
        big.to_bytes()
    header = struct.pack("<4sIHHHHHBB", b"\x00-S3", 0, 1, 0, 1, 20 + 300, 0, 0, 0)
    with pytest.raises(TelegramError, match="more than 256"):
        Telegram.parse(header + bytes(300))


def test_elementary_types_sizes_and_ranges() -> None:
    sizes = {
        "BOOL": 1,
        "BYTE": 1,
        "SINT": 1,
        "USINT": 1,
        "WORD": 2,
        "INT": 2,
        "UINT": 2,
        "DWORD": 4,
        "DINT": 4,
        "UDINT": 4,
        "REAL": 4,
        "TIME": 4,
        "TOD": 4,
        "TIME_OF_DAY": 4,
        "DATE": 4,
        "DT": 4,
        "DATE_AND_TIME": 4,
        "LWORD": 8,
        "LINT": 8,
        "ULINT": 8,
        "LREAL": 8,
        "STRING": 81,
        "STRING(20)": 21,
        "string[5]": 6,
        "WSTRING(10)": 22,
        "WSTRING": 162,
    }
    for name, size in sizes.items():
        assert iec_type(name).size == size, name
    assert iec_type("int").encode(-2) == b"\xfe\xff"
    assert iec_type("TIME").encode(1500) == b"\xdc\x05\x00\x00"
    for name, bad, why in (
        ("SINT", 128, "out of the range of SINT: -128..127"),
        ("UINT", -1, "0..65535"),
        ("BOOL", 2, "TRUE or FALSE"),
        ("INT", 1.5, "a whole number"),
        ("TIME", "1s", r"whole number \(milliseconds\)"),
        ("REAL", 1e39, "out of the range of REAL"),
        ("STRING(3)", "abcd", "holds 3 characters"),
        ("STRING(3)", "€", None),  # (Windows-1252 has it: one byte)
        ("STRING(3)", "日本", "Windows-1252"),
        ("WSTRING(2)", "abc", "holds 2 characters"),
    ):
        if why is None:
            assert iec_type(name).encode(bad) == b"\x80\0\0\0"
            continue
        with pytest.raises(ValueError, match=why):
            iec_type(name).encode(bad)
    with pytest.raises(ValueError, match=r"no elementary type.*STRING\(n\)"):
        iec_type("POINTER TO INT")
    # text ends at the first NUL, whatever follows it
    assert iec_type("STRING(5)").decode(b"ab\0xyz") == "ab"
    assert iec_type("WSTRING(3)").decode("hé".encode("utf-16-le") + b"\0\0zz") == "hé"
    assert iec_type("BOOL").decode(b"\x07") is True


def _list(items: list[tuple[str, str]], pack: bool = True) -> UdpVarList:
    return UdpVarList("l", 7, layout([(n, iec_type(t)) for n, t in items]), pack=pack)


def test_a_packed_list_splits_between_values_at_256_bytes() -> None:
    items = [(f"s{i}", "STRING(99)") for i in range(5)] + [("last", "DINT")]
    lst = _list(items)
    assert lst.parts == ((0, 2, 200), (2, 2, 200), (4, 2, 104))
    values = {f"s{i}": f"text {i}" for i in range(5)} | {"last": -5}
    payload = lst.pack_values(values)
    telegrams = lst.telegrams(payload, counter=0xFFFF)
    assert [(t.sub_index, t.count, len(t.data), t.counter) for t in telegrams] == [
        (0, 2, 200, 0xFFFF),
        (1, 2, 200, 0xFFFF),
        (2, 2, 104, 0xFFFF),
    ]
    assert b"".join(t.data for t in telegrams) == payload
    assert lst.unpack(payload) == values
    # a value of exactly 256 bytes takes a telegram of its own; more is refused
    assert _list([("a", "BOOL"), ("b", "STRING(255)"), ("c", "BOOL")]).parts == (
        (0, 1, 1),
        (1, 1, 256),
        (2, 1, 1),
    )
    with pytest.raises(ValueError, match="takes 257 bytes; a telegram carries 256"):
        _list([("big", "STRING(256)")])


def test_an_unpacked_list_sends_a_telegram_per_value() -> None:
    lst = _list([("a", "BOOL"), ("b", "INT"), ("c", "REAL")], pack=False)
    telegrams = lst.telegrams(lst.pack_values({"a": False, "b": 7, "c": 0.5}), counter=3)
    assert [(t.sub_index, t.count, t.data) for t in telegrams] == [
        (0, 1, b"\x00"),
        (1, 1, b"\x07\x00"),
        (2, 1, struct.pack("<f", 0.5)),
    ]
    assert all(t.counter == 3 for t in telegrams)
    request = lst.request()
    assert request.kind == REQUEST and request.to_bytes()[4] == 6 and len(request.to_bytes()) == 20
    assert MAX_DATA == 256


# ------------------------------------------------------------------ .gvl files

#: As CODESYS writes a list "linked to file" (TAB-indented, no newline at the end).
CODESYS_EXPORT = """<GVL>
  <Declarations><![CDATA[VAR_GLOBAL
\tsinus: REAL;
\tcosine: REAL;
\tsome_word : WORD;
\tinteger : INT;
\tmy_time : TIME;
\tmy_date : DATE;
\tmy_string20 : STRING(20);
\tmy_array : ARRAY[0..4] OF INT;
END_VAR]]></Declarations>
  <NetvarSettings Protocol="UDP">
    <ListIdentifier>1</ListIdentifier>
    <Pack>True</Pack>
    <Checksum>False</Checksum>
    <Acknowledge>False</Acknowledge>
    <CyclicTransmission>True</CyclicTransmission>
    <TransmissionOnChange>False</TransmissionOnChange>
    <TransmissionOnEvent>False</TransmissionOnEvent>
    <Interval>T#1000ms</Interval>
    <MinGap>T#1000ms</MinGap>
    <EventVariable>
    </EventVariable>
    <ProtocolSettings>
      <ProtocolSetting Name="Broadcast Adr." Value="192.168.56.1" />
      <ProtocolSetting Name="Port" Value="1202" />
    </ProtocolSettings>
  </NetvarSettings>
</GVL>"""

#: An export with a pragma, cyclic and on change together, no ProtocolSettings.
WITH_PRAGMA = """<GVL>
  <Declarations><![CDATA[{attribute 'qualified_only'}
VAR_GLOBAL
\tWatchdog: BOOL;
\tInput1: BOOL;
\tInput2: BOOL;
END_VAR]]></Declarations>
  <NetvarSettings Protocol="UDP">
    <ListIdentifier>3</ListIdentifier>
    <Pack>True</Pack>
    <Checksum>False</Checksum>
    <Acknowledge>False</Acknowledge>
    <CyclicTransmission>True</CyclicTransmission>
    <TransmissionOnChange>True</TransmissionOnChange>
    <TransmissionOnEvent>False</TransmissionOnEvent>
    <Interval>T#10s</Interval>
    <MinGap>T#20ms</MinGap>
    <EventVariable>
    </EventVariable>
  </NetvarSettings>
</GVL>"""


def test_gvl_files_in_the_shapes_codesys_writes(tmp_path: Path) -> None:
    path = tmp_path / "plant.gvl"
    path.write_text(CODESYS_EXPORT)
    lst = load_gvl(path)
    assert lst.name == "plant" and lst.list_id == 1 and lst.pack
    assert (lst.transmit, set(lst.modes), lst.interval, lst.min_gap) == (
        "cyclic",
        {"cyclic"},
        1.0,
        1.0,
    )
    assert (lst.address, lst.port) == ("192.168.56.1", 1202)
    names = [v.name for v in lst.variables]
    assert names[:7] == [
        "sinus",
        "cosine",
        "some_word",
        "integer",
        "my_time",
        "my_date",
        "my_string20",
    ]
    assert names[7:] == [f"my_array[{i}]" for i in range(5)]
    assert lst.size == 4 + 4 + 2 + 2 + 4 + 4 + 21 + 10
    other = loads_gvl(WITH_PRAGMA, name="io")
    assert (
        other.modes == {"cyclic", "on_change"} and other.interval == 10.0 and other.min_gap == 0.02
    )
    assert (other.address, other.port) == ("255.255.255.255", 1202)
    assert [v.type.name for v in other.variables] == ["BOOL"] * 3


def test_st_declarations_the_subset_codesys_writes() -> None:
    text = """// a comment before
VAR_GLOBAL  // and after
    a, b : INT;          (* two names *)
    c:WORD; d : DINT := 5;   // an initial value, two on a line
    e : STRING(20) := 'x;y';  (* a ; inside a string *)
    f : (* STRING(40) *) STRING(8);
    g : ARRAY    [0   ..   1   ] OF BOOL;
    h : ARRAY[1..2, 0..1] OF USINT;
    {attribute 'hide'}
    i AT %IW0 : UINT;
    (* a comment
       over lines (* nested *) *)
    j : LREAL;
END_VAR
VAR_GLOBAL RETAIN
    k : TIME;
END_VAR"""
    values = declared_values(text)
    assert [(n, t.name) for n, t in values] == [
        ("a", "INT"),
        ("b", "INT"),
        ("c", "WORD"),
        ("d", "DINT"),
        ("e", "STRING(20)"),
        ("f", "STRING(8)"),
        ("g[0]", "BOOL"),
        ("g[1]", "BOOL"),
        ("h[1, 0]", "USINT"),
        ("h[1, 1]", "USINT"),
        ("h[2, 0]", "USINT"),
        ("h[2, 1]", "USINT"),
        ("i", "UINT"),
        ("j", "LREAL"),
        ("k", "TIME"),
    ]


def test_user_structs_and_enums_from_their_st_text() -> None:
    types = parse_st_types(
        """TYPE Motor :
STRUCT
    current : REAL;
    state : State;
    temps : ARRAY[0..1] OF INT;
END_STRUCT
END_TYPE
TYPE State : (IDLE, RUNNING := 5, FAULT) DINT; END_TYPE
TYPE Mode : (A, B); END_TYPE
TYPE Percent : REAL; END_TYPE"""
    )
    values = declared_values(
        "VAR_GLOBAL m : Motor; ms : ARRAY[0..1] OF Mode; p : Percent; END_VAR", types
    )
    assert [(n, t.name) for n, t in values] == [
        ("m.current", "REAL"),
        ("m.state", "DINT"),
        ("m.temps[0]", "INT"),
        ("m.temps[1]", "INT"),
        ("ms[0]", "INT"),
        ("ms[1]", "INT"),
        ("p", "REAL"),
    ]
    with pytest.raises(GvlError, match=r"line 1: x: type Unknown is not elementary.*Motor"):
        declared_values("VAR_GLOBAL x : Unknown; END_VAR", types)


def test_what_is_refused_says_why(tmp_path: Path) -> None:
    decl = "VAR_GLOBAL\n\tx : INT;\nEND_VAR"
    for text, why in (
        (_gvl(decl, Checksum="True"), "Checksum is on: its algorithm is not published"),
        (_gvl(decl, Acknowledge="TRUE"), "Acknowledge is on: the acknowledgement telegram"),
        (_gvl(decl, ListIdentifier="70000"), "ListIdentifier>70000: give the list's number"),
        (_gvl(decl, Interval="50ms"), "Interval>: '50ms' is no TIME literal"),
        (_gvl(decl, Pack="yes"), "<Pack>yes</Pack>: write True or False"),
        (_gvl("VAR_GLOBAL\n\tx : INT;\n\ty INT;\nEND_VAR"), r"line 4: 'y INT': write NAME : TYPE"),
        (_gvl("VAR_GLOBAL\n\tx : INT;\n\tx : INT;\nEND_VAR"), "line 4: x is declared twice"),
        (_gvl("x : INT;"), "no VAR_GLOBAL"),
        (_gvl("VAR_GLOBAL\n\ta : ARRAY[0..N] OF INT;\nEND_VAR"), "no constants"),
        (_gvl("VAR_GLOBAL CONSTANT\n\ta : INT;\nEND_VAR"), "constants are not network"),
        (_gvl("VAR_GLOBAL\n\ts : STRING(300);\nEND_VAR"), "takes 301 bytes"),
        (_gvl(decl).replace('Protocol="UDP"', 'Protocol="CAN"'), "Protocol CAN"),
        ("<GVL><Declarations>", "not XML"),
        ('<!DOCTYPE x [<!ENTITY a "b">]><GVL/>', "DOCTYPE"),
        ("<NVL/>", "starts with <GVL>"),
    ):
        with pytest.raises(GvlError, match=why):
            loads_gvl(text, source="x.gvl")
    for text, why in (
        (_gvl(decl, Interval="T#0.5ms"), "every 0.5 ms would flood the network"),
        (_gvl("VAR_GLOBAL\n\tt : LTIME;\nEND_VAR"), "LTIME: how it goes in a telegram"),
        (_gvl("VAR_GLOBAL\n\ts : STRING(0);\nEND_VAR"), "a string of 1 to 65535 characters"),
        (
            _gvl(decl).replace('Value="1202"', 'Value="\u00b2"'),
            "Port '\u00b2': give a UDP port",
        ),
    ):
        with pytest.raises(GvlError, match=why):
            loads_gvl(text, source="x.gvl")
    with pytest.raises(GvlError, match=r"none\.gvl"):
        load_gvl(tmp_path / "none.gvl")
    assert iec_time("T#1s500ms") == 1.5 and iec_time("TIME#2m") == 120.0
    assert iec_time("t#1_000ms") == 1.0


def test_a_gvl_written_reads_back_the_same() -> None:
    lst = loads_gvl(CODESYS_EXPORT, name="plant")
    again = loads_gvl(dumps_gvl(lst), name="plant")
    assert again == lst
    # a list without its declarations' text (cobus's own): arrays as ARRAY, the rest by name
    bare = UdpVarList(
        "mine",
        12,
        layout(
            [
                ("speed", iec_type("REAL")),
                ("temps[0]", iec_type("INT")),
                ("temps[1]", iec_type("INT")),
                ("motor.current", iec_type("REAL")),
            ]
        ),
        modes=frozenset({"on_change"}),
        transmit="on_change",
        interval=None,
        min_gap=0.02,
    )
    text = dumps_gvl(bare)
    assert "\ttemps : ARRAY[0..1] OF INT;" in text and "motor_current : REAL;" in text
    back = loads_gvl(text, name="mine")
    assert [v.name for v in back.variables] == ["speed", "temps[0]", "temps[1]", "motor_current"]
    assert back.size == bare.size and back.modes == {"on_change"} and back.min_gap == 0.02


def test_what_the_review_of_the_gvl_reader_found() -> None:
    # a $' in a string, END_VAR in a string: initial values change nothing
    text = "VAR_GLOBAL s : STRING := 'it$'s; END_VAR'; n : INT; m : INT := 5; END_VAR"
    assert [n for n, _ in declared_values(text)] == ["s", "n", "m"]
    # subranges are their base type
    assert [t.name for _, t in declared_values("VAR_GLOBAL r : INT(0..10); END_VAR")] == ["INT"]
    # types that multiply past what a list takes stop at once
    bomb = parse_st_types(
        "TYPE S : STRUCT a : ARRAY[0..60000] OF BOOL; b : ARRAY[0..60000] OF BOOL; "
        "END_STRUCT END_TYPE TYPE T : STRUCT x : S; y : S; END_STRUCT END_TYPE"
    )
    with pytest.raises(GvlError, match="more than 65535 values in a list"):
        declared_values("VAR_GLOBAL t : ARRAY[0..1000] OF T; END_VAR", bomb)
    with pytest.raises(GvlError, match="line 1: UNION is not something cobus sends"):
        parse_st_types("TYPE U : UNION a : INT; b : REAL; END_UNION END_TYPE")
    # the event variable may be any BOOL of the project: read, and written back as it was
    gvl = _gvl(
        "VAR_GLOBAL\n\tx : INT;\nEND_VAR",
        TransmissionOnEvent="True",
        CyclicTransmission="False",
        EventVariable="PLC_PRG.xSend",
    )
    lst = loads_gvl(gvl)
    assert lst.event is None and lst.event_text == "PLC_PRG.xSend"
    assert "<EventVariable>PLC_PRG.xSend</EventVariable>" in dumps_gvl(lst)
    # an empty <Pack/> is the default: packed
    assert loads_gvl(_gvl("VAR_GLOBAL\n\tx : INT;\nEND_VAR", Pack="")).pack
    # names made for struct members never clash, the event goes with its new name
    flat = UdpVarList(
        "mine",
        1,
        layout(
            [
                ("motor.current", iec_type("REAL")),
                ("motor_current", iec_type("REAL")),
                ("cmd.go", iec_type("BOOL")),
            ]
        ),
        transmit="on_event",
        modes=frozenset({"on_event"}),
        event="cmd.go",
    )
    back = loads_gvl(dumps_gvl(flat), name="mine")
    assert [v.name for v in back.variables] == ["motor_current_2", "motor_current", "cmd_go"]
    assert back.event == "cmd_go"


def test_the_example_gvl_reads_and_a_hostile_one_stays_bounded(tmp_path: Path) -> None:
    import json
    import textwrap

    from tests.fuzz_inputs import EXAMPLES
    from tests.util import bounded_python

    line = load_gvl(EXAMPLES / "netvars/line.gvl")
    assert (line.name, line.list_id, line.interval, line.frames) == ("line", 1, 0.05, 1)
    assert [v.name for v in line.variables][:3] == ["speed", "running", "temps[0]"]
    # types that multiply to billions of values, huge arrays, deep nesting: refused at
    # once in a child with 1.5 GB of address space
    types = tmp_path / "bomb.st"
    types.write_text(
        "TYPE S : STRUCT a : ARRAY[0..60000] OF BOOL; b : ARRAY[0..60000] OF BOOL; "
        "END_STRUCT END_TYPE TYPE T : STRUCT x : ARRAY[0..9] OF S; END_STRUCT END_TYPE "
        "TYPE U : STRUCT y : ARRAY[0..9] OF T; END_STRUCT END_TYPE"
    )
    gvl = tmp_path / "bomb.gvl"
    gvl.write_text(_gvl("VAR_GLOBAL\n\tu : ARRAY[0..2000000000] OF U;\n\tv : U;\nEND_VAR"))
    code = textwrap.dedent(
        f"""
        import json, time
        from pathlib import Path
        from cobus.blocks.gvl import GvlError, load_gvl, parse_st_types
        t0 = time.perf_counter()
        try:
            load_gvl({str(gvl)!r}, types=parse_st_types(Path({str(types)!r}).read_text()))
            out = {{"error": None}}
        except GvlError as exc:
            out = {{"error": str(exc)}}
        out["seconds"] = time.perf_counter() - t0
        print(json.dumps(out))
        """
    )
    status, stdout, stderr = bounded_python(code, memory_mb=1500, seconds=60, cwd=tmp_path)
    assert status == 0, stderr[-2000:]
    result = json.loads(stdout)
    assert "more than 65535 values in a list" in result["error"]
    assert result["seconds"] < 10


def test_what_the_second_review_found() -> None:
    # cobus's names as a .gvl: once whatever the case, no keyword, no leading digit
    flat = UdpVarList(
        "mine",
        1,
        layout(
            [
                ("Speed", iec_type("REAL")),
                ("speed", iec_type("REAL")),
                ("_1.a", iec_type("BOOL")),
                ("end_var", iec_type("INT")),
                ("int[0]", iec_type("INT")),
                ("int[1]", iec_type("INT")),
                ("mod", iec_type("BOOL")),
            ]
        ),
    )
    back = loads_gvl(dumps_gvl(flat), name="mine")
    assert [v.name for v in back.variables] == [
        "Speed",
        "speed_2",
        "v_1_a",
        "v_end_var",
        "v_int[0]",
        "v_int[1]",
        "v_mod",
    ]
    assert back.size == flat.size
    # a string or comment that does not end hides nothing: refused, with its line
    for text, why in (
        (
            "VAR_GLOBAL a : INT; END_VAR\nVAR_GLOBAL s : STRING := 'x; END_VAR",
            "line 2: a string does not end",
        ),
        ("VAR_GLOBAL a : INT; (* no end\nEND_VAR", "line 1: a \\(\\* comment does not end"),
        ("{attribute 'x'\nVAR_GLOBAL a : INT; END_VAR", "line 1: a \\{ pragma does not end"),
    ):
        with pytest.raises(GvlError, match=why):
            declared_values(text)
    # the event variable: empty, or a variable of the list that is no BOOL: refused
    decl = "VAR_GLOBAL\n\ti : INT;\nEND_VAR"
    for event, why in (("\n    ", "EventVariable> is empty"), ("i", "a INT; the event is a BOOL")):
        with pytest.raises(GvlError, match=why):
            loads_gvl(_gvl(decl, TransmissionOnEvent="True", EventVariable=event))
