"""Parameter sets from YAML, CSV and DCF: every problem named with file, line and key."""

from __future__ import annotations

import textwrap
from pathlib import Path

import pytest

from cobus.blocks import (
    ParameterFileError,
    ParameterSet,
    SaveCommand,
    load_parameters,
    loads_parameters,
)
from cobus.device import DictionaryBuilder, export_eds
from cobus.od import DataType, ObjectDictionary, loads


def dictionary() -> ObjectDictionary:
    b = DictionaryBuilder(device_type=0, device_name="ZAPI ACE2", rpdos=0, tpdos=0)
    b.variable(0x20A8, "main contactor voltage", DataType.UNSIGNED8, default=100, high=100)
    b.variable(0x2001, "acceleration time", DataType.UNSIGNED16, default=10)
    b.variable(0x2002, "ramp gain", DataType.REAL32, default=1.5)
    b.variable(0x2003, "motor type", DataType.VISIBLE_STRING, default="AC")
    b.variable(0x2004, "firmware", DataType.UNSIGNED16, default=7, access="ro")
    return loads(export_eds(b.od))


def y(text: str) -> str:
    return textwrap.dedent(text).lstrip()


def problems(exc: pytest.ExceptionInfo[ParameterFileError]) -> list[str]:
    return [str(p) for p in exc.value.problems]


def test_yaml_by_name_and_address_in_file_order_with_the_save_command() -> None:
    od = dictionary()
    pset = loads_parameters(
        y("""
        save: {subindex: 0}
        parameters:
          main_contactor_voltage: 90
          "0x2001:00": 25
          Ramp gain: 2.25
          motor type: PM
        """),
        od=od,
    )
    assert [(p.index, p.subindex, p.value) for p in pset] == [
        (0x20A8, 0, 90),
        (0x2001, 0, 25),
        (0x2002, 0, 2.25),
        (0x2003, 0, "PM"),
    ]
    assert pset.save == SaveCommand(0x1010, 0, b"save")
    assert str(pset[0]) == "0x20A8:00 main contactor voltage = 90"
    assert pset[(0x2001, 0)].data_type is DataType.UNSIGNED16
    assert pset[0].line == 3


def test_yaml_without_eds_needs_addresses_and_types() -> None:
    pset = loads_parameters(
        y("""
        save: false
        parameters:
          "0x20A8:00": {value: 90, type: UNSIGNED8}
          "2001sub0": {value: 0x19, type: u16}
        """)
    )
    assert pset.save is None
    assert [(p.index, p.value, p.data_type) for p in pset] == [
        (0x20A8, 90, DataType.UNSIGNED8),
        (0x2001, 25, DataType.UNSIGNED16),
    ]


def test_every_problem_is_named_with_file_line_and_key() -> None:
    with pytest.raises(ParameterFileError) as exc:
        loads_parameters(
            y("""
            parameters:
              main_contactor_volts: 90
              main_contactor_voltage: 101
              firmware: 3
              acceleration time: -1
              "0x20A8:00": 90
              "0x2001:00": {value: 5, type: UNSIGNED8}
              "0x2002:00": "fast"
            colour: red
            """),
            od=dictionary(),
            path="zapi.yml",
        )
    got = problems(exc)
    assert got[0].startswith("zapi.yml:9: colour: unknown key")
    assert "zapi.yml:2: main_contactor_volts: " in got[1]
    assert "did you mean 'main contactor voltage'" in got[1]
    assert got[2].startswith("zapi.yml:3: main_contactor_voltage: 101 is not a valid UNSIGNED8")
    assert "HighLimit" in got[2]
    assert got[3].startswith("zapi.yml:4: firmware: 'firmware' (ro) cannot be written")
    assert got[4].startswith("zapi.yml:5: acceleration time: -1 is not a valid UNSIGNED16")
    assert "type UNSIGNED8 differs from the EDS's UNSIGNED16" in got[5]
    assert got[6].startswith("zapi.yml:8: 0x2002:00: 'fast' is not a valid REAL32")
    assert "0x20A8:00: set twice (first on line 3)" not in " ".join(got)  # line 3 failed
    assert len(got) == 7


def test_an_object_set_twice_and_a_missing_type() -> None:
    with pytest.raises(ParameterFileError) as exc:
        loads_parameters(
            y("""
            parameters:
              main_contactor_voltage: 90
              "0x20a8:0": 80
            """),
            od=dictionary(),
            path="p.yml",
        )
    assert problems(exc) == ["p.yml:3: 0x20A8:00: set twice (first on line 2)"]
    with pytest.raises(ParameterFileError) as exc:
        loads_parameters('parameters: {"0x2001:00": 5, speed: 3}', path="p.yml")
    got = problems(exc)
    assert "p.yml:1: 0x2001:00: no EDS gives the type: add 'type:'" in got[0]
    assert "p.yml:1: speed: without an EDS objects are named by address" in got[1]


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("", "the file is empty"),
        ("- 1\n- 2\n", "the file must be a mapping"),
        ("parameters: [1, 2]\n", "parameters: give a mapping"),
        ("parameters: {a: 1\n", "not valid YAML"),
        ("parameters: {}\nparameters: {}\n", "parameters: the key is given twice"),
        ("save: {subindex: 300}\nparameters: {}\n", "save.subindex: 300 is not 0..255"),
        ("save: {signature: toolong}\nparameters: {}\n", "save.signature: 'toolong': give 4"),
        ('parameters: {"0x2001:00": {value: 1, type: INT99}}\n', "type 'INT99' is not a CiA"),
        ("parameters: {\x07: 1}\n", "control character"),
        ("[" * 5000, "not valid YAML"),
    ],
)
def test_malformed_files(text: str, expected: str) -> None:
    with pytest.raises(ParameterFileError) as exc:
        loads_parameters(text, path="bad.yml")
    assert expected in str(exc.value)


def test_csv_by_name_or_by_address(tmp_path: Path) -> None:
    (tmp_path / "zapi.csv").write_text(
        "object,value,comment\nmain contactor voltage,90,the thesis's example\n"
        "acceleration_time,0x19,\n\n"
    )
    pset = load_parameters(tmp_path / "zapi.csv", od=dictionary())
    assert [(p.index, p.value) for p in pset] == [(0x20A8, 90), (0x2001, 25)]
    assert pset.save == SaveCommand()
    (tmp_path / "raw.csv").write_text("index,subindex,value,type\n20A8h,0,90,UNSIGNED8\n")
    assert load_parameters(tmp_path / "raw.csv")[0].value == 90
    (tmp_path / "bad.csv").write_text(
        "index,subindex,value,type\n0x20A8,0,900,UNSIGNED8\nxyz,0,1,U8\n"
    )
    with pytest.raises(ParameterFileError) as exc:
        load_parameters(tmp_path / "bad.csv")
    got = problems(exc)
    assert got[0].startswith(f"{tmp_path / 'bad.csv'}:2: 0x20A8:00: '900' is not a valid UNSIGNED8")
    assert got[1].endswith("xyz:0: index and subindex must be numbers (0x20A8, 0)")
    (tmp_path / "header.csv").write_text("name,setting\n")
    with pytest.raises(
        ParameterFileError, match="the header lacks index, subindex, value: give object,value"
    ):
        load_parameters(tmp_path / "header.csv")


def test_a_dcf_gives_its_parameter_values_and_a_yaml_file_its_eds(tmp_path: Path) -> None:
    od = dictionary()
    var = od[0x20A8]
    var.parameter_value = 80  # type: ignore[union-attr]
    (tmp_path / "zapi.dcf").write_text(od.to_dcf(8))
    pset = load_parameters(tmp_path / "zapi.dcf")
    assert [(p.index, p.value) for p in pset] == [(0x20A8, 80)]
    (tmp_path / "zapi.eds").write_text(export_eds(dictionary()))
    (tmp_path / "p.yml").write_text("eds: zapi.eds\nparameters: {main contactor voltage: 70}\n")
    assert load_parameters(tmp_path / "p.yml")[0].index == 0x20A8
    (tmp_path / "q.yml").write_text("eds: missing.eds\nparameters: {}\n")
    with pytest.raises(ParameterFileError, match=r"q.yml:1: eds: cannot read .*missing.eds"):
        load_parameters(tmp_path / "q.yml")
    with pytest.raises(ParameterFileError, match="cannot read the file"):
        load_parameters(tmp_path / "none.yml")


def test_a_set_written_out_reads_back_the_same(tmp_path: Path) -> None:
    od = dictionary()
    pset = loads_parameters(
        "save: {subindex: 0}\nparameters: {main contactor voltage: 90, ramp gain: 0.1, "
        "motor type: 'PM: 4 poles'}\n",
        od=od,
    )
    for name in ("out.yml", "out.csv"):
        pset.write(tmp_path / name)
        again = load_parameters(tmp_path / name)  # without the EDS: types are in the file
        assert [(p.index, p.subindex, p.value, p.data_type) for p in again] == [
            (p.index, p.subindex, p.value, p.data_type) for p in pset
        ]
    assert load_parameters(tmp_path / "out.yml").save == SaveCommand(0x1010, 0)
    assert isinstance(load_parameters(tmp_path / "out.yml", od=od), ParameterSet)


def test_numbers_mean_what_they_say_and_files_from_excel_read(tmp_path: Path) -> None:
    od = dictionary()
    pset = loads_parameters("parameters: {acceleration time: 010}\n", od=od)
    assert pset[0].value == 10  # YAML 1.2: not octal
    with pytest.raises(ParameterFileError, match="'1:30' is not a valid UNSIGNED16"):
        loads_parameters("parameters: {acceleration time: 1:30}\n", od=od)
    with pytest.raises(ParameterFileError, match="more than 40 digits"):
        loads_parameters(f"parameters: {{acceleration time: {'9' * 5000}}}\n", od=od)
    with pytest.raises(ParameterFileError, match="give a finite number"):
        loads_parameters("parameters: {ramp gain: .inf}\n", od=od)
    with pytest.raises(ParameterFileError, match="not an address: index 0001h-FFFFh"):
        loads_parameters('parameters: {"0x2100:100": {value: 1, type: u8}}\n')
    (tmp_path / "excel.csv").write_bytes(
        "\ufeffindex,subindex,value,type\n2001h,0,25,UNSIGNED16\n20A8,0,,UNSIGNED8\n".encode()
    )
    with pytest.raises(ParameterFileError) as exc:
        load_parameters(tmp_path / "excel.csv")
    assert problems(exc) == [
        f"{tmp_path / 'excel.csv'}:3: 0x20A8:00: '' is not a valid UNSIGNED8: the value is missing"
    ]
    (tmp_path / "excel.csv").write_bytes(b"\xef\xbb\xbfindex,subindex,value\n2001,0,25\n")
    assert load_parameters(tmp_path / "excel.csv", od=od)[0].index == 0x2001  # hex index


def test_a_dcf_leaves_out_the_commands_and_the_pdo_parameters(tmp_path: Path) -> None:
    od = dictionary()
    od[0x1010][1].parameter_value = 0x65766173  # type: ignore[index]
    od[0x1017].parameter_value = 100  # type: ignore[union-attr]
    od[0x20A8].parameter_value = 80  # type: ignore[union-attr]
    (tmp_path / "zapi.dcf").write_text(od.to_dcf(8))
    pset = load_parameters(tmp_path / "zapi.dcf", save=SaveCommand(0x1010, 0))
    assert [(p.index, p.value) for p in pset] == [(0x1017, 100), (0x20A8, 80)]
    assert pset.save == SaveCommand(0x1010, 0)
    numeric = ParameterSet(pset.parameters, SaveCommand(0x1010, 1, b"\x78\x56\x34\x12"))
    numeric.write(tmp_path / "n.yml")
    assert load_parameters(tmp_path / "n.yml").save == numeric.save


def test_the_example_files_read_on_their_own() -> None:
    from cobus.blocks import load_netvars

    root = Path(__file__).resolve().parent.parent / "examples"
    zapi = load_parameters(root / "parameters" / "zapi.yml")  # names from its eds:
    assert zapi.save == SaveCommand(0x1010, 0) and zapi[0].index == 0x20A8
    assert len(load_parameters(root / "parameters" / "servo.yml")) == 3
    assert set(load_netvars(root / "netvars" / "plant.yml").lists) == {"status", "alarms"}
