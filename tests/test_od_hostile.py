"""EDS files from the internet must never take the machine down: hostile numbers (literals
thousands of digits long, counts of 10^20) give findings or an EdsError, never a crash, and
never make the loader allocate by a count read from the file.

Each case runs in a child process capped at 1 GB of address space and 60 s, so that a
regression shows as a failed test instead of a machine out of memory."""

from __future__ import annotations

import json
import resource
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

SERVO = Path(__file__).resolve().parent.parent / "examples" / "networks" / "servo.eds"
HUGE = "9" * 5000  # past Python's 4300-digit limit for int() of a decimal string
LONG = "0x" + "F" * 4000  # a hex literal Python parses, but cannot print in decimal

#: (name, what is done to the file's text)
CASES: dict[str, tuple[str, str]] = {
    "default value 5000 digits": ("DefaultValue=0x20192", f"DefaultValue={HUGE}"),
    "default value 4000 digits": ("DefaultValue=0x20192", f"DefaultValue={LONG}"),
    "sub number 4000 digits": ("SubNumber=0x5", f"SubNumber={LONG}"),
    "low limit 4000 digits": ("LowLimit=-128", f"LowLimit={LONG}"),
    "supported objects 4000 digits": ("SupportedObjects=3", f"SupportedObjects={LONG}"),
    "data type 4000 digits": ("DataType=0x0007", f"DataType={LONG}"),
    "comment lines 10^20": ("[DeviceInfo]", "[Comments]\nLines=99999999999999999999\n[DeviceInfo]"),
    "comment line key 10^20": (
        "[DeviceInfo]",
        "[Comments]\nLine99999999999999999999=x\n[DeviceInfo]",
    ),
    "baud rate key 5000 digits": ("[DeviceInfo]", f"[DeviceInfo]\nBaudRate_{HUGE}=1"),
}

CHILD = textwrap.dedent(
    """
    import json, sys
    from cobus.od import loads, EdsError
    from cobus.errors import CobusError
    text = sys.stdin.read()
    out = {}
    for strict in (False, True):
        try:
            od = loads(text, strict=strict)
            od.to_eds()
            out[str(strict)] = "loaded, %d findings" % len(od.findings)
        except (EdsError, CobusError) as exc:
            out[str(strict)] = "typed: " + str(exc)[:200]
        except BaseException as exc:
            out[str(strict)] = "UNTYPED %s: %s" % (type(exc).__name__, str(exc)[:200])
    print(json.dumps(out))
    """
)


def _limits() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (1 << 30, 1 << 30))


@pytest.mark.parametrize("case", list(CASES))
def test_a_hostile_number_is_a_finding_or_an_eds_error(case: str) -> None:
    old, new = CASES[case]
    text = SERVO.read_text()
    assert old in text
    hostile = text.replace(old, new, 1)
    done = subprocess.run(
        [sys.executable, "-c", CHILD],
        input=hostile,
        capture_output=True,
        text=True,
        timeout=60,
        preexec_fn=_limits,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    results = json.loads(done.stdout)
    for mode, result in results.items():
        assert not result.startswith("UNTYPED"), (mode, result)
    if "digits" in case and "key" not in case:  # the literal is named, with the limit
        assert "characters long" in json.dumps(results) or "loaded" in results["False"]


def test_an_empty_file_is_not_an_eds(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from cobus.cli import main
    from cobus.od import EdsError, loads

    empty = tmp_path / "empty.eds"
    empty.write_text("")
    assert main(["eds", "check", str(empty)]) == 2
    assert "defines no objects: it is not an EDS or DCF" in capsys.readouterr().out
    with pytest.raises(EdsError, match="defines no objects"):
        loads("", strict=True)


@pytest.mark.parametrize(
    "argv", [["sim", "thesis", "--duration", "nan"], ["demo", "--duration", "-1"]]
)
def test_durations_must_be_finite_and_positive(
    argv: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    from cobus.cli import main

    with pytest.raises(SystemExit) as done:
        main(argv)
    assert done.value.code == 2
    assert "seconds" in capsys.readouterr().err
