"""The example scripts run, against the simulated thesis bench on the simulated clock, and print
what their docstrings promise."""

from __future__ import annotations

import contextlib
import importlib
import io
import sys
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType

import pytest

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


@pytest.fixture
def example(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> Iterator[object]:
    monkeypatch.syspath_prepend(str(EXAMPLES))
    monkeypatch.chdir(tmp_path)

    def run(name: str, *argv: str) -> str:
        module: ModuleType = importlib.import_module(name)
        out = io.StringIO()
        with contextlib.redirect_stdout(out):
            assert module.main(list(argv)) == 0
        return out.getvalue()

    yield run
    for name in ("_bench", "read_drive", "be_a_device", "boot_network", "drive_a_motor"):
        sys.modules.pop(name, None)


def test_read_drive(example) -> None:
    out = example("read_drive", "--simulated", "--duration", "1", "--sync", "10")
    assert "node 10: device type 0x00020192" in out
    assert "<TPDO 2 of node 10 0x28A: Statusword, Position actual value>" in out
    assert "TPDO 2: 100 frames; last: Statusword = 576, Position actual value = 0" in out
    assert "node 10 is OPERATIONAL; 0 emergencies" in out


def test_be_a_device(example, tmp_path: Path) -> None:
    out = example("be_a_device", "--simulated", "--duration", "2")
    assert "set-point written: 300" in out
    pressure = int(out.split("the master reads pressure ")[1].split()[0])
    assert 280 <= pressure <= 320


def test_boot_network(example) -> None:
    out = example("boot_network", "--simulated", "--duration", "1")
    assert "the network runs: master RUNNING" in out
    assert "node 10 servo: operational, NMT OPERATIONAL, 0 emergencies" in out
    assert "%" in out and "bus load" in out


def test_boot_network_names_a_broken_file(example, tmp_path: Path, capsys) -> None:
    broken = tmp_path / "broken.yml"
    broken.write_text("nodes:\n  a: {node_id: 300}\n")
    module = importlib.import_module("boot_network")
    assert module.main([str(broken), "--simulated"]) == 2
    assert "broken.yml" in capsys.readouterr().err


def test_drive_a_motor(example) -> None:
    out = example("drive_a_motor", "--simulated", "--home", "35")
    assert "node 10: 0x0240 SWITCH_ON_DISABLED" in out
    assert "homed (method 35)" in out
    lines = [line for line in out.splitlines() if "(asked " in line]
    assert len(lines) == 3
    # 50 000, then 100 000, then 50 000 increments at 100 000 inc/s and 500 000 inc/s²:
    # trapezoids of 0.7, 1.2 and 0.7 s
    for line, asked, took in zip(lines, (50_000, -50_000, 0), (0.7, 1.2, 0.7), strict=True):
        assert abs(float(line.split()[1]) - asked) <= 20, line
        assert float(line.split("after ")[1].split()[0]) == pytest.approx(took, abs=0.02)
    assert "switched off: 0x0240 SWITCH_ON_DISABLED" in out
