"""The parameter manager as a boot step of the master, on the simulated clock: a
factory-fresh CiA 402 servo is re-parameterised before it is started, a swapped one again, an
up-to-date one is left alone, and a refusal holds the node back with its reason; the blocking
manager and the EC motor's own SDO dialect."""

from __future__ import annotations

import asyncio
import textwrap
from pathlib import Path
from typing import Any

from cobus.blocks import Parameterise, ParameterManager
from cobus.blocks.param_manager import AsyncParameterManager
from cobus.device import export_eds
from cobus.master import (
    BlockingMaster,
    BootStepDone,
    BootStepFailed,
    Diagnostic,
    Master,
    MasterEvent,
    NodeState,
    loads_network,
)
from cobus.profiles.ecmotor import AsyncEcMotorDrive
from cobus.proto.sdo import SdoAbort, SdoAbortCode
from cobus.runtime import AsyncNetwork, Network
from cobus.sim.drive402 import SimulatedDrive402 as Servo
from cobus.sim.ecmotor import EcMotor

from .util import simulate

NETWORK = """
master: {node_id: 1, sync_period: 0}
nodes:
  servo: {node_id: 10, eds: servo.eds, mandatory: false, heartbeat_time: 100}
"""
PARAMETERS = """
parameters:
  profile velocity: 20000
  profile acceleration: 100000
  following error window: 500
"""


def write_files(tmp_path: Path, servo: Servo) -> None:
    (tmp_path / "servo.eds").write_text(export_eds(servo.od))
    (tmp_path / "servo.yml").write_text(f"eds: servo.eds\n{PARAMETERS}")


def test_the_master_re_parameterises_a_fresh_and_a_swapped_servo_before_starting_it(
    tmp_path: Path,
) -> None:
    async def main() -> tuple[list[str], dict[str, str], list[Any], int]:
        async with AsyncNetwork() as net:
            servo = Servo(net, 10, name="servo")
            servo.start()
            write_files(tmp_path, servo)
            master = Master(net, loads_network(NETWORK, base_dir=tmp_path))
            step = Parameterise(tmp_path / "servo.yml")
            master.add_boot_step("servo", step)
            events: list[str] = []
            order: list[Any] = []

            def listen(event: MasterEvent) -> None:
                if isinstance(event, BootStepDone | BootStepFailed):
                    events.append(str(event))
                    order.append(master.node(10).state)

            master.add_listener(listen)
            await master.boot(timeout=10)
            first = dict(master.node("servo").step_results)
            order.append(master.node(10).state)
            values = [servo.device.get(0x6081, 0), servo.device.get(0x6083, 0)]
            # an up-to-date node is left alone on a restart
            await master.restart_node("servo")
            # swapped for a factory-fresh one: it boots with its defaults
            servo.device.restore_defaults()
            servo.power_off()
            await asyncio.sleep(0.5)
            servo.power_on()
            await asyncio.sleep(3)
            order.append(master.node(10).state)
            order.append(values)
            order.append(step.status)
            await master.stop()
            return events, first, order, servo.device.get(0x6065, 0)

    events, first, order, window = simulate(main())
    assert events[0] == (
        "node 10: parameters: node 10 'servo': re-parameterised, 3 of 3 written, saved and verified"
    )
    assert events[1] == "node 10: parameters: node 10 'servo': up to date (3 parameters)"
    assert events[2] == events[0]  # the swapped servo
    assert first == {"parameters": events[0].removeprefix("node 10: parameters: ")}
    # the step ran while the node was being configured, before it was started
    assert order[0] is NodeState.CONFIGURING and order[1] is NodeState.OPERATIONAL
    assert order[-3] is NodeState.OPERATIONAL
    assert order[-2] == [20000, 100000]
    assert order[-1] == {10: events[2].removeprefix("node 10: parameters: ")}
    assert window == 500


def test_a_refused_parameter_holds_the_node_back_and_says_why(tmp_path: Path) -> None:
    def refuse(value: Any) -> None:
        raise SdoAbort(SdoAbortCode.VALUE_TOO_HIGH)

    async def main() -> tuple[list[str], Any, Any, str | None, dict[str, Any]]:
        async with AsyncNetwork() as net:
            servo = Servo(net, 10, name="servo")
            servo.start()
            servo.device.on_write(0x6083, 0, refuse)
            write_files(tmp_path, servo)
            master = Master(net, loads_network(NETWORK, base_dir=tmp_path))
            master.add_boot_step(None, Parameterise(tmp_path / "servo.yml"))
            events: list[str] = []
            master.add_listener(
                lambda e: events.append(str(e)) if isinstance(e, BootStepFailed) else None
            )
            await master.boot(timeout=10)
            await asyncio.sleep(1)
            node = master.node(10)
            result = (events, node.state, node.diagnostic, node.problem, node.summary())
            await master.stop()
            return result

    events, state, diagnostic, problem, summary = simulate(main())
    assert len(events) == 1
    assert events[0].startswith("node 10: parameters failed: node 10 'servo': failed, 1 problem")
    assert "[32] write 0x6083:00 Profile acceleration = 100000: refused" in events[0]
    assert state is NodeState.CONFIGURING  # held: never started
    assert diagnostic is Diagnostic.SDO_SYNTAX_ERROR
    assert problem is not None and problem.startswith("boot step 'parameters' failed: node 10")
    assert summary["steps"]["parameters"].startswith("failed: node 10 'servo': failed")


def test_the_blocking_manager_on_a_blocking_master_node(tmp_path: Path) -> None:
    with Network(simulated=True) as net:
        servo = net.run(_servo(net.aio))
        write_files(tmp_path, servo)
        master = BlockingMaster(net, loads_network(NETWORK, base_dir=tmp_path))
        master.boot(timeout=10)
        manager = ParameterManager(master, tmp_path / "servo.yml", node="servo")
        report = manager.diff()
        assert not report.ok and len(report.differences) == 3
        assert manager.apply().ok
        assert manager.diff().up_to_date
        snap, failures = manager.snapshot([0x6081, (0x6083, 0)])
        assert [p.value for p in snap] == [20000, 100000] and not failures
        master.stop()


async def _servo(net: AsyncNetwork) -> Servo:
    servo = Servo(net, 10, name="servo")
    servo.start()
    return servo


def test_the_ec_motor_is_parameterised_through_its_own_dialect() -> None:
    text = textwrap.dedent(
        """
        save: false
        parameters:
          "0x2020:01": {value: 1500, type: UNSIGNED32}
          "0x2021:01": {value: -4000, type: INTEGER32}
        """
    )

    async def main() -> tuple[Any, Any, list[int]]:
        async with AsyncNetwork() as net:
            motor = EcMotor(net, 3)
            motor.start()
            await asyncio.sleep(0.1)
            drive = AsyncEcMotorDrive(net, 3)
            from cobus.blocks import loads_parameters

            manager = AsyncParameterManager(drive, loads_parameters(text))
            report = await manager.apply()
            again = await manager.diff()
            return report, again, [await drive.read("u_tim"), await drive.read("P_lil")]

    report, again, values = simulate(main())
    assert report.ok and len(report.written) == 2 and report.saved is None
    assert again.up_to_date
    assert values == [1500, -4000]


ZAPI_NETWORK = """
master: {sync_period: 20}
nodes:
  zapi: {node_id: 8, eds: zapi.eds, mandatory: true, do_not_initialise: true}
"""


def test_a_swapped_factory_fresh_zapi_is_re_parameterised_and_saved_on_sub_0(
    tmp_path: Path,
) -> None:
    from cobus.device import MemoryStorage
    from cobus.sim.zapi import ZapiAce2

    async def main() -> tuple[list[str], list[int]]:
        async with AsyncNetwork() as net:
            zapi = ZapiAce2(net, 8)
            zapi.start()
            (tmp_path / "zapi.eds").write_text(export_eds(zapi.od))
            (tmp_path / "zapi.yml").write_text(
                "save: {subindex: 0}\nparameters: {main contactor voltage: 90}\n"
            )
            master = Master(net, loads_network(ZAPI_NETWORK, base_dir=tmp_path))
            master.add_boot_step("zapi", Parameterise(tmp_path / "zapi.yml"))
            details: list[str] = []
            master.add_listener(
                lambda e: details.append(e.detail) if isinstance(e, BootStepDone) else None
            )
            await master.boot(timeout=10)

            def voltage() -> int:
                assert zapi.device is not None
                return int(zapi.device.get(0x20A8, 0))

            values = [voltage()]
            zapi.power_off()
            await asyncio.sleep(0.2)
            zapi.power_on()  # power cycle: the saved value stays
            await asyncio.sleep(0.2)
            await master.restart_node("zapi")
            values.append(voltage())
            zapi.power_off()  # swapped for a factory-fresh one (no boot-up message: the
            zapi.storage = MemoryStorage()  # application restarts the node, e.g. on
            zapi.power_on()  # HandshakeLost)
            await asyncio.sleep(0.2)
            values.append(voltage())
            await master.restart_node("zapi")
            values.append(voltage())
            await master.stop()
            return details, values

    details, values = simulate(main())
    assert details == [
        "node 8 'zapi': re-parameterised, 1 of 1 written, saved and verified",
        "node 8 'zapi': up to date (1 parameter)",
        "node 8 'zapi': re-parameterised, 1 of 1 written, saved and verified",
    ]
    assert values == [90, 90, 100, 90]


def test_a_boot_step_whose_set_holds_a_command_holds_the_node_back(tmp_path: Path) -> None:
    async def main() -> tuple[list[str], Any, Any]:
        async with AsyncNetwork() as net:
            servo = Servo(net, 10, name="servo")
            servo.start()
            assert servo.device.get(0x6060, 0) != 3
            write_files(tmp_path, servo)
            (tmp_path / "servo.yml").write_text(
                f"eds: servo.eds\n{PARAMETERS}  modes of operation: 3\n"
            )
            master = Master(net, loads_network(NETWORK, base_dir=tmp_path))
            master.add_boot_step(None, Parameterise(tmp_path / "servo.yml"))
            events: list[str] = []
            master.add_listener(
                lambda e: events.append(str(e)) if isinstance(e, BootStepFailed) else None
            )
            await master.boot(timeout=10)
            result = (events, master.node(10).state, servo.device.get(0x6060, 0) == 3)
            await master.stop()
            return result

    events, state, written = simulate(main())
    assert len(events) == 1 and "the set writes 1 command(s)" in events[0]
    assert "0x6060:00 Modes of operation: the CiA 402 modes of operation" in events[0]
    assert state is NodeState.CONFIGURING  # held: never started
    assert not written


def test_the_ec_motor_s_commands_are_no_parameters() -> None:
    from cobus.blocks import loads_parameters
    from cobus.blocks.param_manager import CommandsInSetError

    text = 'save: false\nparameters:\n  "0x2024:00": {value: 1234, type: INTEGER16}\n'

    async def main() -> tuple[str, int]:
        async with AsyncNetwork() as net:
            motor = EcMotor(net, 3)
            motor.start()
            await asyncio.sleep(0.1)
            drive = AsyncEcMotorDrive(net, 3)
            manager = AsyncParameterManager(drive, loads_parameters(text))
            try:
                await manager.apply()
            except CommandsInSetError as exc:
                return str(exc), await drive.read("p_ven")
            raise AssertionError("applied")

    message, velocity = simulate(main())
    assert "0x2024:00: p_ven, the target velocity" in message
    assert velocity == 0
