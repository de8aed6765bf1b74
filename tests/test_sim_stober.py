"""The STOeBER MDS 5000 simulator against its manual (seed 004): the golden vectors frame by
frame, parameter groups and STOeBER addresses, the four SDO channels with the bit-31 quirk
and their axes, PDOs with type 254 replies, emergencies with the E82 table, guarding, LEDs,
each quirk on and off, and a master that parameterises it by groups, runs it, meets a fault
and acknowledges it."""

from __future__ import annotations

import asyncio
import struct
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

import pytest

from cobus.proto import Frame
from cobus.proto.sdo import SdoAbortCode, SdoAbortedError
from cobus.runtime import AsyncNetwork
from cobus.runtime.remote import AsyncRemoteNode, SdoChannel
from cobus.sim import SimulatedDevice, SimulationError, UnknownFaultError
from cobus.sim.stober import EVENTS, STATES, StoberMds5000, parameter_index
from tests.golden import Case, load
from tests.test_sim_zapi import case_id, replay
from tests.util import simulate

NODE = 1
EMCY, TPDO1, RPDO1 = 0x81, 0x181, 0x201
SAVE = bytes.fromhex("73617665")


def make_stober(net: AsyncNetwork, case: Case) -> SimulatedDevice:
    quirks = {case.settings["quirk"]: True} if "quirk" in case.settings else None
    return StoberMds5000(net, int(case.settings.get("node", NODE)), quirks=quirks)


async def _motor_temperature_fault(net: AsyncNetwork, sim: Any) -> None:
    """The case prints the two emergencies: a motor temperature fault, then its acknowledge
    (at the terminal: no bus frame) once the motor has cooled down."""
    sim.inject("motor_overtemperature")
    await net.sleep(0.05)
    sim.inject("motor_overtemperature", active=False)
    assert sim.acknowledge()


STOBER_CASES = [c.name for c in load("stober-mds5000")]
STOBER_ACTIONS = {STOBER_CASES[-1]: _motor_temperature_fault}


@pytest.mark.parametrize("title", STOBER_CASES, ids=case_id)
def test_golden_vectors(title: str) -> None:
    replay("stober-mds5000", title, make_stober, STOBER_ACTIONS)


# ---------------------------------------------------------------------------- helpers
class Rig:
    def __init__(self, net: AsyncNetwork, drive: StoberMds5000) -> None:
        self.net = net
        self.drive = drive
        self.frames: list[tuple[float, Frame]] = []
        net.subscribe_all(lambda frame, now: self.frames.append((round(now, 6), frame)))
        self.master: AsyncRemoteNode = net.add_remote(NODE)
        self.sdo: SdoChannel = self.master.sdo

    def on(self, cob_id: int, since: float = -1.0) -> list[Frame]:
        return [f for t, f in self.frames if f.cob_id == cob_id and t >= since]

    async def settle(self) -> None:
        for _ in range(4):
            await asyncio.sleep(0)

    async def read(self, index: int, sub: int = 0, *, signed: bool = False) -> int:
        return int.from_bytes(await self.sdo.upload(index, sub), "little", signed=signed)

    async def write(self, index: int, sub: int, value: int, size: int = 4) -> None:
        await self.sdo.download(index, sub, value.to_bytes(size, "little", signed=value < 0))

    async def abort(self, coro: Awaitable[Any]) -> int:
        with pytest.raises(SdoAbortedError) as err:
            await coro
        return int(err.value.code)

    async def nmt(self, command: str) -> None:
        self.net.nmt.send(command, NODE)
        await self.settle()


def run(scenario: Callable[[Rig], Awaitable[Any]], **options: Any) -> Any:
    async def main() -> Any:
        async with AsyncNetwork() as net:
            drive = StoberMds5000(net, NODE, **options)
            rig = Rig(net, drive)
            drive.start()
            await rig.settle()
            return await scenario(rig)

    return simulate(main())


def entry(coordinate: str, bits: int = 0) -> int:
    index, sub = parameter_index(coordinate)
    return index << 16 | sub << 8 | bits


A180, D230, C230, C01, E08, E48 = (
    parameter_index(c)[0] for c in ("A180", "D230", "C230", "C01", "E08", "E48")
)


async def map_process_data(rig: Rig) -> None:
    """RPDO1 = A180 device control + D230 setpoint, TPDO1 = E08 n-Motor + E48 device state,
    written the drive's way (entries directly, bit lengths left to the drive)."""
    await rig.write(0x1600, 1, entry("A180"))
    await rig.write(0x1600, 2, entry("D230"))
    await rig.write(0x1A00, 1, entry("E08"))
    await rig.write(0x1A00, 2, entry("E48"))


# ---------------------------------------------------------------------------- parameters
def test_parameter_coordinates_map_to_indexes():
    assert parameter_index("A00") == (0x2000, 0)
    assert parameter_index("B00") == (0x2200, 0)
    assert parameter_index("C01") == (0x2401, 0)
    assert parameter_index("D00") == (0x2600, 0)
    assert parameter_index("E08") == (0x2808, 0)
    assert parameter_index("A225") == (0x20E1, 0)
    assert parameter_index("a225.3") == (0x20E1, 3)
    assert parameter_index("Z00") == (0x5200, 0)
    for bad in ("C", "1C01", "C01.x", "C600"):
        with pytest.raises(SimulationError, match=r"coordinate|number"):
            parameter_index(bad)


def test_stober_addresses_reach_the_communication_parameters():
    async def scenario(rig: Rig) -> dict[str, Any]:
        out: dict[str, Any] = {}
        a229 = parameter_index("A229")[0]
        out["A229.0"] = await rig.read(a229, 0)
        await rig.write(a229, 3, 250, 2)  # A229.3 is the event timer, 1800h sub 5
        out["1800/5"] = await rig.read(0x1800, 5)
        await map_process_data(rig)
        out["A225.1"] = await rig.read(parameter_index("A225")[0], 1)
        out["A237"] = await rig.read(parameter_index("A237")[0])  # RPDO1 length
        out["A241"] = await rig.read(parameter_index("A241")[0])  # TPDO1 length
        out["A244"] = await rig.read(parameter_index("A244")[0])
        out["ro"] = await rig.abort(rig.write(parameter_index("A237")[0], 0, 1, 1))
        out["A83"] = await rig.read(parameter_index("A83")[0])
        out["E52"] = await rig.read(parameter_index("E52")[0])
        return out

    assert run(scenario) == {
        "A229.0": 0x180,
        "1800/5": 250,
        "A225.1": entry("D230", 16),
        "A237": 4,
        "A241": 3,
        "A244": 0,
        "ro": SdoAbortCode.WRITE_READ_ONLY,
        "A83": NODE,
        "E52": 8000000,
    }


def test_identity_and_names_by_segmented_upload():
    async def scenario(rig: Rig) -> tuple[bytes, int, int, int, int]:
        name = await rig.sdo.upload(0x1008)
        return (
            name,
            await rig.read(0x1000),
            await rig.read(0x1018, 1),
            await rig.read(0x1018, 2),
            await rig.read(0x1010, 0),
        )

    assert run(scenario, rated_power=2.2) == (b"MDS 5xxx", 0x00020192, 0xB9, 22, 1)


def test_save_values_survive_a_power_cycle_unsaved_do_not(tmp_path: Path):
    async def scenario(rig: Rig) -> tuple[int, int]:
        await rig.write(C01, 0, 2500, 2)
        await rig.write(parameter_index("A11")[0], 1, 2, 1)  # channel 1 edits axis 2
        await rig.write(C01, 0, 1200, 2)
        await rig.sdo.download(0x1010, 1, SAVE)
        await rig.write(C01, 0, 900, 2)  # axis 2, not saved
        rig.drive.inject("power_loss")
        rig.drive.inject("power_return")
        await rig.settle()
        axis2 = await rig.read(C01)
        await rig.write(parameter_index("A11")[0], 1, 1, 1)
        return axis2, await rig.read(C01)

    assert run(scenario, storage=tmp_path / "mds.json") == (1200, 2500)


# ---------------------------------------------------------------------------- SDO channels
def test_sdo_channel_2_with_bit_31_takes_effect_at_reset_communication():
    async def scenario(rig: Rig) -> list[Any]:
        await rig.write(0x1201, 1, 0x80000641)
        await rig.write(0x1201, 2, 0x800005C1)
        out: list[Any] = [sorted(rig.drive.sdo_channels)]
        await rig.nmt("reset_communication")
        out.append(rig.drive.sdo_channels.get(2))
        channel2 = SdoChannel(rig.net, NODE, None, rx_cob_id=0x641, tx_cob_id=0x5C1)
        out.append(await channel2.upload(0x1000))
        return out

    assert run(scenario) == [[1], (0x641, 0x5C1), struct.pack("<I", 0x00020192)]


def test_sdo_channel_quirks_switched_off_follow_cia():
    async def scenario(rig: Rig) -> list[Any]:
        await rig.write(0x1201, 1, 0x80000641)  # CiA: bit 31 = not valid
        await rig.write(0x1201, 2, 0x800005C1)
        await rig.settle()
        out: list[Any] = [sorted(rig.drive.sdo_channels)]
        await rig.write(0x1201, 1, 0x00000641)
        await rig.write(0x1201, 2, 0x000005C1)
        await rig.settle()
        out.append(rig.drive.sdo_channels.get(2))  # at once
        return out

    quirks = {"sdo_channel_bit31_enables": False, "sdo_ids_at_reset": False}
    assert run(scenario, quirks=quirks) == [[1], (0x641, 0x5C1)]


def test_new_sdo_ids_at_once_without_the_reset_quirk():
    async def scenario(rig: Rig) -> Any:
        await rig.write(0x1201, 1, 0x80000641)
        await rig.write(0x1201, 2, 0x800005C1)
        await rig.settle()
        return rig.drive.sdo_channels.get(2)

    assert run(scenario) is None  # waits for reset communication
    assert run(scenario, quirks={"sdo_ids_at_reset": False}) == (0x641, 0x5C1)


def test_stop_then_pre_operational_activates_and_the_bare_function_code_adds_the_node():
    async def scenario(rig: Rig) -> tuple[int, Any, Any]:
        default = await rig.read(0x1202, 1)
        await rig.write(0x1202, 1, 0x80000640)  # function code 640h: plus the node-ID
        await rig.write(0x1202, 2, 0x800005C0)
        await rig.nmt("stop")
        stopped = dict(rig.drive.sdo_channels)
        await rig.nmt("enter_preoperational")
        return default, stopped, rig.drive.sdo_channels.get(3)

    default, stopped, channel3 = run(scenario)
    assert default == 0x640 and stopped == {} and channel3 == (0x641, 0x5C1)


def test_each_channel_edits_the_axis_its_a11_element_names():
    async def scenario(rig: Rig) -> list[int]:
        a11 = parameter_index("A11")[0]
        await rig.write(0x1201, 1, 0x80000641)
        await rig.write(0x1201, 2, 0x800005C1)
        await rig.nmt("reset_communication")
        ch2 = SdoChannel(rig.net, NODE, None, rx_cob_id=0x641, tx_cob_id=0x5C1)
        await ch2.download(a11, 2, b"\x02")  # channel 2 edits axis 2
        await ch2.download(C01, 0, (1000).to_bytes(2, "little"))
        on_axis_2 = int.from_bytes(await ch2.upload(C01), "little")
        on_axis_1 = await rig.read(C01)
        with pytest.raises(SdoAbortedError) as err:
            await ch2.download(E08, 0, b"\x01\x00")  # read-only on every axis
        return [on_axis_2, on_axis_1, err.value.code, rig.drive.status()["setpoint_rpm"]]

    assert run(scenario) == [1000, 3000, SdoAbortCode.WRITE_READ_ONLY, 0]


def test_no_sdo_in_stopped():
    async def scenario(rig: Rig) -> None:
        await rig.nmt("stop")
        rig.net.send(Frame(0x601, bytes.fromhex("4000100000000000")))
        await rig.settle()
        assert rig.on(0x581) == []

    run(scenario)


# ---------------------------------------------------------------------------- PDOs
def test_type_254_answers_each_rpdo_with_the_tpdo_of_its_channel():
    async def scenario(rig: Rig) -> tuple[list[bytes], list[bytes]]:
        await map_process_data(rig)
        await rig.nmt("start")
        rig.net.send(Frame(RPDO1, struct.pack("<Hh", 1, 1500)))
        await rig.settle()
        first = [f.data for f in rig.on(TPDO1)]
        await rig.net.sleep(1.0)
        rig.net.send(Frame(RPDO1, struct.pack("<Hh", 1, 1500)))
        await rig.settle()
        return first, [f.data for f in rig.on(TPDO1)]

    first, later = run(scenario)
    assert first == [struct.pack("<hB", 0, 1)]  # sent at once: not yet turning, disabled
    assert later[-1] == struct.pack("<hB", 1500, 4)  # enabled, at speed after 0.5 s
    first, later = run(scenario, quirks={"pdo_reply_254": False})
    assert first == [] and later == []


def test_type_1_takes_the_rpdo_and_sends_the_tpdo_at_every_sync():
    async def scenario(rig: Rig) -> list[int]:
        await map_process_data(rig)
        await rig.write(0x1400, 2, 1, 1)
        await rig.write(0x1800, 2, 1, 1)
        await rig.nmt("start")
        rig.net.send(Frame(RPDO1, struct.pack("<Hh", 1, 300)))
        await rig.settle()
        counts = [len(rig.on(TPDO1)), rig.drive.status()["setpoint_rpm"]]
        for _ in range(3):
            rig.net.send(Frame(0x80))
            await rig.net.sleep(0.01)
        counts += [len(rig.on(TPDO1)), rig.drive.status()["setpoint_rpm"]]
        return counts

    assert run(scenario) == [0, 0, 3, 300]


def test_function_code_cob_id_quirk():
    async def scenario(rig: Rig) -> tuple[int, int, list[Frame]]:
        stored = await rig.read(0x1800, 1)
        await map_process_data(rig)
        code = 0
        try:
            await rig.write(0x1800, 1, 0x180)
        except SdoAbortedError as exc:
            code = int(exc.code)
        await rig.nmt("start")
        rig.net.send(Frame(RPDO1, struct.pack("<Hh", 0, 0)))
        await rig.settle()
        return stored, code, rig.on(TPDO1)

    stored, code, frames = run(scenario)
    assert stored == 0x180 and code == 0 and len(frames) == 1
    stored, code, frames = run(scenario, quirks={"function_code_cob_ids": False})
    assert stored == 0x181 and code == SdoAbortCode.INVALID_VALUE and len(frames) == 1


def test_pdo_parameter_quirks_switched_off():
    async def scenario(rig: Rig) -> list[int]:
        async def code(coro: Awaitable[Any]) -> int:
            try:
                await coro
            except SdoAbortedError as exc:
                return int(exc.code)
            return 0

        return [
            await code(rig.write(0x1800, 3, 100, 2)),  # inhibit while valid
            await code(rig.write(0x1800, 2, 255, 1)),  # type 255
            await code(rig.write(0x1600, 1, entry("D230"))),  # mapping while valid
            await code(rig.sdo.download(C01, 0, (2500).to_bytes(4, "little"))),  # 4 bytes
        ]

    assert run(scenario) == [0, SdoAbortCode.INVALID_VALUE, 0, 0]
    off = dict.fromkeys(
        (
            "pdo_params_while_valid",
            "transmission_types_limited",
            "direct_pdo_mapping",
            "padded_expedited_writes",
        ),
        False,
    )
    assert run(scenario, quirks=off) == [
        SdoAbortCode.INVALID_VALUE,
        0,
        SdoAbortCode.PARAMETER_INCOMPATIBLE,
        SdoAbortCode.LENGTH_TOO_HIGH,
    ]


def test_short_rpdo_writes_what_it_covers():
    async def scenario(rig: Rig) -> tuple[int, int]:
        await map_process_data(rig)
        await rig.write(0x1400, 2, 1, 1)  # applied at SYNC: no reply TPDO to muddle the test
        await rig.write(D230, 0, 700, 2)
        await rig.nmt("start")
        rig.net.send(Frame(RPDO1, b"\x01\x00\x05"))  # A180 and half of D230
        rig.net.send(Frame(0x80))
        await rig.settle()
        return await rig.read(A180), await rig.read(D230)

    assert run(scenario) == (1, 700)
    assert run(scenario, quirks={"partial_rpdos": False}) == (0, 700)


# ---------------------------------------------------------------------------- faults and EMCY
def test_fault_emergency_and_acknowledge_by_a180():
    async def scenario(rig: Rig) -> list[Any]:
        await rig.nmt("start")
        await rig.write(D230, 0, 1000, 2)
        await rig.write(A180, 0, 1, 2)  # enable
        await rig.net.sleep(1.0)
        out: list[Any] = [rig.drive.status()["speed_rpm"], await rig.read(0x1002)]
        rig.drive.inject("event", number=44, cause=3)
        await rig.settle()
        out.append(await rig.read(E48))  # fault reaction active
        await rig.net.sleep(0.2)
        out.append(await rig.read(E48))  # fault, stopped
        out.append(await rig.read(0x1001))
        await rig.write(A180, 0, 1 | 4, 2)
        out.append(await rig.read(E48))  # cause still there
        rig.drive.inject("event", number=44, active=False)
        await rig.write(A180, 0, 1, 2)
        await rig.write(A180, 0, 1 | 4, 2)
        await rig.net.sleep(0.02)
        out.append(await rig.read(E48))  # acknowledged, enabled again
        out.append([f.data for f in rig.on(EMCY)])
        return out

    assert run(scenario) == [
        1000.0,
        4,
        6,
        7,
        0x01,
        7,
        4,
        [bytes.fromhex("0090012C03000000"), bytes.fromhex("0000001E00000000")],
    ]


def test_emcy_quirks_generic_bit_and_stopped():
    async def scenario(rig: Rig) -> list[bytes]:
        await rig.nmt("stop")
        rig.drive.inject("motor_overtemperature")
        await rig.settle()
        return [f.data for f in rig.on(EMCY)]

    assert run(scenario) == [bytes.fromhex("1043082900000000")]
    assert run(scenario, quirks={"emcy_in_stopped": False}) == []
    off = {"emcy_without_generic_bit": False}
    assert run(scenario, quirks=off) == [bytes.fromhex("1043092900000000")]


def test_overload_and_overspeed_events():
    async def scenario(rig: Rig) -> list[Any]:
        await rig.write(A180, 0, 1, 2)
        await rig.write(C230, 0, 120, 2)
        rig.drive.inject("overload", load=100)  # below M-max
        await rig.net.sleep(0.1)
        out: list[Any] = [rig.drive.event]
        rig.drive.inject("overload", load=130)
        await rig.net.sleep(0.1)
        out.append(rig.drive.event)
        rig.drive.inject("overload", load=0)
        await rig.write(A180, 0, 1 | 4, 2)
        await rig.write(A180, 0, 0, 2)
        await rig.write(C01, 0, 500, 2)
        rig.drive.speed = 2000.0  # driven faster by the load
        await rig.net.sleep(0.02)
        out.append(rig.drive.event)
        out.append(rig.drive.status()["event_text"])
        return out

    assert run(scenario) == [30, 47, 56, "overspeed"]


def test_life_guarding_loss_is_event_52_and_pre_operational():
    async def scenario(rig: Rig) -> list[Any]:
        await rig.write(0x100C, 0, 100, 2)
        await rig.write(0x100D, 0, 3, 1)
        await rig.nmt("start")
        for _ in range(3):
            rig.net.send(Frame(0x701, rtr=True))
            await rig.net.sleep(0.1)
        replies = [f.data for f in rig.on(0x701) if not f.rtr][1:]
        out: list[Any] = [replies, rig.drive.leds()]
        await rig.net.sleep(0.5)
        out += [rig.drive.status()["state"], [f.data for f in rig.on(EMCY)], rig.drive.leds()]
        return out

    replies, leds, state, emcys, after = run(scenario)
    assert replies == [b"\x05", b"\x85", b"\x05"] and leds == ("on", "off")
    assert state == "pre_operational" and after == ("blinking", "double flash")
    assert emcys == [bytes.fromhex("0081103401000000")]


def test_heartbeat_sync_timeout_led_and_ignored_sync():
    async def scenario(rig: Rig) -> list[Any]:
        await rig.write(0x1017, 0, 100, 2)
        await rig.write(0x1006, 0, 20000)  # 20 ms cycle: the SYNC timeout
        rig.net.sync.start(0.02)
        await rig.net.sleep(0.2)
        out: list[Any] = [len(rig.on(0x701)), rig.drive.leds()[1]]
        rig.net.sync.stop()
        await rig.net.sleep(0.2)
        out.append(rig.drive.leds()[1])
        await map_process_data(rig)
        await rig.write(0x1800, 2, 1, 1)  # TPDO1 at every SYNC
        await rig.nmt("start")
        rig.net.send(Frame(0x80))
        await rig.settle()
        out.append(len(rig.on(TPDO1)))
        await rig.write(0x1005, 0, 0x7FF)  # "ignore SYNC"
        rig.net.send(Frame(0x80))
        await rig.settle()
        out.append(len(rig.on(TPDO1)))
        return out

    beats, running, lost, synced, ignored = run(scenario)
    assert beats >= 2 and running == "off" and lost == "triple flash"
    assert (synced, ignored) == (1, 1)


# ---------------------------------------------------------------------------- checks
def test_options_and_faults_are_checked():
    async def main() -> None:
        async with AsyncNetwork() as net:
            with pytest.raises(SimulationError, match="A83"):
                StoberMds5000(net, 0)
            with pytest.raises(SimulationError, match="16 characters"):
                StoberMds5000(net, 2, device_name="MDS 5000 with a long name")
            with pytest.raises(SimulationError, match="ramp"):
                StoberMds5000(net, 2, ramp=0)
            drive = StoberMds5000(net, 2)
            drive.start()
            with pytest.raises(SimulationError, match="already used"):
                StoberMds5000(net, 2).start()
            with pytest.raises(SimulationError, match="E82 event 43"):
                drive.inject("event", number=43)
            with pytest.raises(UnknownFaultError, match="motor_overtemperature"):
                drive.inject("flood")
            assert drive.status()["device_state"] == STATES[1]
            assert EVENTS[41] == ("motor temperature", 0x4310, 0x08)

    simulate(main())


# ---------------------------------------------------------------------------- the application
def test_parameterise_by_groups_run_fault_acknowledge():
    """Chapter 10 with a master: parameters by group, save, power on again (boot-up), NMT
    start, setpoints in RPDO1 answered by TPDO1, a motor temperature fault, acknowledge."""

    async def scenario(rig: Rig) -> dict[str, Any]:
        out: dict[str, Any] = {}
        await rig.write(C01, 0, 2500, 2)  # C01 n-Max
        await rig.write(C230, 0, 200, 2)  # C230 M-max
        await map_process_data(rig)
        await rig.write(parameter_index("A229")[0], 1, 254, 1)  # TPDO1 type 254
        await rig.sdo.download(0x1010, 1, SAVE)
        rig.drive.inject("power_loss")
        await rig.net.sleep(1.0)
        t0 = rig.net.time()
        rig.drive.inject("power_return")
        await rig.settle()
        out["boot"] = rig.on(0x701, since=t0)
        out["green"] = rig.drive.leds()[0]
        await rig.nmt("start")
        out["green_started"] = rig.drive.leds()[0]
        replies: list[bytes] = []
        rig.net.subscribe(TPDO1, lambda frame, now: replies.append(frame.data))

        async def command(control: int, speed: int, wait: float) -> tuple[int, int]:
            rig.net.send(Frame(RPDO1, struct.pack("<Hh", control, speed)))
            await rig.net.sleep(wait)
            rig.net.send(Frame(RPDO1, struct.pack("<Hh", control, speed)))
            await rig.settle()
            speed_now, state = struct.unpack("<hB", replies[-1])
            return speed_now, state

        out["run"] = await command(1, 3000, 1.5)  # clamped to n-Max
        rig.drive.inject("motor_overtemperature")
        out["fault"] = await command(1, 3000, 0.5)
        out["emcy"] = [f.data for f in rig.on(EMCY)]
        rig.drive.inject("motor_overtemperature", active=False)
        await command(0, 0, 0.01)
        out["ack"] = await command(4, 0, 0.01)
        out["again"] = await command(1, 1000, 1.0)
        out["emcy_after"] = [f.data for f in rig.on(EMCY)][1:]
        return out

    assert run(scenario) == {
        "boot": [Frame(0x701, b"\x00")],
        "green": "blinking",
        "green_started": "on",
        "run": (2500, 4),
        "fault": (0, 7),
        "emcy": [bytes.fromhex("1043082900000000")],
        "ack": (0, 1),
        "again": (1000, 4),
        "emcy_after": [bytes.fromhex("0000001E00000000")],
    }
