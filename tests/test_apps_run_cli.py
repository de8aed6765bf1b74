"""``cobus run NETWORK.yml [--panel]``: the master on a bus, the panel beside it."""

from __future__ import annotations

import argparse
import asyncio
import os
import socket
import threading
import time
import urllib.request
from pathlib import Path
from typing import Any

import pytest

from cobus.apps._run_cli import listen_address
from cobus.cli import main
from cobus.device import export_eds
from cobus.runtime import Network
from cobus.sim import Rig, start_rig

RIG = """
bus: embedded
devices:
  - {node: 10, kind: cia402_drive, name: servo}
"""

NETWORK = """
master: {node_id: 127, heartbeat_time: 100}
nodes:
  servo: {node_id: 10, eds: servo.eds, mandatory: true, heartbeat_time: 100}
"""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.mark.parametrize(
    ("text", "address"),
    [
        ("127.0.0.1:8047", ("127.0.0.1", 8047)),
        (":9000", ("127.0.0.1", 9000)),
        ("9000", ("127.0.0.1", 9000)),
        ("0.0.0.0:0", ("0.0.0.0", 0)),
        ("[::1]:8047", ("::1", 8047)),
        ("localhost", ("localhost", 8047)),
    ],
)
def test_listen_addresses(text: str, address: tuple[str, int]) -> None:
    assert listen_address(text) == address


@pytest.mark.parametrize("text", ["127.0.0.1:99999", "host:port", "[::1"])
def test_bad_listen_addresses_say_what_to_give(text: str) -> None:
    with pytest.raises(argparse.ArgumentTypeError, match=r"HOST:PORT|0-65535"):
        listen_address(text)


def test_the_master_runs_the_network_with_its_panel(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    channel = f"cli-run-{os.getpid()}"
    port = free_port()
    fetched: dict[str, object] = {}

    async def snapshot() -> dict[str, Any]:
        import aiohttp

        async with (
            aiohttp.ClientSession() as http,
            http.ws_connect(f"http://127.0.0.1:{port}/ws") as ws,
        ):
            message: Any = await ws.receive_json(timeout=5)  # (alone or first of several)
            first: dict[str, Any] = message[0] if isinstance(message, list) else message
            return first

    def fetch() -> None:
        for _ in range(400):
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=2) as r:
                    fetched["status"] = r.status
                    fetched["csp"] = r.headers["Content-Security-Policy"]
                fetched["snapshot"] = asyncio.run(snapshot())
                return
            except OSError:
                time.sleep(0.01)

    with Network(interface="virtual", channel=channel) as net:
        rig = start_rig(net, Rig.loads(RIG))
        (tmp_path / "servo.eds").write_text(export_eds(rig.aio.devices[10].od))
        (tmp_path / "line.yml").write_text(NETWORK)
        (tmp_path / "servo.yml").write_text('parameters:\n  "0x6083:00": 1234\n')
        reader = threading.Thread(target=fetch)
        reader.start()
        code = main(
            [
                "run",
                str(tmp_path / "line.yml"),
                "--panel",
                "--listen",
                f"127.0.0.1:{port}",
                "--duration",
                "1.5",
                "--history",
                str(tmp_path / "alarms.sqlite"),
                "--parameters",
                f"servo={tmp_path / 'servo.yml'}",
                "-i",
                "virtual",
                "-c",
                channel,
            ]
        )
        reader.join()
        assert str(rig.aio.devices[10].status()["nmt"]).upper() == "OPERATIONAL"
    out, err = capsys.readouterr()
    assert code == 0, err
    assert f"the panel is at http://127.0.0.1:{port}/\n" in out
    assert "node 10: configured -> operational" in err
    assert "re-parameterised, 1 of 1 written, saved and verified" in err
    assert fetched["status"] == 200 and "default-src 'self'" in str(fetched["csp"])
    assert (tmp_path / "alarms.sqlite").stat().st_size > 0
    info = fetched["snapshot"]["info"]  # type: ignore[index]
    assert info["drives"] == [
        {"name": "servo", "kind": "cia402", "node": 10, "unit": "inc/s", "on_demand": False}
    ]
    assert info["alarms"]["history"] is True
    assert info["parameters"]["nodes"][0]["set"] == "servo.yml"


def test_bad_usage_and_files_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["run", str(tmp_path / "missing.yml")]) == 2
    assert "cannot read" in capsys.readouterr().err
    (tmp_path / "bad.yml").write_text("nodes: [1, 2]\n")
    assert main(["run", str(tmp_path / "bad.yml")]) == 2
    assert "bad.yml" in capsys.readouterr().err
    (tmp_path / "ok.yml").write_text("nodes: {}\n")
    assert main(["run", str(tmp_path / "ok.yml"), "--unix", "/tmp/x.sock"]) == 2
    assert "add --panel" in capsys.readouterr().err
    assert main(["run", str(tmp_path / "ok.yml"), "--open-reads"]) == 2
    assert "add --panel" in capsys.readouterr().err


def write_network(folder: Path) -> None:
    """line.yml and the simulated servo's EDS beside it, in ``folder``."""
    with Network(interface="virtual", channel=f"cli-run-eds-{os.getpid()}") as net:
        rig = start_rig(net, Rig.loads(RIG))
        (folder / "servo.eds").write_text(export_eds(rig.aio.devices[10].od))
    (folder / "line.yml").write_text(NETWORK)


def test_bad_parameter_files_exit_2_before_the_bus_is_opened(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    write_network(tmp_path)
    (tmp_path / "good.yml").write_text('parameters:\n  "0x6083:00": 1234\n')
    (tmp_path / "command.yml").write_text('parameters:\n  "0x6040:00": 15\n')
    (tmp_path / "unknown.yml").write_text("parameters:\n  no_such_object: 1\n")
    (tmp_path / "save.yml").write_text(
        'save: {index: 0x60FF, subindex: 0, signature: 123456}\nparameters:\n  "0x6083:00": 1\n'
    )
    line = str(tmp_path / "line.yml")
    for given, text in (
        ("servo", "give NODE=FILE"),
        ("=good.yml", "give NODE=FILE"),
        (f"pump={tmp_path / 'good.yml'}", "no node 'pump' in the network (servo (10))"),
        (f"servo={tmp_path / 'missing.yml'}", "missing.yml"),
        (f"10={tmp_path / 'command.yml'}", "configuration only"),
        (f"servo={tmp_path / 'unknown.yml'}", "no_such_object"),
        (f"servo={tmp_path / 'save.yml'}", "its save command writes 0x60FF"),
    ):
        code = main(["run", line, "--parameters", given, "-i", "virtual", "-c", "nowhere"])
        err = capsys.readouterr().err
        assert code == 2 and text in err, (given, err)
        assert err.startswith("cobus run: ") and "Traceback" not in err, err
    good = f"servo={tmp_path / 'good.yml'}"
    code = main(["run", line, "--parameters", good, "--parameters", "10=x.yml"])
    assert code == 2 and "servo is given twice" in capsys.readouterr().err


def test_a_zapi_page_needs_the_panel_and_a_zapi(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    write_network(tmp_path)
    line = str(tmp_path / "line.yml")
    assert main(["run", line, "--zapi", "servo"]) == 2
    assert "add --panel" in capsys.readouterr().err
    bus = ["-i", "virtual", "-c", "cli-run-zapi", "--listen", "127.0.0.1:0", "-q"]
    for key, text in (
        ("pump", "--zapi pump: no node 'pump' in this network; the nodes are: servo (10)"),
        ("10", "--zapi 10: servo does not look like a ZAPI inverter in the network file: "),
    ):
        assert main(["run", line, "--panel", "--zapi", key, *bus]) == 2
        err = capsys.readouterr().err
        assert text in err and "Traceback" not in err, err
    assert main(["run", line, "--panel", "--zapi", "10", "--zapi", "servo", *bus]) == 2
    assert "--zapi: servo is given twice" in capsys.readouterr().err
    assert main(["run", line, "--listen", "127.0.0.1:0"]) == 2  # (without --panel)
    assert "add --panel" in capsys.readouterr().err


def test_a_panel_address_in_use_exits_3(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with Network(interface="virtual", channel=f"cli-run-eds-{os.getpid()}") as net:
        servo = start_rig(net, Rig.loads(RIG)).aio.devices[10]
        (tmp_path / "servo.eds").write_text(export_eds(servo.od))
    (tmp_path / "ok.yml").write_text(NETWORK)
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        code = main(
            [
                *("run", str(tmp_path / "ok.yml"), "--panel", "--listen", f"127.0.0.1:{port}"),
                *("-i", "virtual", "-c", f"cli-run-taken-{os.getpid()}", "--duration", "1"),
            ]
        )
    assert code == 3
    assert "cannot serve the panel on 127.0.0.1:" in capsys.readouterr().err


def test_sigterm_stops_the_run_in_order_and_says_so(tmp_path: Path) -> None:
    import signal
    import subprocess
    import sys

    with Network(interface="virtual", channel=f"cli-run-term-{os.getpid()}") as net:
        servo = start_rig(net, Rig.loads(RIG)).aio.devices[10]
        (tmp_path / "servo.eds").write_text(export_eds(servo.od))
    (tmp_path / "line.yml").write_text(NETWORK)
    sock = str(tmp_path / "panel.sock")
    command = [sys.executable, "-m", "cobus", "run", str(tmp_path / "line.yml"), "--panel"]
    command += ["--listen", "127.0.0.1:0", "--unix", sock, "-i", "virtual", "-c", "term"]
    with subprocess.Popen(
        command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    ) as child:
        try:
            assert child.stdout is not None
            line = child.stdout.readline()
            assert "the panel is at http://127.0.0.1:" in line, line
            child.send_signal(signal.SIGTERM)
            _out, err = child.communicate(timeout=20)
        finally:
            child.kill()
    assert child.returncode == 0, err
    assert "stopped by SIGTERM" in err
    assert "the panel closed" in err and "supervision ended" in err
    assert not Path(sock).exists()  # its socket file went with it


def test_the_gateway_beside_the_master(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``--gateway``: a client reads the master's node by its EDS names while the master
    boots and supervises it; an address in use exits 3."""
    from cobus.apps.gateway import GatewayClient

    channel = f"cli-run-gw-{os.getpid()}"
    port = free_port()
    replies: list[str | None] = []

    def ask() -> None:
        for _ in range(400):
            try:
                with GatewayClient("127.0.0.1", port, timeout=5) as client:
                    replies.append(client.request('10 r "Identity object.Vendor-ID" x32').value)
                    replies.append(client.request("10 r 0x1000 0").value)  # (u32, its EDS)
                return
            except OSError:
                time.sleep(0.01)

    with Network(interface="virtual", channel=channel) as net:
        rig = start_rig(net, Rig.loads(RIG))
        (tmp_path / "servo.eds").write_text(export_eds(rig.aio.devices[10].od))
        (tmp_path / "line.yml").write_text(NETWORK)
        client = threading.Thread(target=ask)
        client.start()
        bus = ["-i", "virtual", "-c", channel]
        line = str(tmp_path / "line.yml")
        code = main(["run", line, "--gateway", f"127.0.0.1:{port}", "--duration", "1.5", *bus])
        client.join()
        out, err = capsys.readouterr()
        assert code == 0, err
        assert f"the gateway serves net 1 on 127.0.0.1:{port}\n" in out
        assert "node 10: configured -> operational" in err
        assert replies[0] == "0x00C0B005"
        assert replies[1] is not None and int(replies[1]) & 0xFFFF == 0x0192  # (not bytes)
        with socket.socket() as taken:
            taken.bind(("127.0.0.1", 0))
            taken.listen()
            busy = taken.getsockname()[1]
            code = main(["run", line, "--gateway", f"127.0.0.1:{busy}", "--duration", "1", *bus])
        assert code == 3 and "the gateway cannot listen" in capsys.readouterr().err


def test_a_bad_gateway_token_in_the_environment_exits_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    channel = f"cli-run-gwtok-{os.getpid()}"
    with Network(interface="virtual", channel=channel) as net:
        rig = start_rig(net, Rig.loads(RIG))
        (tmp_path / "servo.eds").write_text(export_eds(rig.aio.devices[10].od))
        (tmp_path / "line.yml").write_text(NETWORK)
        monkeypatch.setenv("COBUS_GATEWAY_TOKEN", "has space in it")
        bus = ["-i", "virtual", "-c", channel]
        code = main(["run", str(tmp_path / "line.yml"), "--gateway", "0.0.0.0:0", *bus])
    assert code == 2 and "COBUS_GATEWAY_TOKEN: give 8 characters" in capsys.readouterr().err
