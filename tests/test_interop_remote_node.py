"""A cobus remote node against python-canopen as the device, on python-can's virtual bus in real
time: the mapping read over SDO, a TPDO received by name, an RPDO sent, the NMT state followed
from python-canopen's heartbeat, an emergency with its text."""

from __future__ import annotations

import os
from pathlib import Path

import canopen
import pytest

from cobus.proto.nmt import NmtState
from cobus.runtime import Network, PdoReceived
from tests.util import until

pytestmark = pytest.mark.interop

EDS = str(Path(__file__).resolve().parent.parent / "examples" / "networks" / "servo.eds")
NODE = 10


def test_cobus_remote_node_against_a_canopen_device():
    channel = f"interop-remote-{os.getpid()}"
    cnet = canopen.Network()
    cnet.connect(interface="virtual", channel=channel)
    try:
        device = canopen.LocalNode(NODE, EDS)
        cnet.add_node(device)
        device.tpdo.read(from_od=True)
        device.rpdo.read(from_od=True)
        controlwords: list[int] = []
        device.rpdo[1].add_callback(lambda pdo: controlwords.append(pdo["Controlword"].raw))
        with Network(interface="virtual", channel=channel) as net:
            node = net.add_remote(NODE, EDS)
            assert node.sdo.read("Device type") == 0x00020192  # python-canopen's SDO server
            tpdos = node.tpdo.read()  # the mapping python-canopen serves from its dictionary
            assert [p.names for p in tpdos][1] == ["Statusword", "Position actual value"]
            node.rpdo.read()

            device.nmt.state = "OPERATIONAL"
            device.nmt.start_heartbeat(50)
            try:
                assert node.nmt.wait_for_state("operational", timeout=2) is NmtState.OPERATIONAL

                seen: list[PdoReceived] = []
                node.tpdo[2].add_callback(seen.append)
                device.tpdo[2]["Statusword"].raw = 0x0237
                device.tpdo[2]["Position actual value"].raw = -1234
                device.tpdo[2].transmit()
                until(lambda: seen)
                assert seen[0].values == {"Statusword": 0x0237, "Position actual value": -1234}

                node.rpdo[1]["Controlword"] = 0x0F
                node.rpdo[1].transmit()
                until(lambda: controlwords == [0x0F])

                device.emcy.send(0x8110, 0x11)
                until(lambda: node.emcy.log)
                assert str(node.emcy.log[0]) == "0x8110 CAN overrun (objects lost) (register 0x11)"
            finally:
                device.nmt.stop_heartbeat()
    finally:
        cnet.disconnect()
