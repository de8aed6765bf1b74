"""python-canopen's BaseNode402 drives the simulated CiA 402 servo (cobus.sim), on python-can's
virtual bus in real time: its state machine, mode changes, a velocity and a profile position
move, all through an implementation of CiA 402 that is not ours (its homing() is left out: it
sends the mode by the RPDO that also carries a controlword, 0, which can disable the drive in
the middle of its sequence; it failed about one run in three). Then our Drive402 drives the
same servo."""

from __future__ import annotations

import logging
import os
from pathlib import Path

import canopen
import pytest
from canopen.profiles.p402 import BaseNode402

from cobus.profiles import Drive402, PowerState
from cobus.runtime import Network
from cobus.sim import Rig, start_rig
from tests.util import until

pytestmark = pytest.mark.interop

EDS = str(Path(__file__).resolve().parent.parent / "examples" / "networks" / "servo.eds")
NODE = 10
SERVO = """
bus: embedded
devices:
  - {node: 10, kind: cia402_drive, name: servo}
"""


def test_python_canopen_base_node_402_drives_the_simulated_servo(
    caplog: pytest.LogCaptureFixture,
) -> None:
    channel = f"interop-402-{os.getpid()}"
    with Network(interface="virtual", channel=channel) as net:
        rig = start_rig(net, Rig.loads(SERVO))
        servo = rig.device(NODE)
        cnet = canopen.Network()
        cnet.connect(interface="virtual", channel=channel)
        try:
            node = BaseNode402(NODE, EDS)
            cnet.add_node(node)
            node.nmt.state = "PRE-OPERATIONAL"
            node.setup_402_state_machine()  # reads the PDO mappings over SDO
            node.nmt.state = "OPERATIONAL"
            net.sync.start(0.01)  # the synchronous TPDOs 2-4 carry the statusword too
            until(lambda: servo.status()["nmt"] == "operational")
            # BaseNode402 starts from statusword 0 until a TPDO brings it; the servo sends
            # TPDO1 on a change only, so ask for it once by RTR
            node.tpdo[1].remote_request()
            until(lambda: node.tpdo_values[0x6041] == 0x0240)

            # the mode first: python-canopen sends it by RPDO2, which also carries a 6040h
            node.op_mode = "PROFILED VELOCITY"
            assert node.op_mode == "PROFILED VELOCITY"
            with caplog.at_level(logging.WARNING):
                node.state = "OPERATION ENABLED"  # controlword by RPDO1, statusword by TPDO1
            assert node.state == "OPERATION ENABLED"
            assert servo.status()["state"] == "operation enabled"

            node.sdo[0x6083].raw = 1_000_000
            node.sdo[0x60FF].raw = 20_000
            until(lambda: abs(node.sdo[0x606C].raw - 20_000) <= 100, timeout=3)
            node.sdo[0x60FF].raw = 0
            until(lambda: node.sdo[0x606C].raw == 0, timeout=3)

            # profile position with python-canopen's controlword: new set-point, acknowledge
            node.op_mode = "PROFILED POSITION"  # its RPDO2 sends controlword 0 along: re-enable
            node.state = "OPERATION ENABLED"
            node.sdo[0x607A].raw = 10_000
            node.controlword = 0x3F  # enable operation + new set-point + change immediately
            until(lambda: node.statusword & 0x1000)  # set-point acknowledge
            node.controlword = 0x2F
            until(lambda: node.statusword & 0x1400 == 0x0400, timeout=3)  # target reached
            assert abs(node.sdo[0x6064].raw - 10_000) <= 20

            node.state = "SWITCH ON DISABLED"
            assert servo.status()["state"] == "switch on disabled"
        finally:
            cnet.disconnect()

        # and ours, on the same servo
        drive = Drive402(net.add_remote(NODE, EDS))
        drive.enable()
        drive.move_to(6000, velocity=50_000)
        assert abs(drive.read_position() - 6000) <= 20
        drive.disable()
        assert drive.state is PowerState.SWITCH_ON_DISABLED
