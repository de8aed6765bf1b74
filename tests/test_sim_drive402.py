"""The simulated CiA 402 drive, driven by a cobus master through SDO, NMT, SYNC and PDOs on the
simulated clock: the state machine, profile position / velocity / torque, homing, cyclic
synchronous position, and its faults with their emergencies and fault reset."""

from __future__ import annotations

import math
import struct

import pytest

from cobus.proto.sdo import SdoAbortedError
from cobus.sim.drive402 import DriveState, SimulatedDrive402
from tests.test_sim_support import SimBench, run_sim

NODE = 10
TPDO1, TPDO2, TPDO3, TPDO4 = (0x180 + 0x100 * n + NODE for n in range(4))
RPDO1, RPDO2, RPDO3, RPDO4 = (0x200 + 0x100 * n + NODE for n in range(4))
EMCY = 0x80 + NODE

# statusword values (state bits, voltage enabled, remote) without the mode-specific bits
SOD, RTSO, SO, OE, QSA, FRA, FAULT = 0x0240, 0x0231, 0x0233, 0x0237, 0x0217, 0x021F, 0x0218
STATE_MASK = 0x027F


def drive_run(scenario, **options):
    return run_sim(lambda net: SimulatedDrive402(net, NODE, **options), scenario)


async def state(b: SimBench) -> int:
    return int(await b.sdo.read(0x6041)) & STATE_MASK


async def sw(b: SimBench) -> int:
    return int(await b.sdo.read(0x6041))


def statuswords(b: SimBench, since: float = -1.0) -> list[int]:
    return [struct.unpack("<H", d)[0] for d in b.data(TPDO1, since=since)]


async def enable(b: SimBench) -> None:
    """NMT start, then shutdown / switch on / enable operation by RPDO1."""
    b.net.nmt.start(NODE)
    await b.settle()
    for cw in (0x06, 0x07, 0x0F):
        b.send(RPDO1, struct.pack("<H", cw))
        await b.settle()
    assert await state(b) == OE


async def setpoint(b: SimBench, target: int, *, bits: int = 0) -> None:
    """The profile position handshake: new set-point (bit 4) up, acknowledged, down."""
    b.send(RPDO3, struct.pack("<Hi", 0x0F | bits, target))
    b.send(RPDO3, struct.pack("<Hi", 0x1F | bits, target))
    await b.settle()
    assert await sw(b) & 0x1000, "set-point acknowledge (bit 12) after new set-point"
    b.send(RPDO3, struct.pack("<Hi", 0x0F | bits, target))
    await b.settle()


def test_state_machine_through_every_transition():
    async def scenario(b: SimBench):
        assert await sw(b) == SOD  # not ready to switch on passed at once: switch on disabled
        cw = b.sdo
        # 2, 3, 4, 5, 4, 8 (shutdown from operation enabled), 3, 10 (disable voltage)
        for value, expected in (
            (0x06, RTSO),
            (0x07, SO),
            (0x0F, OE),
            (0x07, SO),
            (0x0F, OE),
            (0x06, RTSO),
            (0x07, SO),
            (0x00, SOD),
        ):
            await cw.write(0x6040, 0, value)
            assert await state(b) == expected, f"controlword {value:#04x}"
        # enable operation is no command in switch on disabled; quick stop from ready (7)
        await cw.write(0x6040, 0, 0x0F)
        assert await state(b) == SOD
        await cw.write(0x6040, 0, 0x06)
        await cw.write(0x6040, 0, 0x02)
        assert await state(b) == SOD
        # ready -> operation enabled directly (3 + 4); quick stop (11) ramps, then 12
        await cw.write(0x6040, 0, 0x06)
        await cw.write(0x6040, 0, 0x0F)
        assert await state(b) == OE
        await cw.write(0x6040, 0, 0x0B)
        assert await state(b) == QSA
        await b.net.sleep(0.01)
        assert await state(b) == SOD  # quick stop option 2: ends in switch on disabled
        # quick stop option 6 stays in quick stop active; enable operation returns (16)
        await cw.write(0x605A, 0, 6)
        for value in (0x06, 0x0F, 0x0B):
            await cw.write(0x6040, 0, value)
        await b.net.sleep(0.05)
        assert await state(b) == QSA
        assert await sw(b) & 0x0400  # stopped: target reached
        await cw.write(0x6040, 0, 0x0F)
        assert await state(b) == OE
        # disable voltage from operation enabled (9)
        await cw.write(0x6040, 0, 0x0D)
        assert await state(b) == SOD
        assert b.sim.state is DriveState.SWITCH_ON_DISABLED

    drive_run(scenario)


def test_statusword_tpdo_follows_each_state_change_and_nmt_reset_node_restarts_the_drive():
    async def scenario(b: SimBench):
        await enable(b)
        assert [w & STATE_MASK for w in statuswords(b)] == [RTSO, SO, OE]
        await b.net.sleep(0.02)
        assert statuswords(b)[-1] == OE | 0x0400  # profile position at rest: target reached
        b.net.nmt.reset_node(NODE)
        await b.settle()
        await b.net.sleep(0.002)
        assert await sw(b) == SOD
        assert await b.sdo.read(0x6040) == 0
        assert b.data(0x700 + NODE)[-1] == b"\x00"  # boot-up after the reset

    drive_run(scenario)


def test_profile_position_move_reaches_its_target_with_the_profile():
    async def scenario(b: SimBench):
        await b.sdo.write(0x6081, 0, 40_000)  # increments/s
        await b.sdo.write(0x6083, 0, 200_000)  # increments/s²
        await b.sdo.write(0x6084, 0, 400_000)
        await enable(b)
        b.net.sync.start(0.01)
        start = b.net.time()
        await setpoint(b, 30_000)
        assert not await sw(b) & 0x0400  # moving: target not reached
        took = await b.until(lambda: b.sim.status()["position"] >= 29_980, 3.0)
        await b.until(lambda: statuswords(b)[-1] & 0x0400, 0.1)
        velocities = [struct.unpack("<Hi", d)[1] for d in b.data(TPDO3, since=start)]
        b.net.sync.stop()
        # 0.2 s accelerating, 0.6 s at 40000, 0.1 s decelerating
        assert took == pytest.approx(0.9, abs=0.03)
        assert max(velocities) == pytest.approx(40_000, rel=0.03)
        assert velocities[9] == pytest.approx(20_000, rel=0.1)  # 0.1 s into the ramp
        assert abs(await b.sdo.read(0x6064) - 30_000) <= 20  # position window 6067h
        assert abs(await b.sdo.read(0x60F4)) <= 20
        # relative set-point (bit 6): from the previous target
        await setpoint(b, -10_000, bits=0x40)
        await b.until(lambda: b.sim.status()["position"] <= 20_020, 2.0)
        await b.until(lambda: statuswords(b)[-1] & 0x0400, 0.2)
        assert abs(await b.sdo.read(0x6064) - 20_000) <= 20

    drive_run(scenario)


def test_buffered_setpoint_runs_after_the_current_one_and_change_immediately_replaces():
    async def scenario(b: SimBench):
        await enable(b)
        await setpoint(b, 20_000)
        await b.net.sleep(0.1)
        # a second set-point without "change immediately": buffered, acknowledge stays up
        await setpoint(b, 5_000)
        assert await sw(b) & 0x1000
        await b.until(lambda: b.sim.status()["position"] >= 19_900, 2.0)
        await b.until(lambda: b.sim.status()["position"] <= 5_100, 2.0)
        assert not await sw(b) & 0x1000  # buffer taken: acknowledge down
        await b.until(lambda: statuswords(b)[-1] & 0x0400, 0.5)
        # change immediately (bit 5): the new target replaces the running move
        await setpoint(b, 40_000)
        await b.net.sleep(0.1)
        assert b.sim.status()["position"] > 5_100
        await setpoint(b, 0, bits=0x20)
        seen = []

        def reached() -> bool:
            seen.append(b.sim.status()["position"])
            return bool(statuswords(b)[-1] & 0x0400)

        await b.until(reached, 2.0)
        assert abs(await b.sdo.read(0x6064)) <= 20
        assert max(seen) < 12_000  # turned back long before 40000

    drive_run(scenario)


def test_profile_velocity_reaches_the_target_velocity():
    async def scenario(b: SimBench):
        await b.sdo.write(0x6083, 0, 250_000)
        await enable(b)
        b.send(RPDO2, struct.pack("<Hb", 0x0F, 3))  # mode 3 with the controlword
        b.send(RPDO4, struct.pack("<Hi", 0x0F, 25_000))
        await b.settle()
        assert await b.sdo.read(0x6061) == 3
        took = await b.until(lambda: statuswords(b)[-1] & 0x0400, 1.0)
        assert took == pytest.approx(0.1 + 0.01, abs=0.02)  # ramp + velocity window time
        assert await b.sdo.read(0x606C) == pytest.approx(25_000, abs=100)
        assert not statuswords(b)[-1] & 0x1000  # speed is not zero
        await b.net.sleep(0.5)
        assert await b.sdo.read(0x606C) == pytest.approx(25_000, abs=100)
        # halt (bit 8): ramps down with 6084h and reports speed zero (bit 12)
        b.send(RPDO4, struct.pack("<Hi", 0x010F, 25_000))
        await b.until(lambda: statuswords(b)[-1] & 0x1000, 0.5)
        assert abs(await b.sdo.read(0x606C)) <= 20

    drive_run(scenario)


def test_profile_torque_with_slope_and_speed_limit():
    async def scenario(b: SimBench):
        await b.sdo.write(0x6080, 0, 30_000)
        await b.sdo.write(0x6087, 0, 10_000)  # per mille per second
        await enable(b)
        await b.sdo.write(0x6060, 0, 4)
        await b.sdo.write(0x6071, 0, 500)

        async def demand_reached() -> bool:
            return bool(await b.sdo.read(0x6074) == 500)

        took = await b.until(demand_reached, 0.5)
        assert took == pytest.approx(0.05, abs=0.005)
        assert await b.sdo.read(0x6041) & 0x0400
        await b.net.sleep(1.0)
        speed = await b.sdo.read(0x606C)
        assert 25_000 < speed <= 31_000  # limited by 6080h
        assert await b.sdo.read(0x6077) > 0

    drive_run(scenario)


@pytest.mark.parametrize(
    ("method", "options", "home_raw"),
    [
        (17, {"negative_limit": -3000}, -3000),
        (18, {"positive_limit": 2500}, 2500),
        (1, {"negative_limit": -3000, "index_offset": 1596}, 1596 - 4096),
        (2, {"positive_limit": 2500, "index_offset": 1596}, 1596),
        (37, {}, 0),
    ],
)
def test_homing_methods_attain_home(method, options, home_raw):
    async def scenario(b: SimBench):
        await b.sdo.write(0x6098, 0, method)
        await b.sdo.write(0x607C, 0, 500)  # home offset
        await enable(b)
        await b.sdo.write(0x6060, 0, 6)
        await b.sdo.write(0x6040, 0, 0x1F)  # homing operation start
        await b.until(lambda: statuswords(b)[-1] & 0x1400 == 0x1400, 2.0)
        assert not statuswords(b)[-1] & 0x2000
        position = await b.sdo.read(0x6064)
        raw = b.sim.motor.raw
        # the home point got the home offset; the axis stopped just past it
        assert abs(position - 500 - (raw - home_raw)) <= 2
        assert abs(raw - home_raw) <= 40
        await b.net.sleep(0.1)
        assert statuswords(b)[-1] & 0x1400 == 0x1400

    drive_run(scenario, **options)


def test_homing_without_the_switch_reports_a_homing_error():
    async def scenario(b: SimBench):
        await b.sdo.write(0x6098, 0, 18)
        await enable(b)
        await b.sdo.write(0x6060, 0, 6)
        await b.sdo.write(0x6040, 0, 0x1F)
        await b.until(lambda: statuswords(b)[-1] & 0x2000, 0.5)
        assert not statuswords(b)[-1] & 0x1000
        with pytest.raises(SdoAbortedError) as err:
            await b.sdo.write(0x6098, 0, 99)
        assert err.value.code == 0x06090030

    drive_run(scenario)


def test_limit_switch_stops_a_move_toward_it():
    async def scenario(b: SimBench):
        await enable(b)
        await setpoint(b, 40_000)
        await b.until(lambda: b.sim.status()["velocity"] == 0 and b.sim.motor.raw > 9_000, 2.0)
        # stopped past the switch with the quick stop deceleration: 50000² / (2 x 2e6) = 625
        assert 10_500 <= b.sim.motor.raw <= 10_700
        assert await b.sdo.read(0x60FD) & 0x2  # positive limit switch
        assert await sw(b) & 0x0800  # internal limit active
        assert not await sw(b) & 0x0400
        await setpoint(b, 0)  # away from the switch is allowed
        await b.until(lambda: statuswords(b)[-1] & 0x0400, 2.0)

    drive_run(scenario, positive_limit=10_000)


def test_cyclic_synchronous_position_follows_the_targets_of_each_sync():
    async def scenario(b: SimBench):
        # RPDO3 (controlword + target position) synchronous: applied at the next SYNC
        comm = 0x1402
        await b.sdo.write(comm, 1, RPDO3 | 0x80000000)
        await b.sdo.write(comm, 2, 1)
        await b.sdo.write(comm, 1, RPDO3)
        await enable(b)
        await b.sdo.write(0x6060, 0, 8)
        period = 0.005
        worst_fe = 0
        lags = []
        for k in range(200):
            target = round(8000 * math.sin(2 * math.pi * k * period))
            b.send(RPDO3, struct.pack("<Hi", 0x0F, target))
            await b.sync()
            await b.net.sleep(period)
            worst_fe = max(worst_fe, abs(await b.sdo.read(0x60F4)))
            # one period after its SYNC the demand has arrived at the target
            lags.append(abs(await b.sdo.read(0x6062) - target))
        assert max(lags) <= 1
        assert worst_fe < 250  # peak speed 50000 increments/s, a velocity step at the start
        assert await sw(b) & 0x1000  # drive follows the command value
        # a target without SYNC is not taken; the next SYNC takes it
        b.send(RPDO3, struct.pack("<Hi", 0x0F, 1_000))
        await b.settle()
        before = await b.sdo.read(0x6062)
        await b.net.sleep(0.05)
        assert await b.sdo.read(0x6062) == before
        await b.sync()
        # interpolated over the time since the last SYNC (60C2h is not set)
        await b.net.sleep(0.06)
        assert await b.sdo.read(0x6062) == 1_000

    drive_run(scenario)


def test_following_error_fault_emergency_and_fault_reset():
    async def scenario(b: SimBench):
        await enable(b)
        b.sim.inject("blocked_rotor")
        t0 = b.net.time()
        await setpoint(b, 20_000)
        await b.until(lambda: statuswords(b)[-1] & 0x4F == 0x08, 0.5)
        emcy = b.data(EMCY, since=t0)
        assert emcy[0] == bytes.fromhex("1186 21 0000000000")  # 8611h, generic + profile
        assert await b.sdo.read(0x603F) == 0x8611
        assert await b.sdo.read(0x1001) == 0x21
        states = [w & STATE_MASK for w in statuswords(b, since=t0)]
        assert FRA in states and states[-1] == FAULT
        assert "following error" in b.sim.fault_reason
        # a fault reset while the bit is high already is no edge; 0 -> 1 is
        b.sim.inject("free_rotor")
        await b.sdo.write(0x6040, 0, 0x00)
        await b.sdo.write(0x6040, 0, 0x80)
        assert await state(b) == SOD
        assert b.data(EMCY)[-1] == bytes(8)  # error reset
        assert await b.sdo.read(0x603F) == 0
        assert await b.sdo.read(0x1001) == 0
        # and it moves again
        await b.sdo.write(0x6040, 0, 0x06)
        await b.sdo.write(0x6040, 0, 0x0F)
        await setpoint(b, 2_000)
        await b.until(lambda: statuswords(b)[-1] & 0x0400 and b.sim.motor.raw > 1_900, 1.0)

    drive_run(scenario)


def test_overtemperature_from_the_thermal_model_and_reset_after_cooling():
    async def scenario(b: SimBench):
        await enable(b)
        await b.sdo.write(0x6060, 0, 4)
        b.sim.inject("blocked_rotor")
        await b.sdo.write(0x6071, 0, 2500)  # 250 % of rated torque into a jammed load
        took = await b.until(lambda: b.data(EMCY), 5.0)
        assert b.data(EMCY)[0][:3] == bytes.fromhex("1043 09")  # 4310h, generic + temperature
        assert 0.1 < took < 1.0
        await b.sdo.write(0x6071, 0, 0)
        await b.until(lambda: statuswords(b)[-1] & 0x4F == 0x08, 1.0)
        assert await b.sdo.read(0x2000) >= 1200  # 0.1 °C
        # too hot for a reset: the fault stays
        await b.sdo.write(0x6040, 0, 0x80)
        assert await state(b) == FAULT
        await b.sdo.write(0x6040, 0, 0x00)
        await b.until(lambda: b.sim.motor.temperature < 110, 5.0)
        await b.sdo.write(0x6040, 0, 0x80)
        assert await state(b) == SOD

    drive_run(scenario, thermal_time_constant=0.5)


def test_overcurrent_and_injected_faults_have_their_codes_and_register_bits():
    async def scenario(b: SimBench):
        await enable(b)
        b.sim.inject("overcurrent")
        await b.settle()
        assert await state(b) == FAULT  # power stage off at once: no fault reaction ramp
        assert b.data(EMCY)[-1][:3] == bytes.fromhex("1023 03")
        await b.sdo.write(0x6040, 0, 0x80)
        assert await state(b) == SOD
        b.sim.inject("overtemperature")
        await b.settle()
        assert b.data(EMCY)[-1][:3] == bytes.fromhex("1043 09")
        assert await b.sdo.read(0x6041) & 0x0088 == 0x0088  # fault + warning (hot)
        b.sim.inject("drive_fault", code=0x5530)
        await b.settle()
        assert await b.sdo.read(0x603F) == 0x4310  # the first fault stays in 603Fh
        with pytest.raises(ValueError, match="takes code, register"):
            b.sim.inject("drive_fault", severity=3)
        assert "blocked_rotor" in b.sim.FAULTS and "overcurrent" in b.sim.FAULTS

    drive_run(scenario)


def test_stopping_the_node_disables_the_drive_and_power_cycle_loses_the_position():
    async def scenario(b: SimBench):
        await enable(b)
        await setpoint(b, 5_000)
        await b.until(lambda: statuswords(b)[-1] & 0x0400, 1.0)
        b.net.nmt.stop(NODE)  # abort connection option 2: disable voltage
        await b.settle()
        assert b.sim.state is DriveState.SWITCH_ON_DISABLED
        b.sim.inject("power_loss")
        await b.net.sleep(1.0)
        b.sim.inject("power_return")
        await b.settle()
        assert b.data(0x700 + NODE)[-1] == b"\x00"
        assert await b.sdo.read(0x6064) == 0  # incremental encoder: counts from 0 again
        assert abs(b.sim.motor.raw - 5_000) <= 20  # the shaft did not move
        assert await sw(b) == SOD

    drive_run(scenario)


def test_unsupported_mode_is_refused_and_status_tells_the_model():
    async def scenario(b: SimBench):
        with pytest.raises(SdoAbortedError) as err:
            await b.sdo.write(0x6060, 0, 2)  # velocity mode (vl): not this drive's
        assert err.value.code == 0x06090030
        assert await b.sdo.read(0x6502) == 0x3ED
        assert await b.sdo.read(0x1000) == 0x00020192
        status = b.sim.status()
        assert status["state"] == "switch on disabled"
        assert status["mode"] == "profile_position"
        assert status["temperature"] == 25.0

    drive_run(scenario)


@pytest.mark.parametrize(
    ("option", "code", "final"),
    [(1, 0x8100, FAULT), (2, None, SOD), (3, None, SOD)],
)
def test_abort_connection_option_on_a_lost_heartbeat(option, code, final):
    async def scenario(b: SimBench):
        await b.sdo.write(0x6007, 0, option)
        await b.sdo.write(0x1016, 1, 127 << 16 | 100)  # watch the master (node 127)
        b.send(0x77F, b"\x05")
        await enable(b)
        await b.sdo.write(0x6060, 0, 3)
        await b.sdo.write(0x60FF, 0, 20_000)
        await b.net.sleep(0.2)  # the heartbeat times out after 100 ms
        # (the node went pre-operational too, 1029h: the statusword is read by SDO)
        states = [w & STATE_MASK for w in statuswords(b)]
        assert await state(b) == final
        if option == 3:
            assert QSA in states  # ramped down first (605Ah = 2), then switch on disabled
        codes = [struct.unpack("<H", d[:2])[0] for d in b.data(EMCY)]
        assert 0x8130 in codes  # the device's own heartbeat error
        assert (code in codes) if code else 0x8100 not in codes

    drive_run(scenario)


@pytest.mark.parametrize(
    ("index", "option", "ramp"),
    [
        (0x605A, 1, 0.1),  # quick stop with the profile deceleration (500000)
        (0x605A, 2, 0.025),  # quick stop with the quick stop deceleration (2000000)
        (0x605A, 0, 0.0),  # disable the drive function: no ramp
        (0x605E, 2, 0.025),  # fault reaction with the quick stop deceleration
        (0x605E, 0, 0.0),  # fault reaction: coast
    ],
)
def test_quick_stop_and_fault_reaction_ramps_follow_their_option_codes(index, option, ramp):
    async def scenario(b: SimBench):
        await b.sdo.write(index, 0, option)
        await enable(b)
        await b.sdo.write(0x6060, 0, 3)
        await b.sdo.write(0x60FF, 0, 50_000)
        await b.until(lambda: statuswords(b)[-1] & 0x0400, 0.5)
        t0 = b.net.time()
        if index == 0x605A:
            await b.sdo.write(0x6040, 0, 0x0B)
            done = SOD
        else:
            b.sim.inject("drive_fault", code=0x5530)
            done = FAULT
        took = await b.until(lambda: statuswords(b)[-1] & STATE_MASK == done, 0.5)
        stopped_speed = abs(b.sim.motor.speed)
        if ramp:
            # the demand ramps down in `ramp`; the state changes once the motor is still
            assert ramp <= took <= ramp + 0.04
            assert stopped_speed <= 20  # 606Fh
        else:
            assert took < 0.0015  # within the first tick
            assert stopped_speed > 40_000  # power off at once: the motor coasts
        assert b.net.time() >= t0

    drive_run(scenario)


@pytest.mark.parametrize("start", ["SWITCH_ON_DISABLED", "READY_TO_SWITCH_ON", "SWITCHED_ON",
                                   "OPERATION_ENABLED"])  # fmt: skip
def test_the_simulated_drive_takes_the_numbered_transitions_of_profiles_cia402(start):
    from cobus.profiles.cia402 import PowerState, command_of, transition

    path = {"SWITCH_ON_DISABLED": (), "READY_TO_SWITCH_ON": (0x06,),
            "SWITCHED_ON": (0x06, 0x07), "OPERATION_ENABLED": (0x06, 0x07, 0x0F)}  # fmt: skip
    bits = {SOD: PowerState.SWITCH_ON_DISABLED, RTSO: PowerState.READY_TO_SWITCH_ON,
            SO: PowerState.SWITCHED_ON, OE: PowerState.OPERATION_ENABLED,
            QSA: PowerState.QUICK_STOP_ACTIVE}  # fmt: skip

    async def scenario(b: SimBench):
        for controlword in (0x00, 0x02, 0x06, 0x07, 0x0F):
            await b.sdo.write(0x6040, 0, 0x00)  # (from anywhere: switch on disabled)
            for step in path[start]:
                await b.sdo.write(0x6040, 0, step)
            current = PowerState[start]
            assert bits[await state(b)] is current
            expected, command = current, command_of(controlword)
            step_ = transition(expected, command)
            while step_ is not None:  # (3 + 4: the same command leads on)
                expected = step_.target
                step_ = transition(expected, command)
            await b.sdo.write(0x6040, 0, controlword)
            assert bits[await state(b)] is expected, f"{start} + {controlword:#04x}"

    drive_run(scenario)
