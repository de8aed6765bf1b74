"""The CiA 402 drive from the master side against the simulated servo (cobus.sim), on the
simulated clock: every move's duration is checked against its motion profile's physics."""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from cobus.master import BlockingMaster
from cobus.profiles import (
    AsyncDrive402,
    Drive402,
    DriveFault,
    DriveStateError,
    DriveTimeoutError,
    OperationMode,
    PowerState,
    Quirks,
    Statusword,
)
from cobus.profiles.trajectory import SCurve, Trapezoid
from cobus.proto import Frame
from cobus.runtime import AsyncNetwork, Network
from cobus.sim import Rig, start_rig
from cobus.sim.blocking import BlockingRig
from tests.util import simulate

SERVO = """
bus: embedded
devices:
  - node: 10
    kind: cia402_drive
    name: servo
    options:
      negative_limit: -200000
      positive_limit: 200000
"""


@dataclass
class Bench:
    net: Network
    rig: BlockingRig
    drive: Drive402


@pytest.fixture
def bench() -> Iterator[Bench]:
    with Network(simulated=True) as net:
        rig = start_rig(net, Rig.loads(SERVO))
        drive = Drive402(net.add_remote(10))  # no EDS: the drive knows CiA 402's types
        yield Bench(net, rig, drive)


def trapezoid(distance: float, v: float, a: float, d: float) -> float:
    """The time a profile move takes: ramps at ``a`` and ``d``, cruise at ``v`` (or a
    triangle when the distance is too short to reach it)."""
    ramps = v * v / (2 * a) + v * v / (2 * d)
    if distance >= ramps:
        return v / a + v / d + (distance - ramps) / v
    peak = math.sqrt(2 * distance * a * d / (a + d))
    return peak / a + peak / d


def test_enable_goes_through_the_state_machine_and_disable_back(bench: Bench) -> None:
    drive = bench.drive
    drive.enable()
    assert drive.state is PowerState.OPERATION_ENABLED
    assert bench.rig.device(10).status()["state"] == "operation enabled"
    drive.disable()
    assert drive.read_statusword().state is PowerState.SWITCH_ON_DISABLED
    drive.set_state("switched_on")
    assert drive.read_statusword().state is PowerState.SWITCHED_ON
    drive.enable()
    assert str(drive.state) == "OPERATION_ENABLED"


def test_move_to_takes_the_time_of_its_trapezoid_and_ends_on_target(bench: Bench) -> None:
    net = bench.net
    drive = bench.drive
    drive.enable()
    for target, v, a in ((10_000, 20_000, 100_000), (12_000, 50_000, 100_000)):
        start, began = drive.read_position(), net.time()
        seen: list[Statusword] = []
        drive.move_to(target, velocity=v, acceleration=a, deceleration=a, progress=seen.append)
        took = net.time() - began
        expected = trapezoid(abs(target - start), v, a, a)
        # + the drive's position window time (10 ms) and a poll period of slack
        assert expected - 0.01 <= took <= expected + 0.03, (took, expected)
        assert abs(drive.read_position() - target) <= 20  # the position window 6067h
        assert seen and "set-point acknowledge" not in str(drive.status)
    # the second was a triangle (12000 - 10000 too short to reach 50 000 inc/s)
    assert trapezoid(2000, 50_000, 100_000, 100_000) == pytest.approx(2 * math.sqrt(0.02))


def test_move_by_is_relative_and_user_units_scale_everything() -> None:
    with Network(simulated=True) as net:
        start_rig(net, Rig.loads(SERVO))
        drive = Drive402(net.add_remote(10), scale=1000, unit="mm")
        drive.enable()
        drive.move_to(5, velocity=20, acceleration=100, deceleration=100)
        began = net.time()
        drive.move_by(-2, velocity=10)
        assert drive.read_position() == pytest.approx(3, abs=0.02)
        assert net.time() - began == pytest.approx(trapezoid(2, 10, 100, 100), abs=0.03)


def test_queued_set_points_run_one_after_the_other(bench: Bench) -> None:
    net = bench.net
    drive = bench.drive
    drive.enable()
    began = net.time()
    drive.move_to(20_000, 40_000, 200_000, 200_000, wait=False)
    drive.move_to(30_000, immediate=False, wait=False)  # buffered behind the first
    assert drive.read_position() < 20_000
    drive.wait_for_target()
    took = net.time() - began
    expected = trapezoid(20_000, 40_000, 200_000, 200_000) + trapezoid(
        10_000, 40_000, 200_000, 200_000
    )
    assert expected - 0.03 <= took <= expected + 0.05, (took, expected)  # two 1 ms-step ends
    assert abs(drive.read_position() - 30_000) <= 20


def test_homing_on_the_negative_limit_switch_sets_the_home_offset(bench: Bench) -> None:
    net = bench.net
    drive = bench.drive
    assert drive.homing_methods() == [1, 2, 17, 18, 35, 37]  # 60E3h
    drive.enable()
    seen: list[Statusword] = []
    began = net.time()
    drive.home(
        17, speeds=(100_000, 5_000), acceleration=1_000_000, offset=1000, progress=seen.append
    )
    # 200 000 increments to the switch at 100 000 inc/s (2.05 s with the ramp), braking past
    # it (0.1 s, 5 000 increments), then back off the switch at 5 000 inc/s (1 s)
    assert 3.1 <= net.time() - began <= 3.25
    assert "homing attained" in str(drive.read_statusword())
    assert abs(drive.read_position() - 1000) <= 20
    assert len(seen) > 10  # progress reported while it searched


def test_homing_refuses_a_method_the_drive_lacks_before_anything_moves(bench: Bench) -> None:
    drive = bench.drive
    drive.enable()
    with pytest.raises(DriveStateError, match=r"homing method 19 \(60E3h lists: 1, 2, 17"):
        drive.home(19)
    assert drive.read_mode() == OperationMode.PROFILE_POSITION  # the default 6060h, unchanged


def test_homing_that_does_not_finish_times_out_naming_what_was_awaited(bench: Bench) -> None:
    drive = bench.drive
    drive.enable()
    with pytest.raises(DriveTimeoutError, match=r"homing attained did not happen within 0\.2 s"):
        drive.home(18, speeds=(1000, 100), timeout=0.2)
    assert isinstance(DriveTimeoutError("x"), TimeoutError)


def test_a_following_error_is_a_drive_fault_with_code_text_emcy_and_state(bench: Bench) -> None:
    drive = bench.drive
    drive.enable()
    bench.rig.inject(10, "blocked_rotor")
    with pytest.raises(DriveFault) as caught:
        drive.move_to(50_000)
    fault = caught.value
    assert fault.code == 0x8611 and fault.text == "Following error"
    assert fault.state in (PowerState.FAULT, PowerState.FAULT_REACTION_ACTIVE)
    assert fault.emergency is not None and fault.emergency.code == 0x8611
    assert "drive 10 faulted while reaching the set-point 50000 inc: 0x8611 Following" in str(fault)
    with pytest.raises(DriveFault, match="fault_reset"):
        drive.enable()  # a faulted drive is not enabled behind the user's back
    bench.rig.inject(10, "free_rotor")
    drive.fault_reset()
    assert drive.state is PowerState.SWITCH_ON_DISABLED
    drive.enable()
    drive.move_to(1000)
    assert abs(drive.read_position() - 1000) <= 20


def test_a_fault_whose_cause_stays_is_not_reset(bench: Bench) -> None:
    net = bench.net
    drive = bench.drive
    drive.enable()
    bench.rig.inject(10, "overtemperature")
    net.sleep(0.05)
    with pytest.raises(DriveFault, match=r"resetting the fault .*0x4310 Excess temperature"):
        drive.fault_reset()


def test_velocity_torque_and_quick_stop(bench: Bench) -> None:
    drive = bench.drive
    drive.enable()
    drive.set_velocity(30_000, acceleration=300_000, deceleration=300_000)
    assert drive.read_velocity() == pytest.approx(30_000, abs=100)  # the velocity window
    assert drive.read_mode() == OperationMode.PROFILE_VELOCITY
    drive.quick_stop()
    assert drive.state is PowerState.SWITCH_ON_DISABLED  # 605Ah = 2: then switch on disabled
    assert drive.read_velocity() == 0
    drive.enable()
    drive.set_torque(100, slope=10_000)
    assert drive.read_mode() == OperationMode.PROFILE_TORQUE
    drive.halt()
    drive.disable()


def test_moves_need_an_enabled_drive_and_unknown_modes_are_named(bench: Bench) -> None:
    drive = bench.drive
    with pytest.raises(DriveStateError, match="cannot move: it is SWITCH_ON_DISABLED"):
        drive.move_to(100)
    with pytest.raises(DriveStateError, match="does not support VELOCITY"):
        drive.set_mode("velocity")
    with pytest.raises(ValueError, match="the modes are 0 NO_MODE"):
        drive.set_mode(42)


def test_a_drive_the_master_manages_uses_its_process_image() -> None:
    with Network(simulated=True) as net:
        start_rig(net, "thesis")
        master = BlockingMaster(net, "examples/networks/thesis.yml")
        master.boot(timeout=10)
        drive = Drive402(master, "servo")  # RPDO4: controlword + target velocity
        drive.enable()
        assert master.outputs["servo.cw"] == 0x0F  # the controlword went by RPDO
        drive.set_velocity(20_000)
        assert master.outputs["servo.target"] == 20_000
        master.sleep(0.1)
        assert master.inputs["servo.velocity"] == pytest.approx(20_000, abs=100)
        drive.disable()


def test_the_async_drive_has_the_same_methods() -> None:
    async def main() -> float:
        async with AsyncNetwork() as net:
            rig = Rig.loads(SERVO)
            await rig.start(net)
            drive = AsyncDrive402(net.add_remote(10), scale=10)
            await drive.enable()
            await drive.move_to(100)
            position = await drive.read_position()
            await rig.stop()
            return position

    assert simulate(main()) == pytest.approx(100, abs=2)


def test_the_mode_is_read_from_the_drive_not_trusted_from_before_a_reset(bench: Bench) -> None:
    net, drive = bench.net, bench.drive
    drive.enable()
    drive.set_velocity(20_000)
    drive.disable()
    net.nmt.reset_node(10)  # 6060h back to its default, profile position
    net.sleep(0.5)
    drive.enable()
    drive.set_velocity(20_000)
    assert drive.read_mode() == OperationMode.PROFILE_VELOCITY
    assert drive.read_velocity() == pytest.approx(20_000, abs=100)


def test_halt_returns_once_the_motor_stands(bench: Bench) -> None:
    drive = bench.drive
    with pytest.raises(DriveStateError, match="cannot halt: it is SWITCH_ON_DISABLED"):
        drive.halt()
    drive.enable()
    drive.set_velocity(30_000, acceleration=100_000, deceleration=100_000)
    began = bench.net.time()
    drive.halt()
    assert abs(drive.read_velocity()) <= 20  # the velocity threshold 606Fh
    assert bench.net.time() - began == pytest.approx(0.3, abs=0.03)  # 30 000 at 100 000/s²
    drive.set_velocity(-10_000)  # Halt is cleared by the next command
    assert drive.read_velocity() == pytest.approx(-10_000, abs=100)
    drive.halt()
    drive.move_to(0)  # a mode change after a halt: Halt cleared first
    assert abs(drive.read_position()) <= 20


def test_a_drive_that_changes_modes_only_when_switched_on_is_enabled_again() -> None:
    with Network(simulated=True) as net:
        start_rig(net, Rig.loads(SERVO))
        quirks = Quirks(mode_change_state=PowerState.SWITCHED_ON, halt_during_mode_change=True)
        drive = Drive402(net.add_remote(10), quirks=quirks)
        drive.enable()
        drive.set_velocity(20_000)
        assert drive.state is PowerState.OPERATION_ENABLED
        assert drive.read_velocity() == pytest.approx(20_000, abs=100)


def test_bad_arguments_are_refused_before_anything_is_sent(bench: Bench) -> None:
    drive = bench.drive
    drive.enable()
    drive.move_to(100_000, wait=False)
    with pytest.raises(ValueError, match="velocity must be a finite number"):
        drive.set_velocity(float("nan"))
    assert drive.read_mode() == OperationMode.PROFILE_POSITION  # the move goes on
    for call, error, text in (
        (lambda: drive.move_to(float("inf")), ValueError, "position must be a finite"),
        (lambda: drive.move_to("100"), TypeError, "position must be a number"),
        (lambda: drive.move_to(True), TypeError, "position must be a number, not True"),
        (lambda: drive.move_to(3e9), ValueError, "beyond INTEGER32"),
        (lambda: drive.move_to(5000, velocity=0.2), ValueError, "0 increments at scale 1"),
        (lambda: drive.move_to(5000, velocity=-5), ValueError, "must be above 0"),
        (lambda: drive.set_state("bogus"), ValueError, "the states are NOT_READY"),
        (lambda: drive.set_mode(True), ValueError, "the modes are 0 NO_MODE"),
        (lambda: drive.home(True), TypeError, "homing method must be an integer"),
        (lambda: drive.set_torque(1.9), TypeError, "torque must be an integer"),
        (lambda: drive.wait_for_target(timeout=float("nan")), ValueError, "timeout must be"),
    ):
        with pytest.raises(error, match=text):
            call()
    with pytest.raises(ValueError, match="poll must be above 0 s"):
        Drive402(bench.net.add_remote(11), poll=0)


def test_objects_are_read_and_written_as_their_types(bench: Bench) -> None:
    drive = bench.drive
    drive.enable()
    drive.move_to(-5000)
    assert drive.read(0x6062) == pytest.approx(-5000, abs=20)  # INTEGER32, signed
    assert isinstance(drive.read(0x6074), int)  # INTEGER16
    drive.write(0x6072, 0, 1500)  # UNSIGNED16
    drive.write(0x607D, 1, -100_000)  # INTEGER32 sub-object of a record
    with pytest.raises(ValueError, match="give the node its EDS"):
        drive.read(0x2000)  # a manufacturer object, no EDS
    drive.close()
    bench.net.remove_remote(10)
    with_eds = Drive402(bench.net.add_remote(10, "examples/networks/servo.eds"))
    assert with_eds.read(0x2000) == pytest.approx(250, abs=100)  # motor temperature, 0.1 °C


def test_a_managed_drive_before_the_network_runs_goes_by_sdo_and_close_detaches() -> None:
    with Network(simulated=True) as net:
        start_rig(net, "thesis")
        master = BlockingMaster(net, "examples/networks/thesis.yml")
        listeners = len(master.aio._tpdo_listeners)
        drive = Drive402(master, "servo")
        net.sleep(0.5)  # the servo booted to pre-operational; the master sends no RPDO yet
        drive.enable()  # so the controlword goes by SDO
        assert drive.state is PowerState.OPERATION_ENABLED
        drive.close()
        assert len(master.aio._tpdo_listeners) == listeners


def csp_bench(net: Network) -> tuple[Drive402, BlockingRig]:
    rig = start_rig(net, Rig.loads(SERVO))
    node = net.add_remote(10)
    node.rpdo.read()  # RPDO3 maps controlword + target position: the cyclic set-point
    node.nmt.start()
    return Drive402(node), rig


def test_csp_follows_a_trapezoid_fed_every_1_ms_sync() -> None:
    with Network(simulated=True) as net:
        drive, rig = csp_bench(net)
        net.sync.start(0.001)
        drive.enable()
        start = drive.read_position()
        move = Trapezoid(start, start + 50_000, velocity=40_000, acceleration=200_000)
        assert move.duration == pytest.approx(trapezoid(50_000, 40_000, 200_000, 200_000))
        worst: list[float] = [0.0]

        def watch(fraction: float) -> None:  # on the loop: the simulated drive, directly
            error = abs(rig.aio.devices[10].status()["following_error"])
            worst[0] = max(worst[0], error)

        began = net.time()
        drive.follow(move, progress=watch)
        # fed one SYNC ahead, taken at the next SYNC: the end comes two periods later
        assert net.time() - began == pytest.approx(move.duration, abs=0.005)
        assert abs(drive.read_position() - (start + 50_000)) <= 20
        assert worst[0] < 500  # the drive followed: far inside its following error window
        assert move.position(move.duration / 2) == pytest.approx(start + 25_000)


def test_csp_refuses_what_cannot_work_and_reports_a_fault_on_the_way() -> None:
    with Network(simulated=True) as net:
        drive, rig = csp_bench(net)
        drive.enable()
        with pytest.raises(DriveStateError, match="the trajectory starts at 1000"):
            drive.follow(Trapezoid(1000, 2000, 1000, 1000))
        with pytest.raises(DriveTimeoutError, match=r"no SYNC came within 0\.3 s"):
            drive.follow(Trapezoid(0, 2000, 1000, 1000), timeout=0.3)
        net.sync.start(0.001)
        rig.inject(10, "blocked_rotor")
        with pytest.raises(DriveFault, match="following a trajectory: 0x8611 Following error"):
            drive.follow(Trapezoid(0, 100_000, 50_000, 500_000))
    with Network(simulated=True) as net:
        start_rig(net, Rig.loads(SERVO))
        drive = Drive402(net.add_remote(10))  # no RPDO mapping known
        drive.enable()
        with pytest.raises(DriveStateError, match="no RPDO maps the target position 607Ah:00"):
            drive.follow(Trapezoid(0, 1000, 1000, 1000))
    with pytest.raises(ValueError, match="velocity must be above 0"):
        Trapezoid(0, 1, 0, 1)


SYNC_NETWORK = """
master: {sync_period: 20}
nodes:
  servo:
    node_id: 10
    eds: servo.eds
    rpdo1: {enabled: false}
    rpdo2: {enabled: false}
    rpdo3: {mapping: [controlword, target_position], transmission_type: 1}
    rpdo4: {enabled: false}
"""


def test_controlword_edges_survive_a_synchronous_rpdo() -> None:
    """Through an RPDO sent at the SYNC, every controlword value reaches the drive: a
    homing start edge, a fault-reset pulse, a new set-point after homing."""
    from cobus.master import loads_network

    examples = Path(__file__).resolve().parent.parent / "examples" / "networks"
    with Network(simulated=True) as net:
        rig = start_rig(net, Rig.loads(SERVO))
        master = BlockingMaster(net, loads_network(SYNC_NETWORK, base_dir=examples))
        master.boot(timeout=10)
        drive = Drive402(master, "servo")
        drive.enable()
        drive.home(37)
        began = net.time()
        drive.home(17, speeds=(100_000, 5_000), acceleration=1_000_000, offset=0)
        assert net.time() - began > 3.0  # it really went to the switch and back
        drive.move_to(5000)
        assert abs(drive.read_position() - 5000) <= 20
        rig.inject(10, "drive_fault", code=0x7305)
        net.sleep(0.1)
        drive.fault_reset()  # the pulse lasts until the drive took it
        assert drive.state is PowerState.SWITCH_ON_DISABLED


def test_follow_reports_errors_of_its_feeding_and_samples_every_period() -> None:
    class Ramp:  # a trajectory that starts moving at once: 10 000 increments/s
        start, end, duration = 0.0, 500.0, 0.05

        def position(self, t: float) -> float:
            return min(10_000 * t, 500.0)

    with Network(simulated=True) as net:
        drive, _rig = csp_bench(net)
        frames: list[Frame] = []
        net.aio.subscribe(0x40A, lambda frame, now: frames.append(frame))  # RPDO3
        net.sync.start(0.001)
        drive.enable()
        drive.follow(Ramp())
        targets = [int.from_bytes(f.data[2:6], "little", signed=True) for f in frames]
        steps = [b - a for a, b in itertools.pairwise(targets) if a < 500]
        assert steps[0] == 0 and set(steps[1:]) == {10}  # the start, then every sample
        assert targets[-1] == 500

        def broken(fraction: float) -> None:
            raise RuntimeError("the operator panel crashed")

        with pytest.raises(RuntimeError, match="the operator panel crashed"):
            drive.follow(Trapezoid(500, 1000, 10_000, 100_000), progress=broken)


def test_cyclic_synchronous_velocity_and_torque() -> None:
    with Network(simulated=True) as net:
        drive, _rig = csp_bench(net)  # RPDO4: controlword + target velocity
        node = net.remotes[10]
        net.sync.start(0.001)
        drive.enable()
        # a velocity profile: up to 30 000 inc/s and back to rest, as a trapezoid's velocity
        move = Trapezoid(0, 30_000, velocity=30_000, acceleration=100_000)
        began = net.time()
        drive.follow(move, mode="velocity")
        assert net.time() - began == pytest.approx(move.duration, abs=0.01)
        assert abs(drive.read_velocity()) <= 100
        # the distance the velocities add up to: the trapezoid's (within a few cycles)
        assert drive.read_position() == pytest.approx(30_000, abs=300)

        # torque: remap RPDO1 to controlword + target torque (CiA 301 procedure)
        drive.disable()
        node.nmt.enter_preoperational()
        node.rpdo[1].clear()
        node.rpdo[1].add(0x6040, 0, 16)  # no EDS: the bit lengths are given
        node.rpdo[1].add(0x6071, 0, 16)
        node.rpdo[1].save()
        node.nmt.start()
        drive.enable()
        ramp = Trapezoid(0, 200, velocity=2000, acceleration=20_000)  # per mille of torque
        drive.follow(ramp, mode="torque")
        assert drive.read(0x6071) == 200
        with pytest.raises(ValueError, match="position, velocity, torque or interpolated"):
            drive.follow(ramp, mode="acceleration")


def test_interpolated_position_mode() -> None:
    with Network(simulated=True) as net:
        drive, _rig = csp_bench(net)
        node = net.remotes[10]
        node.nmt.enter_preoperational()
        node.rpdo[3].clear()  # controlword + interpolation data record 60C1h sub 1
        node.rpdo[3].add(0x6040, 0, 16)
        node.rpdo[3].add(0x60C1, 1, 32)
        node.rpdo[3].save()
        node.nmt.start()
        net.sync.start(0.002)
        drive.enable()
        move = SCurve(0, 20_000, 40_000, 200_000, 2_000_000)
        began = net.time()
        drive.follow(move, mode="interpolated")
        assert net.time() - began == pytest.approx(move.duration, abs=0.01)
        assert abs(drive.read_position() - 20_000) <= 20
        assert "interpolation active" in str(drive.read_statusword())  # bit 12, still held


def test_a_move_stopped_by_a_limit_switch_says_so_at_once(bench: Bench) -> None:
    drive = bench.drive
    drive.enable()
    began = bench.net.time()
    with pytest.raises(DriveStateError, match=r"stopped at a limit at 20[0-9]+ inc before"):
        drive.move_to(300_000, velocity=100_000)  # the switch is at 200 000
    assert bench.net.time() - began < 4.0  # not the 60 s timeout


def test_every_command_through_the_process_image_goes_out() -> None:
    """A controlword the image already holds is sent all the same: the drive may have been
    reset meanwhile and not have it."""
    with Network(simulated=True) as net:
        start_rig(net, "thesis")
        master = BlockingMaster(net, "examples/networks/thesis.yml")
        master.boot(timeout=10)
        drive = Drive402(master, "servo")
        frames: list[Frame] = []
        net.aio.subscribe(0x50A, lambda frame, now: frames.append(frame))  # RPDO4
        drive.write(0x6040, 0, 0x06)
        drive.write(0x6040, 0, 0x06)
        net.sleep(0.01)
        assert [f.data[:2] for f in frames] == [b"\x06\x00", b"\x06\x00"]
