"""The STÖBER MDS 5000 adapter against the simulated inverter of the thesis rig (node 1): a
parameter read and written by its name, the E82 event decoded from the EMCY and read back,
the device control."""

from __future__ import annotations

import pytest

from cobus.od import DataType
from cobus.profiles.stober import (
    StoberDrive,
    StoberError,
    StoberEvent,
    event_of,
    parameter_index,
)
from cobus.runtime import Network
from cobus.sim import Rig, start_rig

RIG = """
bus: embedded
devices:
  - {node: 1, kind: stober_mds5000, name: inverter}
"""


def test_a_parameter_by_its_name_an_event_decoded_and_the_device_control() -> None:
    with Network(simulated=True) as net:
        rig = start_rig(net, Rig.loads(RIG))
        inverter = StoberDrive(net.add_remote(1), types={"C01": DataType.UNSIGNED16})
        assert inverter.read("C01") == 3000  # n-Max, rpm: 2401h by the group/number rule
        inverter.write("c01", 2500)  # names are case-blind
        assert inverter.read("C01") == 2500
        assert rig.device(1).aio.device.get(0x2401, 0) == 2500
        assert inverter.read_state() == "switch-on disabled"
        inverter.enable()
        net.sleep(0.1)
        assert inverter.read_state() == "operation enabled"

        node = net.remotes[1]
        rig.inject(1, "motor_overtemperature")
        net.sleep(0.1)
        emcy = node.emcy.last
        assert emcy is not None and emcy.code == 0x4310
        event = event_of(emcy)
        assert event == StoberEvent(41, 0) and event.active
        assert str(event) == "E82 41 motor temperature (cause 0)"
        assert event.emcy_code == 0x4310
        assert inverter.read_event() == event
        assert inverter.read_state() == "fault"

        rig.inject(1, "motor_overtemperature", active=False)
        inverter.acknowledge()
        net.sleep(0.1)
        assert node.emcy.last.code == 0x0000  # the acknowledge's EMCY
        assert inverter.read_state() != "fault"
        with pytest.raises(StoberError, match="its data type is unknown"):
            inverter.write("D230", 100)  # no EDS, no type given


def test_parameter_names_follow_the_manual_and_bad_ones_say_why() -> None:
    assert parameter_index("C01") == (0x2401, 0)
    assert parameter_index("E08") == (0x2808, 0)
    assert parameter_index("A225.3") == (0x20E1, 3)
    assert parameter_index("Z00") == (0x5200, 0)
    for bad in ("", "C", "1C01", "C01.x", "C600", 42):
        with pytest.raises(StoberError, match=r"is not a parameter|the number is 0\.\.511"):
            parameter_index(bad)  # type: ignore[arg-type]
    assert str(StoberEvent(99)) == "E82 99 event 99 (cause 0)"
    assert StoberEvent(99).emcy_code is None and not StoberEvent(30).active
