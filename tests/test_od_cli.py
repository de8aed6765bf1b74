"""``cobus eds check|show|doc`` on corpus files and broken ones."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from cobus.cli import main
from tests.conftest import EDS_DIR

BROKEN = Path(__file__).parent / "data" / "broken_eds"
FINDING = re.compile(r"^(?P<file>.+?):(?P<line>\d+): (\[(?P<sect>[^\]]+)\] )?(warning|error): .+$")


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(["eds", *argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_check_clean_file_exits_0(capsys):
    code, out, err = run(capsys, "check", str(BROKEN / "valid.eds"))
    assert code == 0 and out == ""
    assert "7 objects, 0 error(s), 0 warning(s)" in err


def test_check_warnings_exit_1(capsys):
    path = str(EDS_DIR / "kacanopen_406.eds")
    code, out, _ = run(capsys, "check", path)
    assert code == 1
    assert out == (
        f"{path}:57: [OptionalObjects] warning: SupportedObjects=64 but 67 objects are listed\n"
    )


def test_check_errors_exit_2_one_line_per_finding(capsys):
    path = str(EDS_DIR / "canopen-python_sample.eds")
    code, out, err = run(capsys, "check", path)
    assert code == 2
    lines = out.splitlines()
    assert len(lines) == 23 and "18 error(s), 5 warning(s)" in err
    numbers = []
    for line in lines:
        m = FINDING.match(line)
        assert m and m["file"] == path, line
        numbers.append(int(m["line"]))
    assert numbers == sorted(numbers)  # like a compiler: in file order
    assert f"{path}:77: [1018] error: missing sub-object: SubNumber=5" in out


def test_check_broken_file(capsys):
    path = str(BROKEN / "pdo_over_64_bits.eds")
    code, out, _ = run(capsys, "check", path)
    assert (code, out) == (
        2,
        f"{path}:94: [1A00sub0] error: TPDO mapping 0x1A00 maps 72 bits; a PDO carries "
        "at most 64\n",
    )


def test_check_unreadable_file(capsys, tmp_path):
    code, out, err = run(capsys, "check", str(tmp_path / "nope.eds"))
    assert code == 2 and out == "" and "cannot read the file" in err


def test_eds_without_action_prints_usage(capsys):
    code, out, _ = run(capsys)
    assert code == 2 and "check" in out and "show" in out and "doc" in out


def test_show_lists_objects(capsys):
    code, out, _ = run(capsys, "show", str(EDS_DIR / "lely_co-sdev.dcf"))
    assert code == 0
    lines = out.splitlines()
    assert lines[0].endswith("28 objects")
    assert re.match(r"Index\s+Sub\s+Name\s+Type\s+Access\s+PDO\s+Default\s+Value$", lines[2])
    assert re.search(r"^0x1018\s+Identity object\s+RECORD$", out, re.M)
    assert re.search(r"^0x1018\s+1\s+Vendor-ID\s+UNSIGNED32\s+ro\s+0x360$", out, re.M)
    assert re.search(r"^0x2009\s+VISIBLE_STRING\s+VISIBLE_STRING\s+rw\s+Hello, World!$", out, re.M)
    assert re.search(r"^0x200C\s+TIME_OF_DAY\s+TIME_OF_DAY\s+rw\s+365 43200000$", out, re.M)


def test_show_resolves_node_id(capsys):
    path = str(EDS_DIR / "canopennode_ds301_profile.eds")
    _, plain, _ = run(capsys, "show", path)
    assert re.search(r"^0x1014\s+COB-ID EMCY\s+UNSIGNED32\s+rw\s+\$NODEID\+0x80$", plain, re.M)
    _, resolved, _ = run(capsys, "show", "--node-id", "5", path)
    assert re.search(r"^0x1014\s+COB-ID EMCY\s+UNSIGNED32\s+rw\s+0x85$", resolved, re.M)


def test_doc_is_a_datasheet(capsys):
    code, out, _ = run(capsys, "doc", "--node-id", "1", str(EDS_DIR / "elmo_elmo.eds"))
    assert code == 0
    assert out.startswith("# ")
    for heading in ("## Identity", "## PDOs", "### RPDO 1", "### TPDO 1", "## Objects"):
        assert f"\n{heading}\n" in out
    assert "| Device type (0x1000) | 0x00000192 CiA 402 drives and motion control |" in out
    assert "| Vendor | Elmo Motion Control (0x0000009A) |" in out
    assert "| Bit rates (kbit/s) | 50, 125, 250, 500, 1000 |" in out
    assert "> 1. Added 100K baud to Device Information" in out  # [Comments]
    # TPDO 1 of the Elmo drive maps the statusword by default.
    tpdo1 = out.split("### TPDO 1")[1].split("###")[0]
    assert "Communication 0x1800: COB-ID 0x181 ($NODEID+0x180)" in tpdo1
    assert "| 1 | 0x6041sub0 | statusword | 16 |" in tpdo1
    assert "| 0x6040 |  | controlword | UNSIGNED16 | rww | yes | 0x0 | 0x0 … 0xFFFF |  |" in out
    assert "## Notes" in out  # the file has a finding; the doc says so


def test_doc_of_every_corpus_file_renders(capsys):
    for path in sorted(EDS_DIR.glob("*.[ed][dc][sf]")):
        code, out, _ = run(capsys, "doc", str(path))
        assert code == 0 and "## Objects" in out, path.name


def test_convert_an_eds_to_a_node_dcf_and_back(capsys, tmp_path):
    from cobus.od import load

    source = Path(__file__).resolve().parent.parent / "examples" / "networks" / "servo.eds"
    dcf = tmp_path / "servo10.dcf"
    code, _, err = run(capsys, "convert", str(source), str(dcf), "--node-id", "10")
    assert code == 0 and "DCF for node 10" in err
    od = load(dcf)
    assert od.node_id == 10 and len(od) == len(load(source))
    eds = tmp_path / "back.eds"
    assert run(capsys, "convert", str(dcf), str(eds))[0] == 0
    assert len(load(eds)) == len(od)
    code, _, err = run(capsys, "convert", str(source), str(tmp_path / "x.dcf"))
    assert code == 2 and "give --node-id" in err


def test_convert_refuses_a_name_it_would_not_honour(capsys, tmp_path):
    """Issue 38 (9): `eds convert x.eds x.xdd` wrote an EDS under the .xdd name."""
    source = Path(__file__).resolve().parent.parent / "examples" / "networks" / "servo.eds"
    for name, why in (("x.xdd", "XDD/XDC (CiA 311) is not written"), ("x.txt", ".eds or .dcf")):
        code, _, err = run(capsys, "convert", str(source), str(tmp_path / name))
        assert code == 2 and why in err and err.count("\n") == 1
        assert not (tmp_path / name).exists()


def test_show_doc_and_convert_refuse_a_file_with_no_object(capsys, tmp_path):
    empty = tmp_path / "empty.eds"
    empty.write_text("; nothing\n")
    for argv in (
        ("show", str(empty)),
        ("doc", str(empty)),
        ("convert", str(empty), str(tmp_path / "o.dcf"), "--node-id", "3"),
    ):
        code, _, err = run(capsys, *argv)
        assert code == 2 and "the file defines no objects" in err
    assert not (tmp_path / "o.dcf").exists()
