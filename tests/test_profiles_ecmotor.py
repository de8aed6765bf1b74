"""The EC motor's SDO dialect as a client (seed 002), against the simulated motor: the
document's frames sent as printed, values read and written, modes, the status poll, a
refused request reported by its emergency."""

from __future__ import annotations

import pytest

from cobus.profiles.ecmotor import (
    EcMotorDrive,
    EcRefusedError,
    EcStatus,
    EcTimeoutError,
)
from cobus.proto import Frame
from cobus.runtime import Network
from cobus.sim import Rig, start_rig

RIG = """
bus: embedded
devices:
  - {node: 3, kind: ec_motor, name: ec motor}
"""


def test_the_master_reads_and_writes_the_ec_motor_over_its_dialect() -> None:
    with Network(simulated=True) as net:
        start_rig(net, Rig.loads(RIG))
        frames: list[Frame] = []
        net.aio.subscribe_all(lambda frame, now: frames.append(frame))
        motor = EcMotorDrive(net, 3)

        motor.write("p_ven", 0x1234)
        motor.write("p_pon", 0x01234567)
        motor.set_bits("m_ssm", 1 << 13)  # bx, the user flag
        sent = [bytes(f.data) for f in frames if f.cob_id == 0x603]
        assert sent == [  # as ../shared/vectors/ec-motor.txt prints them
            bytes.fromhex("22 24 20 00 34 12 00 00"),
            bytes.fromhex("22 23 20 01 67 45 23 01"),
            bytes.fromhex("22 0F 20 02 00 20 00 00"),
        ]
        assert motor.read("p_ven") == 0x1234  # answered 583 [6] 40 24 20 00 34 12
        assert motor.read("p_pon") == 0x01234567
        assert bytes(frames[-1].data) == bytes.fromhex("40 23 20 01 67 45 23 01")
        assert motor.read("m_ssm") & 1 << 13
        assert motor.read("sw_version") == 0x00BE  # ECA19.0

        motor.write("p_ven", -1000)  # signed, as its type I16
        assert motor.read("p_ven") == -1000
        assert motor.read_value("p_ven") == pytest.approx(-187.5)  # x 0.1875 rpm

        motor.set_mode("PON")
        motor.write_value("p_ven", 375.0)  # rpm -> 2000 raw
        motor.set_mode("VEL")
        net.sleep(1.0)
        status = motor.poll_status()
        assert isinstance(status, EcStatus)
        assert status.mode == "VEL" and status.power_stage_on and status.rotating
        assert motor.read_value("h_vel") == pytest.approx(375.0, abs=1)

        with pytest.raises(EcRefusedError, match=r"read 0x2050: refused .*bad command"):
            motor.read(0x2050)  # an unused index: the motor answers with its emergency
        assert motor.emergencies and "bad command" in motor.emergencies[-1].communication
        with pytest.raises(ValueError, match=r"p_ven \(I16\): 40000 is outside"):
            motor.write("p_ven", 40_000)
        with pytest.raises(KeyError, match="no object 'warp'"):
            motor.read("warp")
        with pytest.raises(ValueError, match="the modes a master sets are 0 MON"):
            motor.set_mode("RES")

        motor.reset()  # 000: 82 03, no SDO answer
        net.sleep(0.01)
        assert [bytes(f.data) for f in frames if f.cob_id == 0] == [bytes.fromhex("82 03")]
        missing = EcMotorDrive(net, 4, timeout=0.2)
        with pytest.raises(EcTimeoutError, match="EC motor 4: no answer to read p_ven"):
            missing.read("p_ven")


def test_an_emergency_that_is_no_refusal_does_not_fail_the_request() -> None:
    with Network(simulated=True) as net:
        start_rig(net, Rig.loads(RIG))
        motor = EcMotorDrive(net, 3)
        seen = []
        motor.add_callback(seen.append)
        motor.set_bits("c_sss", 1 << 9)  # bcse: the motor sends its error message...
        net.sleep(0.01)
        assert seen and "bad command" not in seen[-1].communication  # ... which is no refusal
        assert motor.read("p_ven") == 0


def test_the_command_line_reads_and_writes_the_motor(capsys: pytest.CaptureFixture[str]) -> None:
    import os

    from cobus.cli import main

    channel = f"cli-ec-{os.getpid()}"
    with Network(interface="virtual", channel=channel) as net:
        start_rig(net, Rig.loads(RIG))
        bus = ["-i", "virtual", "-c", channel]
        assert main(["ec", "write", "3", "p_ven", "2000", *bus]) == 0
        assert main(["ec", "read", "3", "p_ven", "sw_version", *bus]) == 0
        out = capsys.readouterr().out
        assert "p_ven <- 2000" in out and "p_ven: 2000 = 375 rpm" in out
        assert "sw_version: 190" in out
        assert main(["ec", "mode", "3", "PON", *bus]) == 0
        assert main(["ec", "status", "3", *bus]) == 0
        status = capsys.readouterr().out
        assert "mode PON" in status and "power stage on" in status
        assert main(["ec", "read", "3", "warp", *bus]) == 2
        assert "no object 'warp'" in capsys.readouterr().err
        assert main(["ec", "read", "4", "p_ven", "--timeout", "0.1", *bus]) == 1
        assert "EC motor 4: no answer" in capsys.readouterr().err
