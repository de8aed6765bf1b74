"""``cobus netvars watch / send / gvl`` (issue 46): lists over UDP from the command line."""

from __future__ import annotations

import json
import socket
import threading
from pathlib import Path

import pytest

from cobus.blocks.gvl import load_gvl
from cobus.blocks.netvar_lists import load_netvars
from cobus.cli import main

from .test_netvar_udp_codec import CODESYS_EXPORT

NETVARS = """
controllers: [plc1, plc2]
lists:
  line_status:
    id: 0x300
    sender: plc1
    transmit: cyclic
    interval: 100 ms
    variables:
      speed: REAL32
      running: BOOLEAN
      temps: {array: INTEGER16, length: 4}
      motor: {struct: {current: REAL32, voltage: UNSIGNED16}}
      label: {string: 8}
  alarms:
    id: 0x310
    sender: plc2
    transmit: on_change
    min_gap: 20 ms
    variables: {code: UNSIGNED16, active: BOOLEAN}
"""


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_gvl_writes_cobus_lists_codesys_imports(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    yml = tmp_path / "netvars.yml"
    yml.write_text(NETVARS)
    assert main(["netvars", "gvl", str(yml), str(tmp_path / "out")]) == 0
    written = capsys.readouterr().out.split()
    assert sorted(Path(p).name for p in written) == ["alarms.gvl", "line_status.gvl"]
    ours = load_netvars(yml)
    for name in ("line_status", "alarms"):
        back = load_gvl(tmp_path / "out" / f"{name}.gvl")
        assert back.list_id == ours[name].cob_id and back.size == ours[name].size
    status = load_gvl(tmp_path / "out/line_status.gvl")
    assert [v.type.name for v in status.variables][-1] == "STRING(7)"
    assert status.interval == 0.1 and status.modes == {"cyclic"}
    assert "temps : ARRAY[0..3] OF INT;" in (tmp_path / "out/line_status.gvl").read_text()
    # one list: to the file named
    one = tmp_path / "alarms.gvl"
    assert main(["netvars", "gvl", str(yml), str(one), "--list", "alarms", "--port", "1300"]) == 0
    assert load_gvl(one).port == 1300 and load_gvl(one).modes == {"on_change"}
    capsys.readouterr()
    # a type IEC 61131-3 has not: refused, one line, exit code 2
    odd = tmp_path / "odd.yml"
    odd.write_text(NETVARS.replace("code: UNSIGNED16", "code: INTEGER24"))
    assert main(["netvars", "gvl", str(odd), str(tmp_path / "odd")]) == 2
    err = capsys.readouterr().err
    assert "code is INTEGER24, which has no IEC 61131-3 type" in err and err.count("\n") == 1
    assert main(["netvars", "gvl", str(yml), str(tmp_path / "x"), "--list", "nope"]) == 2
    assert "no variable list 'nope'" in capsys.readouterr().err


def test_watch_prints_what_send_sent(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    gvl = tmp_path / "plant.gvl"
    gvl.write_text(CODESYS_EXPORT)
    port = _free_port()
    codes: list[int] = []
    watch = threading.Thread(
        target=lambda: codes.append(
            main(
                [
                    "netvars",
                    "watch",
                    str(gvl),
                    "--udp",
                    "--port",
                    str(port),
                    "--json",
                    "--count",
                    "1",
                    "--seconds",
                    "20",
                ]
            )
        )
    )
    watch.start()
    sent = [
        "netvars",
        "send",
        str(gvl),
        "--udp",
        "--to",
        f"127.0.0.1:{port}",
        "sinus=0.5",
        "integer=-12",
        "my_time=T#1s500ms",
        "some_word=16#FF",
        "my_string20=line 2",
        "my_array[4]=7",
    ]
    for _ in range(200):  # (until the watch listens: a datagram before it is lost)
        assert main(sent) == 0
        watch.join(0.05)
        if not watch.is_alive():
            break
    assert codes == [0]
    out = capsys.readouterr()
    (line,) = [json.loads(t) for t in out.out.splitlines() if t.startswith("{")]
    assert line["list"] == "plant"
    assert f"plant: sent to 127.0.0.1:{port} (1 telegram(s))" in out.out
    values = line["values"]
    assert values["sinus"] == 0.5 and values["integer"] == -12 and values["my_time"] == 1500
    assert values["some_word"] == 255 and values["my_string20"] == "line 2"
    assert values["my_array[4]"] == 7 and values["cosine"] == 0.0
    assert "# not given, sent as 0 or empty: cosine, my_date, my_array[0]" in out.err
    assert "1 list(s) received (plant 1)" in out.err


def test_what_send_and_watch_refuse(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    gvl = tmp_path / "plant.gvl"
    gvl.write_text(CODESYS_EXPORT)
    base = ["netvars", "send", str(gvl), "--udp", "--to", "127.0.0.1:9"]
    for extra, why in (
        (["integer=abc"], "integer: INT takes a whole number, not 'abc'"),
        (["integer=70000"], "integer: 70000 is out of the range of INT: -32768..32767"),
        (["nothing=1"], "list 'plant' has no variable 'nothing'"),
        (["sinus"], "'sinus': give NAME=VALUE"),
        (["my_string20=" + "x" * 21], "holds 20 characters"),
    ):
        assert main([*base, *extra]) == 2
        err = capsys.readouterr().err
        assert why in err and err.count("\n") == 1, err
    # the file's address is a broadcast one: refused unless --broadcast
    wide = tmp_path / "wide.gvl"
    wide.write_text(CODESYS_EXPORT.replace("192.168.56.1", "255.255.255.255"))
    assert main(["netvars", "send", str(wide), "--udp", "sinus=1"]) == 1
    assert "broadcast=True (cobus netvars --broadcast)" in capsys.readouterr().err
    # a name that is nobody's: looked up once when the socket opens, said when sent
    assert main(["netvars", "send", str(gvl), "--to", "nosuch.invalid:1202", "sinus=1"]) == 1
    assert "cannot send to nosuch.invalid: no such host" in capsys.readouterr().err
    # a file cobus cannot use
    bad = tmp_path / "bad.gvl"
    bad.write_text(CODESYS_EXPORT.replace("<Checksum>False", "<Checksum>True"))
    assert main(["netvars", "watch", str(bad), "--udp", "--seconds", "0.1"]) == 2
    assert "Checksum is on" in capsys.readouterr().err
    # a port already taken
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as taken:
        taken.bind(("127.0.0.1", 0))
        port = str(taken.getsockname()[1])
        assert main(["netvars", "watch", str(gvl), "--udp", "--port", port, "--seconds", "1"]) == 1
    assert f"cannot listen on 127.0.0.1:{port}" in capsys.readouterr().err
    # nothing came: says so, exit 0
    assert main(["netvars", "watch", str(gvl), "--udp", "--port", "0", "--seconds", "0.05"]) == 0
    assert "# 0 list(s) received (plant 0)" in capsys.readouterr().err


def test_what_the_review_of_the_cli_found(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import subprocess
    import sys

    gvl = tmp_path / "plant.gvl"
    gvl.write_text(CODESYS_EXPORT)
    # two files of one list identifier: one line, exit code 2
    twin = tmp_path / "twin.gvl"
    twin.write_text(CODESYS_EXPORT)
    assert main(["netvars", "watch", str(gvl), str(twin), "--udp", "--seconds", "0.1"]) == 2
    err = capsys.readouterr().err
    assert "lists plant and twin have one identifier, 1" in err and err.count("\n") == 1
    assert main(["netvars", "watch", str(gvl), "--seconds", "-1"]) == 2
    assert "--seconds: a time above 0" in capsys.readouterr().err
    # gvl: a folder named with a slash, --json
    yml = tmp_path / "netvars.yml"
    yml.write_text(NETVARS)
    folder = str(tmp_path / "new") + "/"
    assert main(["netvars", "gvl", str(yml), folder, "--list", "alarms", "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == {"alarms": str(tmp_path / "new/alarms.gvl")}
    # SIGTERM: what it received, exit 143; a closed pipe: quiet, exit 0
    port = _free_port()
    command = [sys.executable, "-m", "cobus", "netvars", "watch", str(gvl), "--port", str(port)]
    proc = subprocess.Popen(command, stderr=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stderr is not None
        assert proc.stderr.readline().startswith("# listening on 127.0.0.1:")
        proc.terminate()
        _, err = proc.communicate(timeout=20)
    finally:
        proc.kill()
    assert proc.returncode == 143
    assert "cobus netvars watch: terminated: 0 list(s) received (plant 0)" in err
    proc2 = subprocess.Popen([*command, "--json"], stderr=subprocess.PIPE, stdout=subprocess.PIPE)
    try:
        assert proc2.stderr is not None and proc2.stdout is not None
        proc2.stderr.readline()
        send = ["netvars", "send", str(gvl), "--to", f"127.0.0.1:{port}", "integer=1"]
        assert main(send) == 0
        assert json.loads(proc2.stdout.readline())["values"]["integer"] == 1
        proc2.stdout.close()  # (as `| head -1` does)
        for _ in range(3):
            assert main(send) == 0
        proc2.wait(timeout=20)
        err_bytes = proc2.stderr.read()
    finally:
        proc2.kill()
    assert proc2.returncode == 0 and b"Traceback" not in err_bytes
