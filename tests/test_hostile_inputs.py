"""Inputs that used to cost minutes or gigabytes (issue 39): each is refused or read within
seconds and a bounded amount of memory, with a typed error that says what to fix. What could
run away runs in a child Python under an address-space cap and a time limit."""

from __future__ import annotations

import json
import os
import textwrap
from pathlib import Path
from typing import Any

import pytest

from cobus._yaml import MAX_ALIAS_VALUES, read_yaml
from cobus.errors import clip
from tests.fuzz_inputs import EXAMPLES, ROOT, alias_bomb
from tests.util import bounded_python, need, need_module, until

# (example file, loader call, a key whose value a message names) of the four YAML inputs.
YAML_INPUTS = {
    "network": (
        EXAMPLES / "networks/thesis.yml",
        "from cobus.master import load_network as load",
        b"node_id",
    ),
    "rig": (
        ROOT / "src/cobus/sim/rigs/thesis.yaml",
        "from cobus.sim import Rig; load = Rig.load",
        b"bus",
    ),
    "parameters": (
        EXAMPLES / "parameters/servo.yml",
        "from cobus.blocks.parameters import load_parameters as load",
        b"profile velocity",
    ),
    "netvars": (
        EXAMPLES / "netvars/plant.yml",
        "from cobus.blocks.netvar_lists import load_netvars as load",
        b"interval",
    ),
}


def load_bounded(kind: str, path: Path) -> dict[str, str]:
    """Load ``path`` as ``kind`` in a capped child: what came out, as JSON."""
    _, loader, _ = YAML_INPUTS[kind]
    code = textwrap.dedent(
        f"""
        import json, time
        {loader}
        from cobus.errors import CobusError
        t0 = time.perf_counter()
        try:
            load({str(path)!r})
            out = {{"error": None, "message": ""}}
        except CobusError as exc:
            out = {{"error": type(exc).__name__, "message": str(exc)}}
        out["seconds"] = time.perf_counter() - t0
        print(json.dumps(out))
        """
    )
    status, stdout, stderr = bounded_python(code, memory_mb=1500, seconds=60, cwd=path.parent)
    assert status == 0, f"{kind}: exit {status}: {stderr[-2000:]}"
    result: dict[str, str] = json.loads(stdout)
    return result


@pytest.mark.parametrize("kind", sorted(YAML_INPUTS))
def test_an_alias_bomb_is_refused_at_once_in_every_yaml_input(kind: str, tmp_path: Path) -> None:
    source, _, key = YAML_INPUTS[kind]
    target = tmp_path / source.name
    bomb = alias_bomb(source.read_bytes(), key=key)
    assert b": *l9 " in bomb and len(bomb) - source.stat().st_size < 600
    target.write_bytes(bomb)
    for other in source.parent.glob("*.eds"):  # (what a network file names)
        (tmp_path / other.name).write_bytes(other.read_bytes())
    result = load_bounded(kind, target)
    assert result["error"] is not None
    assert "alias" in result["message"] and "100,000 values" in result["message"]
    assert len(result["message"]) < 2000


def test_a_self_referring_alias_is_refused() -> None:
    data, problems = read_yaml("a: &a [1, *a]\n")
    assert data is None
    assert problems[0].line == 1 and "refers to a value it is part of" in problems[0].reason


def test_anchors_and_merge_keys_within_the_budget_still_read() -> None:
    text = "defaults: &d {heartbeat_time: 100, sdo_timeout: 500}\na: {<<: *d, node_id: 5}\n"
    data, problems = read_yaml(text)
    assert problems == []
    assert data["a"] == {"heartbeat_time": 100, "sdo_timeout": 500, "node_id": 5}
    wide = (
        "x: &x ["
        + ", ".join(["1"] * 1000)
        + "]\n"
        + "".join(f"k{i}: *x\n" for i in range(MAX_ALIAS_VALUES // 1001 - 1))
    )
    assert read_yaml(wide)[1] == []  # (just under the budget)


def test_a_huge_value_is_clipped_in_every_message(tmp_path: Path) -> None:
    huge = "x" * 1_000_000
    (tmp_path / "net.yml").write_text(f"master: {{node_id: {huge}}}\nnodes: {{}}\n")
    result = load_bounded("network", tmp_path / "net.yml")
    assert result["error"] == "NetworkConfigError"
    assert "characters left out" in result["message"] and len(result["message"]) < 2000


def test_clip_keeps_both_ends_and_says_how_much_is_left_out() -> None:
    assert clip("short") == "short"
    text = clip("a" * 200 + "b" * 1000 + "c" * 100)
    assert text.startswith("a" * 200) and text.endswith("c" * 100)
    assert "(1,000 characters left out)" in text


# -- EDS: linear time, bounded widths -----------------------------------------------------------

OBJECT = "[{index:04X}]\nParameterName={name}\nObjectType=0x7\nDataType={type}\nAccessType=rw\n"
OBJECT += "DefaultValue={default}\nPDOMapping=0\n"


def eds_text(*objects: str) -> str:
    head = "[FileInfo]\nFileName=hostile.eds\n[DeviceInfo]\nVendorName=x\n[MandatoryObjects]\n"
    return head + "SupportedObjects=1\n1=0x1000\n" + "".join(objects)


def load_eds_bounded(text: str, tmp_path: Path, *, show: bool = False) -> dict[str, object]:
    path = tmp_path / "hostile.eds"
    path.write_text(text, encoding="latin-1")
    code = textwrap.dedent(
        f"""
        import json
        from cobus.od import load
        from cobus.od._cli import render_table
        od = load({str(path)!r})
        shown = render_table(od) if {show!r} else ""
        print(json.dumps({{"findings": [str(f) for f in od.findings][:3],
                           "count": len(od.findings), "shown": len(shown)}}))
        """
    )
    status, stdout, stderr = bounded_python(code, memory_mb=1500, seconds=30)
    assert status == 0, f"exit {status}: {stderr[-2000:]}"
    result: dict[str, object] = json.loads(stdout)
    return result


def test_an_eds_of_repeated_keys_is_read_in_linear_time(tmp_path: Path) -> None:
    """520 kB of one key repeated took 22 s (each repeat scanned the section for the line of
    the first); now each repeat is a finding that names that line."""
    device_type = OBJECT.format(index=0x1000, name="Device type", type="0x0007", default=0x191)
    result = load_eds_bounded(eds_text(device_type + "DefaultValue=1\n" * 37_000), tmp_path)
    assert result["count"] == 37_000
    first = str(result["findings"][0])  # type: ignore[index]
    assert "key DefaultValue appears twice in the section (first at line 13)" in first
    assert "hostile.eds:15:" in first


def test_an_eds_of_indented_section_headers_is_read_in_linear_time(tmp_path: Path) -> None:
    """Headers indented by a space (" [2000]") kept the whole file in one stretch and
    counted each header's offset from its start: 160 kB took 9.4 s, 650 kB minutes."""
    headers = "".join(f" [{n >> 8:04X}sub{n & 0xFF:X}]\n" for n in range(50_000))
    result = load_eds_bounded(eds_text(headers), tmp_path)
    assert int(str(result["count"])) >= 1  # (a sub-object without its object, without keys)


def test_eds_show_pads_no_row_to_a_huge_cell(tmp_path: Path) -> None:
    """A 700 kB default value used to pad every row of `cobus eds show` to its width."""
    objects = [
        OBJECT.format(index=0x1000, name="Device type", type="0x0007", default=0x191),
        OBJECT.format(index=0x2000, name="Huge", type="0x0009", default="x" * 700_000),
        *(
            OBJECT.format(index=0x2001 + n, name=f"n{n}", type="0x0007", default=n)
            for n in range(200)
        ),
    ]
    result = load_eds_bounded(eds_text(*objects), tmp_path, show=True)
    assert int(str(result["shown"])) < 700_000 + 200 * 200


# -- parameter files: bounded suggestions and reports -------------------------------------------


def test_a_parameter_file_of_5000_unknown_names_is_reported_briefly(tmp_path: Path) -> None:
    """Each unknown name cost a close-match search (5,000: 14 s) and the message listed all
    (949 kB): now the first 20 get suggestions, the message lists 50 and counts the rest."""
    eds = EXAMPLES / "networks/servo.eds"
    names = "".join(f"  profile velocityy {n}: 1\n" for n in range(5000))
    (tmp_path / "many.yml").write_text(f"eds: {eds}\nparameters:\n{names}")
    result = load_bounded("parameters", tmp_path / "many.yml")
    assert result["error"] == "ParameterFileError"
    message = result["message"]
    assert message.startswith("the parameter file has 5000 problem(s):")
    assert message.count("did you mean") == 20
    assert "no suggestions after the first ones" in message
    assert message.endswith("... and 4,950 more (fix these first)")
    assert len(message) < 20_000


# -- BLF: no container inflated past what cobus allows --------------------------------------------


def blf_bomb(path: Path, inflated: int, announced: int) -> None:
    """A BLF file of a few real frames, then a log container of ``inflated`` zero bytes
    (zlib: about a thousandth of that on disk) that announces ``announced`` bytes."""
    import zlib

    import can
    from can.io import blf

    with can.BLFWriter(str(path)) as writer:
        for n in range(5):
            writer.on_message_received(can.Message(arbitration_id=0x181, data=[n], timestamp=n))
    deflate = zlib.compressobj()
    chunk = bytes(16 * 1024 * 1024)
    parts = [deflate.compress(chunk) for _ in range(inflated // len(chunk))]
    parts.append(deflate.compress(bytes(inflated % len(chunk))))
    parts.append(deflate.flush())
    body = blf.LOG_CONTAINER_STRUCT.pack(blf.ZLIB_DEFLATE, announced) + b"".join(parts)
    size = blf.OBJ_HEADER_BASE_STRUCT.size + len(body)
    head = blf.OBJ_HEADER_BASE_STRUCT.pack(b"LOBJ", 16, 1, size, blf.LOG_CONTAINER)
    with path.open("ab") as f:
        f.write(head + body + bytes(size % 4))


def decode_bounded(path: Path) -> tuple[int, str, str]:
    code = f"from cobus.cli import main; raise SystemExit(main(['decode', {str(path)!r}]))"
    return bounded_python(code, memory_mb=700, seconds=60)


@pytest.mark.parametrize(
    ("announced", "said"),
    [
        (1 << 30, "announces 1,073,741,824 bytes uncompressed, more than the 16,777,216"),
        (128 * 1024, "inflates to more than the 131,072 bytes it announces (a zip bomb?)"),
    ],
)
def test_a_blf_zlib_bomb_is_refused_before_it_is_inflated(
    tmp_path: Path, announced: int, said: str
) -> None:
    """python-can's reader inflates a container whole: 1.57 MB took 1.6 GB."""
    path = tmp_path / "bomb.blf"
    blf_bomb(path, 1 << 30, announced)
    assert path.stat().st_size < 2_000_000
    status, _, stderr = decode_bounded(path)
    assert status == 1, stderr[-2000:]
    assert "bomb.blf: the log container at byte " in stderr
    assert said in stderr and "not read" in stderr
    assert len(stderr.strip().splitlines()) == 1


def test_a_gzipped_blf_bomb_is_refused_too(tmp_path: Path) -> None:
    import gzip

    from cobus.trace.files import TraceFileError, open_trace

    plain = tmp_path / "bomb.blf"
    blf_bomb(plain, 64 << 20, 128 * 1024)
    packed = tmp_path / "bomb.blf.gz"
    packed.write_bytes(gzip.compress(plain.read_bytes()))
    with pytest.raises(TraceFileError, match="inflates to more than the 131,072 bytes"):
        open_trace(packed)


def test_a_stored_container_is_not_held_to_its_announced_size(tmp_path: Path) -> None:
    """python-can ignores the size a stored (uncompressed) container announces: its bytes
    are in the file already, so the check does not refuse it for that."""
    from can.io import blf

    from cobus.trace.files import check_blf

    path = tmp_path / "stored.blf"
    blf_bomb(path, 0, 0)  # (a few real frames, then an empty deflated container)
    body = blf.LOG_CONTAINER_STRUCT.pack(blf.NO_COMPRESSION, 0xFFFFFFFF) + bytes(64)
    size = blf.OBJ_HEADER_BASE_STRUCT.size + len(body)
    head = blf.OBJ_HEADER_BASE_STRUCT.pack(b"LOBJ", 16, 1, size, blf.LOG_CONTAINER)
    with path.open("ab") as f:
        f.write(head + body)
    check_blf(path)


def test_a_real_blf_file_passes_the_check(tmp_path: Path) -> None:
    import can

    from cobus.trace.files import check_blf, open_trace

    path = tmp_path / "real.blf"
    with can.BLFWriter(str(path)) as writer:
        for n in range(20_000):  # (several containers of 128 KiB)
            msg = can.Message(arbitration_id=0x180 + n % 8, data=n.to_bytes(4, "little"))
            msg.timestamp = n / 1000
            writer.on_message_received(msg)
    check_blf(path)
    with open_trace(path) as reader:
        assert sum(1 for _ in reader) == 20_000
    import gzip

    packed = tmp_path / "real.blf.gz"
    packed.write_bytes(gzip.compress(path.read_bytes()))
    with open_trace(packed) as reader:
        assert sum(1 for _ in reader) == 20_000


# -- rig files: what would never fire, or fail when it fires, is refused at load -------------


RIG = """
bus: embedded
devices:
  - {{node: 5, kind: cia401_io}}
  - {{node: 6, kind: cia401_io}}
faults:
  - {fault}
"""


@pytest.mark.parametrize(
    ("fault", "said"),
    [
        ("{at: .nan, node: 5, fault: power_loss}", "at nan must be seconds after the start"),
        ("{at: .inf, node: 5, fault: power_loss}", "at inf must be seconds after the start"),
        (
            "{at: 1, node: 5, fault: node_id_change, node_id: 200}",
            "node_id_change: node_id 200 must be a node-ID 1..127",
        ),
        (
            "{at: 1, node: 5, fault: node_id_change, node_id: 6}",
            "node_id_change to node 6: that node-ID is taken by another device of this rig",
        ),
    ],
)
def test_a_rig_fault_that_could_never_fire_is_refused_at_load(fault: str, said: str) -> None:
    from cobus.sim import Rig
    from cobus.sim.rig import RigError

    with pytest.raises(RigError, match="faults\\[0\\]") as err:
        Rig.loads(RIG.format(fault=fault))
    assert said in str(err.value)


def test_a_node_id_change_to_a_node_freed_first_still_loads() -> None:
    from cobus.sim import Rig

    text = RIG.format(fault="{at: 1, node: 6, fault: node_id_change, node_id: 7}")
    text += "  - {at: 2, node: 5, fault: node_id_change, node_id: 6}\n"
    assert len(Rig.loads(text).fault_specs) == 2


# -- udp_multicast: this host only unless asked -------------------------------------------------


def test_the_reach_of_a_multicast_group() -> None:
    from cobus.runtime.bus import HOST_ONLY_GROUP, multicast_reach

    assert multicast_reach(HOST_ONLY_GROUP) is None
    assert multicast_reach("ff02::1") == "this link"
    assert multicast_reach("ff15:7079:7468:6f6e:6465:6d6f:6d63:6173") == (
        "beyond this link (scope 5)"
    )
    assert "IPv4" in str(multicast_reach("239.74.163.2"))


def test_udp_multicast_stays_on_this_host_unless_a_group_is_named(
    caplog: pytest.LogCaptureFixture,
) -> None:
    import logging

    need_module("msgpack", "python-can's udp_multicast needs msgpack")
    from cobus.runtime.bus import HOST_ONLY_GROUP, open_bus

    port = 43_000 + os.getpid() % 500
    with caplog.at_level(logging.WARNING, logger="cobus.runtime.bus"):
        try:
            bus = open_bus("udp_multicast", port=port)
        except Exception as exc:  # (no IPv6 multicast on this host)
            need(False, f"no multicast here: {exc}")
            return
        try:
            assert bus._multicast.group == HOST_ONLY_GROUP  # type: ignore[attr-defined]
        finally:
            bus.shutdown()
        assert not caplog.records
        wide = open_bus("udp_multicast", "ff15:7079:7468:6f6e:6465:6d6f:6d63:6173", port=port)
        wide.shutdown()
    (record,) = caplog.records
    assert "anyone who can send there writes to this bus" in record.getMessage()


def test_the_help_of_the_bus_options_says_who_can_write(
    capsys: pytest.CaptureFixture[str],
) -> None:
    from cobus.cli import main

    with pytest.raises(SystemExit):
        main(["monitor", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "python-can listens on every interface" in text


# -- outputs: never overwritten unasked, never written through a link -----------------------------


SERVO_EDS = EXAMPLES / "networks/servo.eds"


def _cli(capsys: pytest.CaptureFixture[str], *words: str) -> tuple[int, str]:
    from cobus.cli import main

    code = main(list(words))
    return code, capsys.readouterr().err


def test_eds_convert_overwrites_only_with_force_and_never_through_a_link(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out" / "servo.eds"
    out.parent.mkdir()
    outside = tmp_path / "precious.txt"
    outside.write_text("not yours")
    out.symlink_to(outside)
    code, err = _cli(capsys, "eds", "convert", str(SERVO_EDS), str(out))
    assert code == 2 and "is a symbolic link: pass --force" in err
    assert outside.read_text() == "not yours"
    assert _cli(capsys, "eds", "convert", str(SERVO_EDS), str(out), "--force")[0] == 0
    assert outside.read_text() == "not yours"  # the link was replaced, not followed
    assert not out.is_symlink() and out.read_bytes().startswith(b"[FileInfo]\r\n")
    code, err = _cli(capsys, "eds", "convert", str(SERVO_EDS), str(out))
    assert (
        code == 2
        and err.strip() == f"cobus eds convert: {out} exists: pass --force to overwrite it"
    )
    assert not list(out.parent.glob(".*partial"))  # (no leftovers)


def test_config_dcf_writes_nothing_over_files_or_through_links_unasked(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    network_file = EXAMPLES / "networks/thesis.yml"
    outdir = tmp_path / "dcf"
    assert _cli(capsys, "config", "dcf", str(network_file), str(outdir))[0] == 0
    written = sorted(p.name for p in outdir.iterdir())
    assert "servo.dcf" in written and "servo.bin" in written
    outside = tmp_path / "precious.txt"
    outside.write_text("not yours")
    (outdir / "servo.dcf").unlink()
    (outdir / "servo.dcf").symlink_to(outside)
    code, err = _cli(capsys, "config", "dcf", str(network_file), str(outdir))
    assert code == 2 and "nothing written" in err
    assert "servo.dcf is a symbolic link" in err and "servo.bin exists" in err
    assert _cli(capsys, "config", "dcf", str(network_file), str(outdir), "--force")[0] == 0
    assert outside.read_text() == "not yours" and not (outdir / "servo.dcf").is_symlink()


def test_record_overwrites_only_with_force(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    trace = tmp_path / "bus.log"
    trace.write_text("earlier recording\n")
    code, err = _cli(capsys, "record", str(trace), "--duration", "0.1", "-i", "virtual")
    assert code == 2 and "exists: pass --force" in err
    assert trace.read_text() == "earlier recording\n"
    outside = tmp_path / "precious.txt"
    outside.write_text("not yours")
    link = tmp_path / "link.log"
    link.symlink_to(outside)
    args = ("record", str(link), "--duration", "0.1", "-i", "virtual", "-c", f"rec{os.getpid()}")
    assert _cli(capsys, *args)[0] == 2
    assert _cli(capsys, *args, "--force")[0] == 0
    assert outside.read_text() == "not yours" and not link.is_symlink()


def test_config_check_shows_no_line_of_a_file_that_is_no_eds(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    secret = tmp_path / "secret.txt"
    secret.write_text("root:x:0:0:root:/root:/bin/bash\nsecret=hunter2\n[x]\npassword=abc\n")
    (tmp_path / "net.yml").write_text("nodes:\n  a: {node_id: 5, eds: secret.txt}\n")
    from cobus.cli import main

    assert main(["config", "check", str(tmp_path / "net.yml")]) == 2
    shown = capsys.readouterr()
    text = shown.out + shown.err
    assert "secret.txt is not an EDS or DCF: it defines no objects" in text
    for word in ("root:x", "hunter2", "password", "abc"):
        assert word not in text


def test_replacing_a_file_keeps_its_mode_and_never_writes_a_device(tmp_path: Path) -> None:
    from cobus._files import refusal, replace_file

    target = tmp_path / "private.dcf"
    target.write_text("old")
    target.chmod(0o600)
    replace_file(target, b"new")
    assert target.read_bytes() == b"new" and (target.stat().st_mode & 0o777) == 0o600
    fresh = tmp_path / "fresh.dcf"
    replace_file(fresh, b"x")
    assert fresh.stat().st_mode & 0o777 == 0o666 & ~_umask_now()
    assert "no regular file" in str(refusal("/dev/null", True))
    assert "is a folder" in str(refusal(tmp_path, True))


def _umask_now() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def test_a_group_from_python_cans_configuration_is_kept(monkeypatch: pytest.MonkeyPatch) -> None:
    from cobus.runtime.bus import _udp_multicast_without_group

    monkeypatch.setenv("CAN_INTERFACE", "udp_multicast")
    monkeypatch.setenv("CAN_CHANNEL", "239.74.163.2")
    assert not _udp_multicast_without_group({})  # the user's group, from the environment
    monkeypatch.delenv("CAN_CHANNEL")
    assert _udp_multicast_without_group({})  # none named: cobus's host-only group
    assert not _udp_multicast_without_group({"channel": "ff12::1"})
    assert not _udp_multicast_without_group({"interface": "virtual"})


def test_a_unicast_datagram_to_the_port_is_no_frame_on_the_bus() -> None:
    """python-can's udp_multicast socket listens on every interface at its port: a datagram
    sent to the host's address was a frame on the bus. cobus's filter (Linux) takes only
    what was sent to the group - and what other members send there still arrives."""
    import random
    import socket
    import sys

    import can

    need_module("msgpack", "python-can's udp_multicast needs msgpack")
    from can.interfaces.udp_multicast.utils import pack_message

    from cobus.proto import Frame
    from cobus.runtime import Network

    if not sys.platform.startswith("linux"):
        pytest.skip("the kernel filter is Linux's")
    port = random.randrange(20000, 40000)
    try:
        net = Network(interface="udp_multicast", port=port)
    except Exception as exc:  # (no IPv6 multicast on this host)
        need(False, f"no multicast here: {exc}")
        return
    with net, Network(interface="udp_multicast", port=port) as other:
        assert net.aio._tx is not None  # the filter is on (the host-only group too)
        got: list[Frame] = []
        net.subscribe(0x123, lambda f, now: got.append(f))
        other.subscribe(0x123, lambda f, now: got.append(f))
        # (both sockets share the port: the kernel hands a unicast datagram to either)
        sockets = [n.aio._bus._multicast._socket for n in (net, other)]  # type: ignore[union-attr]
        dropped = sum(map(_drops, sockets))
        intruder = socket.socket(socket.AF_INET6, socket.SOCK_DGRAM)
        forged = can.Message(arbitration_id=0x123, data=b"\x66", is_extended_id=False)
        intruder.sendto(pack_message(forged), ("::1", port))
        intruder.close()
        until(lambda: sum(map(_drops, sockets)) > dropped)  # the kernel's filter took it
        other.send(Frame(0x123, b"\x01"))  # what a member sends still arrives
        until(lambda: len(got) == 2)  # (net hears it; other too, by its local echo)
        assert got == [Frame(0x123, b"\x01")] * 2


def _drops(sock: Any) -> int:
    """The datagrams the kernel dropped for ``sock`` (its filter's too): /proc/net/udp6."""
    inode = os.fstat(sock.fileno()).st_ino
    with open("/proc/net/udp6", encoding="ascii") as f:
        for line in f:
            fields = line.split()
            if len(fields) > 12 and fields[9] == str(inode):
                return int(fields[-1])
    return 0


def test_a_data_file_of_100_mb_is_refused_before_it_is_parsed(tmp_path: Path) -> None:
    """make fuzz: a 100 MB mutated parameter file took 26 s in PyYAML's parser."""
    from cobus._yaml import MAX_TEXT

    text = "parameters:\n" + "  x: 1\n" * (MAX_TEXT // 7 + 1)
    data, problems = read_yaml(text)
    assert data is None and "more than the 16,777,216 a cobus data file may hold" in str(
        problems[0].reason
    )
