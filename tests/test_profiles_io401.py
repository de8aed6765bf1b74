"""The CiA 401 I/O module from the master side, against the simulated module: named
digital inputs and outputs, polarity, interrupt masks, scaled analogue channels with their
delta, change callbacks, on a bare node and on one the master manages."""

from __future__ import annotations

from collections.abc import Callable, Coroutine
from typing import Any

import pytest

from cobus.master import BlockingMaster
from cobus.profiles.io401 import AnalogChannel, Io401, IoChange, IoError
from cobus.runtime import Network
from cobus.sim import Rig, start_rig

RIG = """
bus: embedded
devices:
  - node: 9
    kind: cia401_io
    name: remote I/O
    options: {digital_inputs: 16, digital_outputs: 8, analog_inputs: 4, analog_outputs: 2}
"""


def test_named_channels_polarity_interrupts_and_changes_on_a_bare_node() -> None:
    with Network(simulated=True) as net:
        rig = start_rig(net, Rig.loads(RIG))
        sim = rig.aio.devices[9]
        node = net.add_remote(9)
        node.tpdo.read()  # TPDO1 digital input bytes, TPDO2 analogue inputs
        io = Io401(
            node,
            inputs={"door": 1, "estop": 10},
            outputs={"lamp": 1, "horn": 8},
            analog_inputs={"pot": AnalogChannel(1, scale=100 / 32767, unit="%")},
            analog_outputs={"valve": AnalogChannel(2, scale=0.001, unit="V")},
        )
        changes: list[IoChange] = []
        io.add_callback(changes.append)
        node.nmt.start()
        net.sleep(0.05)

        assert io.read_inputs() == {"door": False, "estop": False}  # by SDO: no TPDO yet
        net.run(_call(lambda: sim.set_digital_input(10, True)))
        net.sleep(0.05)
        assert io.read_input("estop") is True  # channel 10: bit 1 of 6000h sub 2
        assert [str(c) for c in changes] == ["door = False", "estop = True"]

        io.set_polarity("door", True)  # 6002h: the module inverts channel 1
        net.sleep(0.05)
        assert io.read_input("door") is True

        io.set_output("lamp", True)
        io.set_output("horn", True)
        assert sim.digital_output(1) and sim.digital_output(8)
        io.set_output("lamp", False)  # the other bit of the byte stays
        assert not sim.digital_output(1) and sim.digital_output(8)
        io.set_filter("horn", False, output=True)  # 6208h: writes leave the horn as it is
        io.set_output("horn", False)
        assert sim.digital_output(8)
        io.set_filter("horn", True, output=True)
        io.set_output("horn", False)
        assert not sim.digital_output(8)
        io.set_filter("door", True)  # 6003h: the module debounces the door input
        assert node.sdo.upload(0x6003, 1) == b"\x01"
        io.set_outputs({"lamp": True, "horn": True})
        assert sim.digital_output(1) and sim.digital_output(8)
        io.set_outputs({"lamp": False, "horn": False})
        assert not sim.digital_output(1) and not sim.digital_output(8)

        # estop (channel 10: bit 1 of sub 2) on its falling edge only: 6006h/6007h/6008h
        io.set_interrupt("estop", any_change=False, falling=True)
        masks = [node.sdo.upload(index, 2)[0] & 0x02 for index in (0x6006, 0x6007, 0x6008)]
        assert masks == [0, 0, 0x02]
        seen = len(changes)
        net.run(_call(lambda: sim.set_digital_input(10, False)))  # falling: sent
        net.sleep(0.05)
        estop = [str(c) for c in changes[seen:] if c.name == "estop"]
        assert estop == ["estop = False"]
        net.run(_call(lambda: sim.set_digital_input(10, True)))  # rising: not sent
        net.sleep(0.05)
        assert [str(c) for c in changes[seen:] if c.name == "estop"] == estop
        io.set_interrupt("estop")  # back to any change
        assert [node.sdo.upload(i, 2)[0] & 0x02 for i in (0x6006, 0x6007, 0x6008)] == [2, 0, 0]

        io.enable_interrupts()  # 6423h is off by default (CiA 401)
        io.set_delta("pot", 10.0)  # 10 % of the range: 3277 raw
        net.run(_call(lambda: sim.set_analog_input(1, 1000)))  # under the delta: not sent
        net.sleep(0.05)
        assert not [c for c in changes if c.name == "pot"]
        net.run(_call(lambda: sim.set_analog_input(1, 16384)))
        net.sleep(0.05)
        pot = [c for c in changes if c.name == "pot"]
        assert pot and pot[-1].value == pytest.approx(50.0, abs=0.01)
        assert io.read_analog("pot") == pytest.approx(50.0, abs=0.01)

        io.set_analog("valve", 2.5)  # V -> 2500 raw in 6411h sub 2
        assert sim.analog_output(2) == 2500

        with pytest.raises(IoError, match="no input 'window' \\(door, estop\\)"):
            io.read_input("window")
        with pytest.raises(IoError, match="outside INTEGER16"):
            io.set_analog("valve", 100.0)
        with pytest.raises(IoError, match="True or False"):
            io.set_output("lamp", 1)


def test_a_managed_module_reads_its_inputs_from_the_process_image() -> None:
    with Network(simulated=True) as net:
        rig = start_rig(net, "thesis")
        master = BlockingMaster(net, "examples/networks/thesis.yml")
        master.boot(timeout=10)
        io = Io401(master, "io", analog_inputs={"pot": AnalogChannel(1, scale=1 / 32767)})
        rig.device(9).set_potentiometer(0.5)
        net.sleep(0.1)  # TPDO2 (synchronous) brings it with the next SYNC
        assert io.read_analog("pot") == pytest.approx(0.5, abs=0.001)
        assert master.inputs["io.pot"] == round(0.5 * 32767)


def _call(fn: Callable[[], object]) -> Coroutine[Any, Any, None]:
    """A coroutine that runs ``fn`` on the network's loop (the simulated module's methods
    are called there)."""

    async def run() -> None:
        fn()

    return run()


def test_a_refused_construction_leaves_nothing_behind() -> None:
    with Network(simulated=True) as net:
        start_rig(net, "thesis")
        master = BlockingMaster(net, "examples/networks/thesis.yml")
        listeners = len(master.aio._tpdo_listeners)
        for _ in range(3):
            with pytest.raises(IoError, match="channel 0 must be an integer from 1"):
                Io401(master, "io", inputs={"door": 0})
        assert len(master.aio._tpdo_listeners) == listeners
        with pytest.raises(TypeError, match="the name is for a master's node"):
            Io401(net.add_remote(9), "io")
