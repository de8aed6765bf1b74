"""The simulated CiA 401 I/O module: event-driven TPDOs when inputs change (with the interrupt
objects), analogue inputs with their delta, outputs by RPDO and their error state, and the
speed potentiometer; on the simulated clock with a cobus master."""

from __future__ import annotations

import struct

import pytest

from cobus.proto.sdo import SdoAbortedError
from cobus.sim.io401 import ChannelError, SimulatedIo401
from tests.test_sim_support import SimBench, run_sim

NODE = 20
TPDO1, TPDO2 = 0x180 + NODE, 0x280 + NODE
RPDO1, RPDO2 = 0x200 + NODE, 0x300 + NODE


def io_run(scenario, **options):
    return run_sim(lambda net: SimulatedIo401(net, NODE, **options), scenario)


async def start(b: SimBench) -> None:
    b.net.nmt.start(NODE)
    await b.settle()


def test_an_input_change_sends_the_event_driven_tpdo():
    async def scenario(b: SimBench):
        io: SimulatedIo401 = b.sim
        io.set_digital_input(3, True)  # pre-operational: no PDO
        await b.settle()
        assert b.data(TPDO1) == []
        assert await b.sdo.read(0x6000, 1) == 0x04
        await start(b)
        io.set_digital_input(10, True)
        await b.settle()
        assert b.data(TPDO1) == [bytes((0x04, 0x02))]
        io.set_digital_input(10, True)  # no change, no PDO
        io.set_digital_input(3, False)
        await b.settle()
        assert b.data(TPDO1)[-1] == bytes((0x00, 0x02))
        assert len(b.data(TPDO1)) == 2
        assert io.digital_input(10) and not io.digital_input(3)

    io_run(scenario)


def test_interrupt_masks_polarity_and_global_enable_decide_which_changes_are_sent():
    async def scenario(b: SimBench):
        io: SimulatedIo401 = b.sim
        await b.sdo.write(0x6006, 1, 0x00)  # no "any change" on byte 1
        await b.sdo.write(0x6007, 1, 0x01)  # low-to-high of channel 1 only
        await start(b)
        io.set_digital_input(1, True)
        io.set_digital_input(1, False)  # high-to-low: masked
        io.set_digital_input(2, True)  # masked
        await b.settle()
        assert b.data(TPDO1) == [bytes((0x01, 0x00))]
        # polarity 6002h inverts what is read and sent
        await b.sdo.write(0x6002, 2, 0xFF)
        assert await b.sdo.read(0x6000, 2) == 0xFF
        io.set_digital_input(9, True)  # logical 1 -> 0 on byte 2: any change is enabled there
        await b.settle()
        assert b.data(TPDO1)[-1] == bytes((0x02, 0xFE))
        # global interrupt off: values change, nothing is sent
        await b.sdo.write(0x6005, 0, False)
        io.set_digital_input(16, True)
        await b.settle()
        assert len(b.data(TPDO1)) == 2
        assert await b.sdo.read(0x6000, 2) == 0x7E

    io_run(scenario)


def test_acyclic_synchronous_tpdo_sends_the_change_at_the_next_sync():
    async def scenario(b: SimBench):
        await b.sdo.write(0x1800, 1, TPDO1 | 0x80000000)
        await b.sdo.write(0x1800, 2, 0)
        await b.sdo.write(0x1800, 1, TPDO1)
        await start(b)
        await b.sync()
        assert b.data(TPDO1) == []
        b.sim.set_digital_input(5, True)
        await b.settle()
        assert b.data(TPDO1) == []
        await b.sync()
        assert b.data(TPDO1) == [bytes((0x10, 0x00))]
        await b.sync()
        assert len(b.data(TPDO1)) == 1

    io_run(scenario)


def test_analogue_inputs_are_sent_on_a_change_of_at_least_the_delta():
    async def scenario(b: SimBench):
        io: SimulatedIo401 = b.sim
        await start(b)
        io.set_analog_input(1, 500)  # 6423h is off by default (CiA 401)
        await b.settle()
        assert b.data(TPDO2) == []
        assert await b.sdo.read(0x6401, 1) == 500
        await b.sdo.write(0x6426, 1, 100)
        await b.sdo.write(0x6423, 0, True)
        io.set_analog_input(1, 580)  # 580 from the last value sent (none yet: 0)
        io.set_analog_input(1, 650)  # 70 from 580: below the delta
        await b.settle()
        assert b.data(TPDO2) == [struct.pack("<4h", 580, 0, 0, 0)]
        io.set_analog_input(1, 480)  # 100 from 580
        await b.settle()
        assert b.data(TPDO2)[-1] == struct.pack("<4h", 480, 0, 0, 0)
        io.set_analog_input(2, 1)  # delta 0 on channel 2: any change
        await b.settle()
        assert b.data(TPDO2)[-1] == struct.pack("<4h", 480, 1, 0, 0)
        assert len(b.data(TPDO2)) == 3

    io_run(scenario)


def test_speed_potentiometer_is_an_analogue_input():
    async def scenario(b: SimBench):
        io: SimulatedIo401 = b.sim
        assert await b.sdo.read(0x6401, 2) == 8192  # 0.25 of full scale
        await b.sdo.write(0x6423, 0, True)
        await start(b)
        io.set_potentiometer(1.0)
        await b.settle()
        assert b.data(TPDO2) == [struct.pack("<4h", 0, 32767, 0, 0)]
        assert io.potentiometer == 1.0
        assert b.sim.status()["potentiometer"] == 1.0
        with pytest.raises(ChannelError, match=r"outside 0\.\.1"):
            io.set_potentiometer(1.5)

    io_run(scenario, potentiometer={"channel": 2, "position": 0.25})


def test_outputs_follow_the_rpdos_and_take_their_error_values_when_stopped():
    async def scenario(b: SimBench):
        io: SimulatedIo401 = b.sim
        await b.sdo.write(0x6206, 1, 0x0F)  # error mode for channels 1-4
        await b.sdo.write(0x6207, 1, 0x08)  # channel 4 on in the error state
        await b.sdo.write(0x6202, 1, 0x80)  # channel 8 inverted
        await b.sdo.write(0x6444, 2, -1000)
        await start(b)
        b.send(RPDO1, bytes((0x05,)))
        b.send(RPDO2, struct.pack("<2h", 1500, -200))
        await b.settle()
        levels = [io.digital_output(c) for c in range(1, 9)]
        assert levels == [True, False, True, False, False, False, False, True]
        assert (io.analog_output(1), io.analog_output(2)) == (1500, -200)
        b.net.nmt.stop(NODE)
        await b.settle()
        assert b.sim.in_error_state
        levels = [io.digital_output(c) for c in range(1, 9)]
        assert levels == [False, False, False, True, False, False, False, True]
        assert (io.analog_output(1), io.analog_output(2)) == (0, -1000)
        assert b.sim.status()["outputs"] == "00010001"
        # operational again and new values: the error state ends
        await start(b)
        b.send(RPDO1, bytes((0x02,)))
        await b.settle()
        assert not b.sim.in_error_state
        assert [io.digital_output(c) for c in (1, 2, 4)] == [False, True, False]
        io.inject("power_loss")
        assert not io.digital_output(2) and io.analog_output(1) == 0

    io_run(scenario)


def test_heartbeat_option_and_channel_errors():
    async def scenario(b: SimBench):
        await b.net.sleep(0.26)
        assert [t for t, f in b.on(0x700 + NODE) if f.data == b"\x7f"] == pytest.approx(
            [0.05, 0.10, 0.15, 0.20, 0.25]
        )
        io: SimulatedIo401 = b.sim
        with pytest.raises(ChannelError, match=r"digital inputs 1\.\.8"):
            io.set_digital_input(9, True)
        with pytest.raises(ChannelError, match="INTEGER16"):
            io.set_analog_input(1, 40_000)
        with pytest.raises(ChannelError, match="no potentiometer"):
            io.set_potentiometer(0.5)
        with pytest.raises(SdoAbortedError) as err:
            await b.sdo.upload(0x6411, 1)  # no analogue outputs on this module
        assert err.value.code == 0x06020000
        assert await b.sdo.read(0x1000) == 0x00050191  # digital + analogue inputs

    io_run(scenario, digital_inputs=8, digital_outputs=0, analog_outputs=0, heartbeat_ms=50)


def test_a_lost_heartbeat_puts_the_outputs_in_their_error_state():
    async def scenario(b: SimBench):
        io: SimulatedIo401 = b.sim
        await b.sdo.write(0x1016, 1, 127 << 16 | 100)
        await b.sdo.write(0x1029, 1, 1)  # communication error: no NMT change
        b.send(0x77F, b"\x05")
        await start(b)
        b.send(RPDO1, bytes((0x03,)))
        await b.settle()
        assert [io.digital_output(c) for c in (1, 2)] == [True, True]
        await b.net.sleep(0.15)  # the master's heartbeat is gone
        assert b.sim.in_error_state
        assert [io.digital_output(c) for c in (1, 2)] == [False, False]  # 6207h: 0
        b.send(0x77F, b"\x05")
        b.send(RPDO1, bytes((0x01,)))
        await b.settle()
        assert not b.sim.in_error_state
        assert [io.digital_output(c) for c in (1, 2)] == [True, False]

    io_run(scenario)
