"""The network description: reading, checking (file, line, node, key, reason), the start-up SDO
lists derived from EDS/DCF and the file, the process image layout, DCF and concise DCF."""

from __future__ import annotations

import re
import struct
from pathlib import Path

import pytest

from cobus.cli import main as cli
from cobus.device import DictionaryBuilder
from cobus.master import (
    NetworkConfigError,
    NodeNotFoundError,
    Severity,
    SignalValueError,
    check_network,
    load_network,
    loads_network,
)
from cobus.od import DataType, ObjectDictionary, Variable, load
from cobus.proto.pdo import Kind
from tests.test_master_support import io_od, network, write_eds

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = ROOT / "examples" / "networks"

BASIC = """
master: {node_id: 127, bitrate: 250000, sync_period: 10, heartbeat_time: 50}
defaults: {heartbeat_time: 100, sdo_timeout: "0.5 s"}
nodes:
  io1:
    node_id: 5
    eds: io.eds
    mandatory: true
    device_type: 0x191
    vendor_id: 0x00C0B05
    tpdo1: {mapping: [Counter, "0x2003:00"], transmission_type: 255, event_timer: 50}
    rpdo1: {mapping: [setpoint, flags], transmission_type: 1}
    sdo: [{object: parameter, value: 9}]
    signals:
      count: {object: counter, scale: 0.5, offset: 1, unit: pieces}
      temp: temperature
"""


def var(od: ObjectDictionary, index: int, sub: int = 0) -> Variable:
    found = od.get_variable(index, sub)
    assert found is not None
    return found


def problems_of(folder: Path, text: str) -> list[str]:
    write_eds(folder)
    (folder / "net.yml").write_text(text, encoding="utf-8")
    _cfg, problems = check_network(folder / "net.yml")
    return [str(p) for p in problems if p.severity is Severity.ERROR]


def test_a_network_file_becomes_nodes_with_their_start_up_lists(tmp_path):
    cfg = network(tmp_path, BASIC)
    assert cfg.master.node_id == 127
    assert cfg.master.bitrate == 250_000
    assert cfg.master.sync_period_us == 10_000
    node = cfg.node("io1")
    assert node is cfg.nodes[5]
    assert node.mandatory and node.heartbeat_time == 100 and node.sdo_timeout == 0.5
    assert node.heartbeat_consumer_time == pytest.approx(0.15)
    # the generic part (1006h: the master's SYNC period), then each PDO in CiA 301 order,
    # then the explicit entries
    assert [str(e) for e in node.startup] == [
        "0x1006:00 = 0x2710 (Communication cycle period)",
        "0x1400:01 = 0x80000205 (RPDO 1: disable)",
        "0x1600:00 = 0x0 (RPDO 1: clear mapping)",
        "0x1600:01 = 0x20010010 (RPDO 1: map)",
        "0x1600:02 = 0x20020008 (RPDO 1: map)",
        "0x1600:00 = 0x2 (RPDO 1: mapped objects)",
        "0x1400:02 = 0x1 (RPDO 1: Transmission type)",
        "0x1400:01 = 0x205 (RPDO 1: enable)",
        "0x1800:01 = 0x80000185 (TPDO 1: disable)",
        "0x1A00:00 = 0x0 (TPDO 1: clear mapping)",
        "0x1A00:01 = 0x20000010 (TPDO 1: map)",
        "0x1A00:02 = 0x20030020 (TPDO 1: map)",
        "0x1A00:00 = 0x2 (TPDO 1: mapped objects)",
        "0x1800:05 = 0x32 (TPDO 1: Event timer)",
        "0x1800:01 = 0x185 (TPDO 1: enable)",
        "0x200A:00 = 0x9 (Parameter)",
    ]
    assert node.startup[0].data == (10_000).to_bytes(4, "little")
    assert [str(e) for e in node.error_control_entries()] == [
        "0x1017:00 = 0x64 (producer heartbeat time)"
    ]
    assert [str(e) for e in node.error_control_entries("guarding")] == [
        "0x100C:00 = 0x64 (guard time)",
        "0x100D:00 = 0x3 (life time factor)",
    ]
    (tpdo,) = node.tpdos
    assert (tpdo.number, tpdo.cob_id, tpdo.transmission_type, tpdo.length) == (1, 0x185, 255, 6)
    assert tpdo.timeout == pytest.approx(0.15)  # event timer x pdo_timeout_factor 3
    count, temp = tpdo.signals
    assert (count.name, count.kind, count.scale, count.offset, count.unit) == (
        "io1.count",
        Kind.UNSIGNED,
        0.5,
        1.0,
        "pieces",
    )
    assert count.to_engineering(10) == 6.0 and count.to_raw(6.0) == 10
    with pytest.raises(SignalValueError, match=r"io1\.count: 'x' is not a number"):
        count.to_raw("x")
    with pytest.raises(NodeNotFoundError, match=r"no node 'io2'.*io1 \(5\)"):
        cfg.node("io2")
    assert (temp.name, temp.kind) == ("io1.temp", Kind.REAL32)
    (rpdo,) = node.rpdos
    assert [s.name for s in rpdo.signals] == ["io1.setpoint", "io1.flags"]
    assert rpdo.timeout is None and rpdo.synchronous
    assert node.aliases == {"count": "counter", "temp": "temperature"}
    assert set(cfg.signals) == {"io1.count", "io1.temp", "io1.setpoint", "io1.flags"}


def test_concise_dcf_holds_every_write_of_the_boot_up(tmp_path):
    node = network(tmp_path, BASIC).node("io1")
    blob = node.concise_dcf()
    (count,) = struct.unpack_from("<I", blob)
    entries, pos = [], 4
    for _ in range(count):
        index, sub, size = struct.unpack_from("<HBI", blob, pos)
        pos += 7
        entries.append((index, sub, blob[pos : pos + size]))
        pos += size
    assert pos == len(blob)
    expected = [(e.index, e.subindex, e.data) for e in node.startup]
    assert entries == [*expected, (0x1017, 0, (100).to_bytes(2, "little"))]


def test_the_dcf_written_holds_the_configuration_as_parameter_values(tmp_path):
    cfg = network(tmp_path, BASIC)
    written = cfg.write_dcfs(tmp_path / "out")
    assert [p.name for p in written] == ["io1.dcf", "io1.bin"]
    dcf = load(tmp_path / "out" / "io1.dcf")
    assert dcf.commissioning is not None
    assert (dcf.commissioning.node_id, dcf.commissioning.baudrate) == (5, 250)
    assert var(dcf, 0x1A00, 1).parameter_value == 0x20000010
    assert var(dcf, 0x1600, 0).parameter_value == 2
    assert var(dcf, 0x1017).parameter_value == 100
    assert var(dcf, 0x200A).parameter_value == 9
    # read back as the node's file, it configures the node the same way
    again = loads_network(
        "nodes: {io1: {node_id: 5, dcf: out/io1.dcf}}", base_dir=tmp_path, path="again.yml"
    ).node("io1")
    assert again.heartbeat_time == 100  # taken from the DCF's 1017h
    wanted = {(e.index, e.subindex, e.data) for e in cfg.node("io1").startup}
    assert {(e.index, e.subindex, e.data) for e in again.startup} == wanted


def test_start_up_list_from_a_dcf_takes_only_writable_changed_values(tmp_path):
    od = io_od()
    var(od, 0x200A).parameter_value = 11  # changed: written
    var(od, 0x1015).parameter_value = 0  # equal to the default: not written
    var(od, 0x1018, 1).parameter_value = 0x99  # read-only: never written
    var(od, 0x1010, 1).parameter_value = 0x65766173  # "save": a command, never in the list
    (tmp_path / "dev.dcf").write_text(od.to_dcf(9), encoding="utf-8")
    text = "nodes: {n: {node_id: 9, dcf: dev.dcf, heartbeat_time: 100}}"
    node = loads_network(text, base_dir=tmp_path).node("n")
    assert [(e.index, e.subindex, e.value) for e in node.startup] == [(0x200A, 0, 11)]
    text = "nodes: {n: {node_id: 9, dcf: dev.dcf, heartbeat_time: 100, sdo_from_dcf: false}}"
    assert loads_network(text, base_dir=tmp_path).node("n").startup == []


def test_all_pdo_objects_switch_writes_every_pdo(tmp_path):
    text = "nodes: {n: {node_id: 9, eds: io.eds, heartbeat_time: 100, sdo_all_pdo: true}}"
    node = network(tmp_path, text).node("n")
    pdo_writes = [e for e in node.startup if 0x1400 <= e.index <= 0x1BFF]
    # 4 RPDOs and 4 TPDOs of the device: disable, clear, count, type, inhibit, timer, (sync
    # start), enable; none is mapped, so no entries
    assert len({e.index for e in pdo_writes}) == 16
    assert sum(1 for e in pdo_writes if e.name.endswith("enable")) == 8
    assert node.tpdos == [] and node.rpdos == []


def test_objects_are_found_by_name_in_any_case_or_by_address(tmp_path):
    text = """
nodes:
  n:
    node_id: 9
    eds: io.eds
    heartbeat_time: 100
    tpdo2: {mapping: ["  COUNTER ", "0x2004", "digital inputs.Digital Inputs 1", dummy8,
                      "Digital inputs[2]"], cob_id: 0x1A0}
    tpdo3: {mapping: ["0x2000sub0"], cob_id: 0x1A1, enabled: false}
"""
    node = network(tmp_path, text).node("n")
    (tpdo2,) = node.tpdos  # TPDO 3 is disabled: not in the process image
    assert [(s.index, s.subindex) for s in tpdo2.signals] == [
        (0x2000, 0),
        (0x2004, 0),
        (0x6000, 1),
        (0x6000, 2),
    ]
    assert [s.name for s in tpdo2.signals] == [
        "n.counter",
        "n.ready",
        "n.digital_inputs.digital_inputs_1",
        "n.digital_inputs.digital_inputs_2",
    ]
    assert tpdo2.codec.entries[3].is_dummy and tpdo2.length == 6
    writes = {(e.index, e.subindex): e.value for e in node.startup}
    assert writes[(0x1802, 1)] == 0x800001A1  # disabled
    assert writes[(0x1A01, 3)] == 0x60000108


@pytest.mark.parametrize(
    ("snippet", "key", "reason"),
    [
        ("    colour: red\n", "colour", "unknown key"),
        ("    mandatroy: true\n", "mandatroy", "did you mean 'mandatory'"),
        ("    heartbeat_time: 12.5\n", "heartbeat_time", "not a whole number"),
        ("    heartbeat_time: -5\n", "heartbeat_time", "out of range"),
        ("    sdo_timeout: soon\n", "sdo_timeout", "not a duration"),
        ("    error_reaction: panic\n", "error_reaction", "not one of none, stop_node"),
        ("    tpdo1: {mapping: [setpointt]}\n", "tpdo1.mapping[0]", "did you mean 'Setpoint'"),
        ("    tpdo1: {mapping: [parameter]}\n", "tpdo1.mapping[0]", "not PDO-mappable"),
        ("    rpdo1: {mapping: [counter]}\n", "rpdo1.mapping[0]", "cannot go in an RPDO"),
        ("    tpdo1: {mapping: [0x6041]}\n", "tpdo1.mapping[0]", "in quotes"),
        (
            "    tpdo1: {mapping: [counter, temperature, temperature]}\n",
            "tpdo1.mapping",
            "80 bits",
        ),
        ("    tpdo1: {cob_id: 0x605}\n", "tpdo1.cob_id", "restricted"),
        ("    rpdo1: {transmission_type: 252}\n", "rpdo1.transmission_type", "TPDOs only"),
        ("    tpdo1: {transmission_type: 245}\n", "tpdo1.transmission_type", "reserved"),
        ("    tpdo9: {mapping: [counter]}\n", "tpdo9", "has no TPDO 9"),
        ("    tpdo1: {every: 2}\n", "tpdo1.every", "unknown PDO setting"),
        ("    signals: {x: counter}\n", "signals.x", "not mapped in any valid PDO"),
        (
            "    tpdo1: {mapping: [ready]}\n    signals: {r: {object: ready, scale: 2}}\n",
            "signals.r",
            "cannot be scaled",
        ),
        ("    sdo: [{object: counter, value: 1}]\n", "sdo[0].object", "is ro"),
        ("    sdo: [{object: setpoint, value: 5000}]\n", "sdo[0].value", "above the HighLimit"),
        ("    watch_master: true\n", "watch_master", "needs node_id and heartbeat_time"),
        ("    node_id: 200\n", "node_id", "out of range"),
    ],
)
def test_errors_name_file_line_node_key_and_reason(tmp_path, snippet, key, reason):
    text = "nodes:\n  n:\n    eds: io.eds\n" + snippet
    if "node_id" not in snippet:
        text += "    node_id: 9\n"
    if "heartbeat_time" not in snippet:
        text += "    heartbeat_time: 100\n"
    errors = problems_of(tmp_path, text)
    assert errors, "expected an error"
    head = re.split(r"[.\[]", key)[0] + ":"
    line = next(i for i, t in enumerate(text.splitlines(), 1) if t.strip().startswith(head))
    first = errors[0]
    assert first.startswith(f"{tmp_path / 'net.yml'}:{line}: node 'n': {key}: error:"), first
    assert reason in first, first


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("nodes: [1, 2]\n", "nodes: error: give the nodes"),
        ("master: {bitrate: 300000}\nnodes: {}\n", "master.bitrate: error: 300000 bit/s is no"),
        ("master: {node_id: 5}\nnodes: {n: {node_id: 5, eds: io.eds}}\n", "master's own node-ID"),
        ("master: {heartbeat_time: 100}\nnodes: {}\n", "a master heartbeat needs"),
        (
            "nodes: {a: {node_id: 5, eds: io.eds}, b: {node_id: 5, eds: io.eds}}\n",
            "node 'b': node_id: error: node-ID 5 is used by node 'a' too",
        ),
        ("nodes: {a: {node_id: 5}}\n", "eds: error: give the node's EDS"),
        ("nodes: {a: {node_id: 5, eds: nope.eds}}\n", "eds: error: cannot read"),
        ("nodes: {a: {node_id: 5, eds: io.eds}}\nnode: {}\n", "did you mean 'nodes'"),
        ("defaults: {node_id: 3}\nnodes: {a: {node_id: 5, eds: io.eds}}\n", "defaults.node_id"),
        ("nodes: {a: {node_id: 5, eds: io.eds}, a: {node_id: 6, eds: io.eds}}\n", "given twice"),
        ("nodes: {a: {node_id: 5, eds: io.eds}\n", "not valid YAML"),
        ("nodes: {1a: {node_id: 5, eds: io.eds}}\n", "node names start with a letter"),
        (
            "nodes:\n  a: {node_id: 5, eds: io.eds, tpdo1: {mapping: [counter]}}\n"
            "  b: {node_id: 6, eds: io.eds, tpdo1: {mapping: [counter], cob_id: 0x185}}\n",
            "also sent by a TPDO 1",
        ),
        (
            "nodes: {a: {node_id: 5, eds: io.eds, sdo: [{object: setpoint, value: 1}],"
            " sdo_timeout: 0}}\n",
            "sdo_timeout: error: must be above 0 ms",
        ),
    ],
)
def test_network_level_errors(tmp_path, text, expected):
    errors = problems_of(tmp_path, text)
    assert any(expected in e for e in errors), errors


def test_signal_names_stay_unique_when_the_eds_repeats_names(tmp_path):
    b = DictionaryBuilder()
    inputs = b.array(0x6000, "Inputs", DataType.UNSIGNED8, 2, access="ro", mappable=True)
    for var in inputs:
        var.name = "Input" if var.subindex else var.name  # sub-objects of one name
    b.variable(0x2000, "Speed", DataType.INTEGER16, access="ro", mappable=True)
    b.variable(0x2001, "Speed", DataType.INTEGER16, access="ro", mappable=True)
    od = b.build()
    write_eds(tmp_path, "same.eds", od)
    text = (
        "nodes: {n: {node_id: 9, eds: same.eds, heartbeat_time: 100,"
        ' tpdo1: {mapping: ["inputs[1]", "inputs[2]", "0x2000", "0x2001"]}}}'
    )
    (tpdo,) = loads_network(text, base_dir=tmp_path).node("n").tpdos
    assert [s.name for s in tpdo.signals] == [
        "n.inputs[1]",
        "n.inputs[2]",
        "n.speed_2000",
        "n.speed_2001",
    ]


def test_warnings_do_not_stop_loading(tmp_path):
    write_eds(tmp_path)
    (tmp_path / "net.yml").write_text(
        "nodes:\n"
        "  a: {node_id: 5, eds: io.eds, tpdo1: {mapping: [counter]}}\n"
        "  b: {node_id: 6, eds: io.eds, heartbeat_time: 100, rpdo1: {mapping: [setpoint],"
        " cob_id: 0x185}}\n",
        encoding="utf-8",
    )
    cfg = load_network(tmp_path / "net.yml")
    reasons = [str(w) for w in cfg.warnings]
    assert any("node 'a'" in r and "cannot tell when this node fails" in r for r in reasons)
    assert any("PDO linking" in r for r in reasons)
    (linked,) = cfg.node("b").rpdos
    assert linked.linked and linked.signals == ()


def test_load_network_raises_with_every_error(tmp_path):
    write_eds(tmp_path)
    (tmp_path / "net.yml").write_text(
        "nodes:\n  a: {node_id: 5, eds: io.eds, colour: red, mandatory: maybe}\n",
        encoding="utf-8",
    )
    with pytest.raises(NetworkConfigError) as err:
        load_network(tmp_path / "net.yml")
    assert len([p for p in err.value.problems if p.severity is Severity.ERROR]) == 2
    assert "colour" in str(err.value) and "mandatory" in str(err.value)


def test_cli_check_exit_codes(tmp_path, capsys):
    write_eds(tmp_path)
    good = tmp_path / "good.yml"
    good.write_text("nodes: {a: {node_id: 5, eds: io.eds, heartbeat_time: 100}}\n")
    warn = tmp_path / "warn.yml"
    warn.write_text("nodes: {a: {node_id: 5, eds: io.eds}}\n")
    bad = tmp_path / "bad.yml"
    bad.write_text("nodes: {a: {node_id: 5, eds: io.eds, heartbeat_time: x}}\n")
    assert cli(["config", "check", str(good)]) == 0
    assert cli(["config", "check", str(warn)]) == 1
    assert cli(["config", "check", str(bad)]) == 2
    out = capsys.readouterr().out
    assert f"{bad}:1: node 'a': heartbeat_time: error:" in out
    assert cli(["config", "check", str(tmp_path / "missing.yml")]) == 2
    assert cli(["config", "check", "-v", str(good)]) == 0
    assert "0x1017:00 = 0x64" in capsys.readouterr().out


def test_cli_writes_dcfs(tmp_path, capsys):
    write_eds(tmp_path)
    (tmp_path / "net.yml").write_text(BASIC)
    assert cli(["config", "dcf", str(tmp_path / "net.yml"), str(tmp_path / "out")]) == 0
    assert (tmp_path / "out" / "io1.dcf").is_file() and (tmp_path / "out" / "io1.bin").is_file()
    (tmp_path / "bad.yml").write_text("nodes: {a: {node_id: 500, eds: io.eds}}\n")
    assert cli(["config", "dcf", str(tmp_path / "bad.yml"), str(tmp_path / "out2")]) == 2
    assert not (tmp_path / "out2").exists()


def test_example_networks_are_clean():
    files = sorted(EXAMPLES.glob("*.yml"))
    assert files, "examples/networks has no network files"
    # (the ZAPI inverter of the thesis bench has neither heartbeat nor guarding: its
    # synchronous TPDO1, which the master supervises, tells when it fails)
    for path in files:
        cfg, problems = check_network(path)
        assert cfg is not None, [str(p) for p in problems]
        assert [str(p) for p in problems] == []
        assert cli(["config", "check", str(path)]) == 0  # as the files' headers say to run it


def test_a_node_nothing_watches_is_a_warning(tmp_path):
    import shutil

    shutil.copy(EXAMPLES / "zapi.eds", tmp_path / "zapi.eds")
    net = (
        "master: {sync_period: 20}\nnodes:\n  z: {node_id: 8, eds: zapi.eds, heartbeat_time: 0%s}\n"
    )

    def problems_of(extra: str) -> list[str]:
        (tmp_path / "net.yml").write_text(net % extra)
        _cfg, problems = check_network(tmp_path / "net.yml")
        return [str(p) for p in problems]

    assert problems_of("") == []  # its synchronous TPDO1 is supervised
    off = "".join(f", tpdo{n}: {{enabled: false}}" for n in range(1, 5))
    assert any("nor a supervised TPDO" in p for p in problems_of(off))


def test_dcf_values_beyond_the_eds_limits_are_written_with_a_warning(tmp_path):
    od = io_od()
    var(od, 0x2001).parameter_value = 500  # Setpoint, limits -1000..1000
    var(od, 0x200A).parameter_value = 8
    text = od.to_dcf(9).replace("ParameterValue=500", "ParameterValue=1500")
    (tmp_path / "dev.dcf").write_text(text, encoding="utf-8")
    net = "nodes: {n: {node_id: 9, dcf: dev.dcf, heartbeat_time: 100}}"
    node = loads_network(net, base_dir=tmp_path, path="net.yml").node("n")
    assert [(e.index, e.value, e.data) for e in node.startup] == [
        (0x2001, 1500, (1500).to_bytes(2, "little")),
        (0x200A, 8, (8).to_bytes(4, "little")),
    ]
    (tmp_path / "net.yml").write_text(net, encoding="utf-8")
    _cfg, problems = check_network(tmp_path / "net.yml")
    (warning,) = [str(p) for p in problems if "limits" in str(p)]
    assert "dcf: warning: 0x2001:00 (Setpoint) is configured as 1500" in warning
    assert "it is written as configured (line" in warning
    # a value the type itself cannot hold is an error, at its line in the DCF
    (tmp_path / "dev.dcf").write_text(text.replace("ParameterValue=1500", "ParameterValue=70000"))
    errors = problems_of(tmp_path, net)
    assert len(errors) == 1, errors
    assert "dcf: error:" in errors[0] and "dev.dcf:" in errors[0]
    assert "'70000' = 70000 is out of range for INTEGER16" in errors[0]
    assert "the master cannot write it" in errors[0]


@pytest.mark.parametrize(
    ("text", "reason"),
    [
        ("master: {node_id: 1}\nnodes:\n  a: \x01\n", "3: error: not valid YAML: character 0x1"),
        ("? [a, b]\n: 1\n", "1: error: not valid YAML: a key must be a plain value"),
        ("[" * 100_000, "not valid YAML: nested too deeply to read"),
        ("a: " + "{b: " * 5000 + "1" + "}" * 5000, "nested too deeply to read"),
    ],
    ids=["control character", "list as a key", "deep sequence", "deep mapping"],
)
def test_hostile_yaml_is_a_config_error_with_its_line(tmp_path, text, reason):
    with pytest.raises(NetworkConfigError, match=re.escape(reason)):
        loads_network(text)
    path = tmp_path / "hostile.yml"
    path.write_text(text)
    cfg, problems = check_network(path)  # cobus config check's path
    assert cfg is None and any(reason.split("error: ")[-1] in str(p) for p in problems)
