"""python-canopen as the master of a cobus device, on python-can's virtual bus in real time:
it fetches the device's EDS from 1021h, reads and saves the PDO mapping by SDO, stores the
parameters, starts the node, sends SYNC and RPDOs and receives the device's TPDOs."""

from __future__ import annotations

import os

import canopen
import pytest
from canopen.objectdictionary.eds import import_from_node

from cobus.device import DictionaryBuilder, add_device
from cobus.od import DataType
from cobus.proto.nmt import NmtState
from cobus.runtime import Network
from tests.util import until

pytestmark = pytest.mark.interop

NODE = 12


def _od():
    b = DictionaryBuilder(device_name="interop device", vendor_id=0xC0B05)
    b.variable(0x2000, "Counter", DataType.UNSIGNED16, access="ro", mappable=True)
    b.variable(0x2001, "Setpoint", DataType.INTEGER16, access="rww", mappable=True)
    b.variable(0x2006, "Temperature", DataType.REAL32, access="ro", mappable=True)
    b.array(0x6000, "Digital inputs", DataType.UNSIGNED8, 2, access="ro", mappable=True)
    b.tpdo(1, [(0x2006, 0)], transmission_type=255)
    return b.build()


def test_python_canopen_configures_and_runs_a_cobus_device():
    channel = f"interop-device-{os.getpid()}"
    with Network(interface="virtual", channel=channel) as net:
        device = add_device(net, NODE, _od())
        master = canopen.Network()
        master.connect(interface="virtual", channel=channel)
        try:
            # the master takes the dictionary from the device itself (1021h)
            od = import_from_node(NODE, master)
            assert od is not None
            assert od[0x1018][1].default == 0xC0B05
            node = canopen.RemoteNode(NODE, od)
            master.add_node(node)
            with node.sdo.open(0x1021, 0, "rb", block_transfer=True) as fh:
                assert fh.read().startswith(b"[FileInfo]")

            node.tpdo.read()
            tpdo = node.tpdo[1]
            assert tpdo.cob_id == 0x180 + NODE and tpdo.enabled
            assert [v.index for v in tpdo.map] == [0x2006]
            tpdo.clear()
            tpdo.add_variable(0x2000)
            tpdo.add_variable(0x6000, 2)
            tpdo.trans_type = 1
            tpdo.enabled = True
            node.tpdo.save()
            assert device.get(0x1A00, 0) == 2
            assert device.get(0x1A00, 1) == 0x20000010
            assert device.get(0x1A00, 2) == 0x60000208
            assert device.get(0x1800, 2) == 1

            node.rpdo.read()
            rpdo = node.rpdo[1]
            rpdo.clear()
            rpdo.add_variable(0x2001)
            rpdo.trans_type = 255
            rpdo.enabled = True
            node.rpdo.save()
            node.store()  # 1010h sub 1 "save"

            node.nmt.state = "OPERATIONAL"
            until(lambda: device.state is NmtState.OPERATIONAL)
            device.set(0x2000, 0, 0x1234)
            device.set(0x6000, 2, 0x5A)
            master.sync.transmit()
            assert tpdo.wait_for_reception(timeout=2.0) is not None
            assert tpdo["Counter"].raw == 0x1234
            assert tpdo["Digital inputs.Digital inputs 2"].raw == 0x5A
            device.set(0x2000, 0, 0x4321)
            master.sync.transmit()
            until(lambda: tpdo["Counter"].raw == 0x4321)

            rpdo["Setpoint"].raw = -321
            rpdo.transmit()
            until(lambda: device.get(0x2001) == -321)

            assert node.sdo[0x1017].raw == 0
            node.sdo[0x1017].raw = 50
            node.nmt.wait_for_heartbeat(timeout=1.0)
            assert node.nmt.state == "OPERATIONAL"
        finally:
            master.disconnect()
