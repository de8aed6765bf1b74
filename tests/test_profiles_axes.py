"""Several axes in lockstep, and the jog's dead-man timer, against simulated CiA 402 servos
on the simulated clock."""

from __future__ import annotations

import textwrap
from pathlib import Path

import pytest

from cobus.master import BlockingMaster, loads_network
from cobus.profiles import Drive402, DriveStateError, PowerState
from cobus.profiles.axes import Axes
from cobus.proto import Frame
from cobus.runtime import Network
from cobus.sim import Rig, start_rig

EXAMPLES = Path(__file__).resolve().parent.parent / "examples" / "networks"
RIG = """
bus: embedded
devices:
  - {node: 10, kind: cia402_drive, name: x}
  - {node: 11, kind: cia402_drive, name: y}
"""
AXIS = """
    node_id: {id}
    eds: servo.eds
    rpdo1: {{mapping: [controlword], transmission_type: 1}}   # taken at the SYNC
    rpdo2: {{enabled: false}}
    rpdo3: {{enabled: false}}
    rpdo4: {{enabled: false}}
    tpdo1: {{mapping: [statusword], transmission_type: 255}}
"""
NETWORK = "master: {sync_period: 10}\nnodes:\n" + "".join(
    f"  {name}:{textwrap.indent(AXIS.format(id=node), '  ')}"
    for name, node in (("x", 10), ("y", 11))
)


def state_changes(frames: list[tuple[float, Frame]], cob_id: int) -> list[tuple[float, int]]:
    """(time, statusword) of each TPDO1 of a drive."""
    return [(t, int.from_bytes(f.data[:2], "little")) for t, f in frames if f.cob_id == cob_id]


def test_two_axes_enable_and_quick_stop_on_the_same_sync() -> None:
    with Network(simulated=True) as net:
        start_rig(net, Rig.loads(RIG))
        master = BlockingMaster(net, loads_network(NETWORK, base_dir=EXAMPLES))
        master.boot(timeout=10)
        frames: list[tuple[float, Frame]] = []
        net.aio.subscribe_all(lambda frame, now: frames.append((now, frame)))
        x, y = Drive402(master, "x"), Drive402(master, "y")
        axes = Axes([x, y])
        axes.enable()
        assert x.state is PowerState.OPERATION_ENABLED and y.state is PowerState.OPERATION_ENABLED
        enabled = [
            next(t for t, sw in state_changes(frames, cob) if sw & 0x6F == 0x27)
            for cob in (0x18A, 0x18B)
        ]
        assert enabled[0] == enabled[1]  # the same SYNC took both controlwords

        x.set_velocity(20_000, wait=False)
        y.set_velocity(-20_000, wait=False)
        net.sleep(0.2)
        frames.clear()
        axes.quick_stop()
        stopped = [
            next(t for t, sw in state_changes(frames, cob) if sw & 0x6F != 0x27)
            for cob in (0x18A, 0x18B)
        ]
        assert stopped[0] == stopped[1]
        assert abs(x.read_velocity()) < 100 and abs(y.read_velocity()) < 100  # stopped
        with pytest.raises(ValueError, match="in the group twice"):
            Axes([x, x])


def test_a_jog_stops_by_itself_when_the_operator_lets_go() -> None:
    with Network(simulated=True) as net:
        start_rig(net, Rig.loads(RIG))
        drive = Drive402(net.add_remote(10))
        with pytest.raises(DriveStateError, match="no jog runs"):
            drive.keep_jogging()
        drive.enable()
        drive.jog(10_000, deadman=0.2)
        for _ in range(10):  # the operator holds the button for a second
            net.sleep(0.1)
            drive.keep_jogging()
        assert drive.jogging and drive.read_velocity() == pytest.approx(10_000, abs=100)
        net.sleep(0.5)  # ... and lets go (or the panel's link drops)
        assert not drive.jogging
        assert drive.jog_ended == "dead-man: no keep_jogging() for 0.2 s"
        assert drive.read_velocity() == 0
        assert drive.state is PowerState.OPERATION_ENABLED  # halted, not switched off

        drive.jog(-5_000)
        net.sleep(0.1)
        drive.stop_jog()
        assert drive.jog_ended == "stopped" and drive.read_velocity() == pytest.approx(0, abs=20)
