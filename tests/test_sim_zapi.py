"""The ZAPI ACE2 simulator against the thesis (seed 000): its golden vectors frame by frame,
each quirk on and off, the motor model, the faults, and the PLC application of the thesis run
by a cobus master (SYNC 20 ms, start, handshake, 50 Hz clockwise, broken handshake,
acknowledge).

:func:`replay` also drives the golden vectors of the other simulated devices."""

from __future__ import annotations

import asyncio
import struct
from collections.abc import Awaitable, Callable, Mapping
from pathlib import Path
from typing import Any

import pytest

from cobus.proto import Frame
from cobus.proto.nmt import NmtState
from cobus.proto.sdo import SdoAbortCode, SdoAbortedError
from cobus.runtime import AsyncNetwork
from cobus.sim import SimulatedDevice, SimulationError, UnknownFaultError, UnknownQuirkError
from cobus.sim.zapi import ALARM_TEXTS, ZapiAce2
from tests.golden import Case, load
from tests.util import simulate

NODE = 8
TPDO1, TPDO2, TPDO4, RPDO1 = 0x188, 0x288, 0x488, 0x208
SAVE = bytes.fromhex("73617665")

Make = Callable[[AsyncNetwork, Case], SimulatedDevice]
Action = Callable[[AsyncNetwork, Any], Awaitable[None]]


# ---------------------------------------------------------------------------- golden vectors
async def settle(net: AsyncNetwork, log: list[Frame]) -> None:
    """Run until no frame is in flight (no virtual time passes)."""
    quiet = 0
    seen = len(log)
    while quiet < 4:
        await asyncio.sleep(0)
        quiet = quiet + 1 if len(log) == seen else 0
        seen = len(log)


def same(expected: Frame, actual: Frame, value_free: bool) -> bool:
    """Equal frames; with ``value_free`` only the identifier, DLC and (SDO) command bytes."""
    if not value_free:
        return expected == actual
    if (expected.cob_id, expected.dlc, expected.rtr) != (actual.cob_id, actual.dlc, actual.rtr):
        return False
    if 0x580 <= expected.cob_id <= 0x67F:  # SDO: command byte, index, sub-index
        return expected.data[:4] == actual.data[:4]
    return True


def replay(
    source: str,
    title: str,
    make: Make,
    actions: Mapping[str, Action] | None = None,
    checks: Mapping[str, Action] | None = None,
) -> None:
    """Play the cases of vectors file ``source`` up to the one named ``title`` on one simulated
    device (the documents number their examples in order: later ones read what earlier ones
    wrote) and compare the bus of that case with its steps, frame by frame and in order.

    The device is powered on first; its power-on frames open the first case. ``actions``
    (by case title) run before a case's frames: what the document does off the bus (a
    fault, an acknowledge); the frames they cause open the case. ``checks`` (by case title)
    run before a case too, for what a case states without printing frames; their frames are
    not part of the case."""
    cases = load(source)
    names = [c.name for c in cases]
    index = names.index(title)
    target = cases[index]

    async def main() -> tuple[list[Frame], list[Frame]]:
        async with AsyncNetwork() as net:
            log: list[Frame] = []
            net.subscribe_all(lambda frame, now: log.append(frame))
            sim = make(net, target)
            sim.start()
            await settle(net, log)

            async def play(case: Case, first: bool) -> int:
                """Play one case; returns where its own frames begin in the log."""
                begin = 0 if first else len(log)  # the power-on frames open the first case
                check = (checks or {}).get(case.name)
                if check is not None:
                    await check(net, sim)
                    await settle(net, log)
                    begin = len(log)
                action = (actions or {}).get(case.name)
                if action is not None:
                    await action(net, sim)
                    await settle(net, log)
                for step in case.steps:
                    if step.direction == ">":
                        net.send(step.frame)
                        await settle(net, log)
                return begin

            for n, case in enumerate(cases[:index]):
                await play(case, n == 0)
            begin = await play(target, index == 0)
            return [s.frame for s in target.steps], log[begin:]

    expected, seen = simulate(main())
    assert len(seen) == len(expected) and all(
        same(e, a, target.value_free) for e, a in zip(expected, seen, strict=True)
    ), f"{source}: {title}\nexpected {expected}\n     got {seen}"


def make_zapi(net: AsyncNetwork, case: Case) -> SimulatedDevice:
    quirks = {case.settings["quirk"]: True} if "quirk" in case.settings else None
    return ZapiAce2(net, int(case.settings.get("node", NODE)), quirks=quirks)


async def _toggle_case(net: AsyncNetwork, sim: Any) -> None:
    """The case prints no frames: the alternation is checked here, answered as the master must."""
    bytes3: list[int] = []

    def answer(frame: Frame, now: float) -> None:
        bytes3.append(frame.data[3])
        toggle = frame.data[3] >> 7
        net.send(Frame(RPDO1, struct.pack("<HHBBB", 0, (1 - toggle) << 15, 0, 0, 0)))

    sub = net.subscribe(TPDO1, answer)
    for _ in range(6):
        net.send(Frame(0x80))
        await asyncio.sleep(0.02)
    sub.cancel()
    assert bytes3 == [0x44, 0xC4] * 3
    assert sim.alarm == 0


ZAPI_CASES = [c.name for c in load("thesis-zapi")]
ZAPI_CHECKS: dict[str, Action] = {ZAPI_CASES[2]: _toggle_case}


def case_id(title: str) -> str:
    """A short test id of a case title."""
    return "-".join(title.split(":")[0].split()[:6])


@pytest.mark.parametrize("title", ZAPI_CASES, ids=case_id)
def test_golden_vectors(title: str) -> None:
    replay("thesis-zapi", title, make_zapi, checks=ZAPI_CHECKS)


# ---------------------------------------------------------------------------- helpers
class Rig:
    """A ZAPI controller and the test acting as its PLC, on one simulated network."""

    def __init__(self, net: AsyncNetwork, zapi: ZapiAce2) -> None:
        self.net = net
        self.zapi = zapi
        self.frames: list[tuple[float, Frame]] = []
        net.subscribe_all(lambda frame, now: self.frames.append((round(now, 6), frame)))
        self.master = net.add_remote(NODE)

    def on(self, cob_id: int, since: float = -1.0) -> list[Frame]:
        return [f for t, f in self.frames if f.cob_id == cob_id and t >= since]

    async def settle(self) -> None:
        await asyncio.sleep(0)
        await asyncio.sleep(0)
        await asyncio.sleep(0)

    def rpdo(
        self, speed: float, control: int, *, toggle: int = 0, ramp: int = 0, pedal: int = 0
    ) -> None:
        word = control | toggle << 15
        layout = "<HHBBH" if self.zapi.ramp_bytes == 2 else "<HHBBB"
        data = struct.pack(layout, round(speed * 100), word, pedal, 0, ramp)
        self.net.send(Frame(RPDO1, data))


def run(scenario: Callable[[Rig], Awaitable[Any]], **options: Any) -> Any:
    async def main() -> Any:
        async with AsyncNetwork() as net:
            zapi = ZapiAce2(net, NODE, **options)
            rig = Rig(net, zapi)
            zapi.start()
            await rig.settle()
            return await scenario(rig)

    return simulate(main())


class Plc:
    """The thesis's PLC program in small: answers every TPDO1 with the opposite toggle and
    the current command (speed, controlword bits, ramp)."""

    def __init__(self, rig: Rig) -> None:
        self.rig = rig
        self.speed = 0.0
        self.control = 0
        self.ramp = 0
        self.pedal = 0
        self.answering = True
        self.seen: list[bytes] = []
        rig.net.subscribe(TPDO1, self._on_tpdo1)

    def _on_tpdo1(self, frame: Frame, now: float) -> None:
        self.seen.append(frame.data)
        if self.answering:
            toggle = frame.data[3] >> 7
            self.rig.rpdo(
                self.speed, self.control, toggle=1 - toggle, ramp=self.ramp, pedal=self.pedal
            )

    @property
    def actual_speed(self) -> float:
        raw: int = struct.unpack_from("<h", self.seen[-1])[0]
        return raw / 100

    @property
    def statusword(self) -> int:
        value: int = struct.unpack_from("<H", self.seen[-1], 2)[0]
        return value


A16, ENABLE, ACK, CW, CCW = 1 << 1, 1 << 3, 1 << 4, 1 << 6, 1 << 7


async def start_with_sync(rig: Rig, period: float = 0.02) -> None:
    rig.net.sync.start(period)
    await rig.net.sleep(period * 2.5)
    rig.net.nmt.start(NODE)
    await rig.settle()


# ---------------------------------------------------------------------------- quirks
def test_no_bootup_quirk():
    async def scenario(rig: Rig) -> list[Frame]:
        rig.net.nmt.reset_node(NODE)
        await rig.settle()
        return rig.on(0x708)

    assert run(scenario) == []
    assert run(scenario, quirks={"no_bootup": False}) == [Frame(0x708, b"\x00")] * 2


def test_no_error_control_quirk():
    async def scenario(rig: Rig) -> list[Frame]:
        await rig.master.sdo.download(0x1017, 0, struct.pack("<H", 100))
        rig.net.send(Frame(0x708, rtr=True))
        await rig.net.sleep(0.35)
        return [f for f in rig.on(0x708) if not f.rtr]

    assert run(scenario) == []
    frames = run(scenario, quirks={"no_error_control": False})
    assert frames[0] == Frame(0x708, b"\x7f")  # the guarding reply (no boot-up: a quirk too)
    assert frames[1:] == [Frame(0x708, b"\x7f")] * 3  # heartbeat every 100 ms


def test_pdos_before_start_quirk():
    async def scenario(rig: Rig) -> tuple[int, int, int]:
        Plc(rig)
        await rig.net.sleep(0.55)
        before = len(rig.on(TPDO2)), len(rig.on(TPDO4))
        await start_with_sync(rig)
        t = rig.net.time()
        await rig.net.sleep(0.25)
        return before[0], before[1], len(rig.on(TPDO2, since=t))

    tpdo2, tpdo4, after = run(scenario)
    assert (tpdo2, tpdo4) == (5, 5) and after >= 2  # every 100 ms, before and after start
    tpdo2, tpdo4, after = run(scenario, quirks={"pdos_before_start": False})
    assert (tpdo2, tpdo4) == (0, 0) and after >= 2  # CiA 301: once operational


def test_sync_before_start_quirk():
    async def scenario(rig: Rig) -> tuple[str, int, int]:
        rig.net.nmt.start(NODE)  # no SYNC yet
        await rig.settle()
        state = rig.zapi.status()["state"]
        rig.net.sync.start(0.02)
        await rig.net.sleep(0.05)
        return state, rig.zapi.alarm, len(rig.on(TPDO1))

    assert run(scenario) == ("pre_operational", 248, 0)
    # without the quirk the controller waits for SYNC; the master must then answer at once
    state, alarm, tpdo1 = run(scenario, quirks={"sync_before_start": False})
    assert state == "operational" and tpdo1 == 1 and alarm == 248  # nobody answered


def test_handshake_quirk_checks_the_answer_the_toggle_still_alternates():
    async def scenario(rig: Rig) -> tuple[list[int], int, str]:
        await start_with_sync(rig)
        await rig.net.sleep(0.2)
        return [f.data[3] for f in rig.on(TPDO1)], rig.zapi.alarm, rig.zapi.status()["state"]

    toggles, alarm, state = run(scenario)
    assert toggles == [0x44] and alarm == 248 and state == "pre_operational"
    toggles, alarm, state = run(scenario, quirks={"handshake": False})
    assert toggles[:4] == [0x44, 0xC4, 0x44, 0xC4] and alarm == 0 and state == "operational"


def test_handshake_answered_keeps_running_and_a_wrong_answer_breaks_it():
    async def scenario(rig: Rig) -> tuple[int, int, list[int]]:
        plc = Plc(rig)
        await start_with_sync(rig)
        await rig.net.sleep(2.0)
        running = len(plc.seen)
        assert rig.zapi.alarm == 0 and rig.zapi.status()["handshake"] == "running"
        plc.answering = False
        rig.rpdo(0, 0, toggle=plc.seen[-1][3] >> 7)  # the same value instead of the opposite
        await rig.net.sleep(0.1)
        alarms = [f.data[0] for f in rig.on(TPDO2)]
        return running, rig.zapi.alarm, alarms

    running, alarm, alarms = run(scenario)
    assert running >= 99 and alarm == 248 and alarms[-1] == 248


def test_handshake_misses_forgive_late_answers():
    async def scenario(rig: Rig) -> int:
        plc = Plc(rig)
        await start_with_sync(rig)
        await rig.net.sleep(0.1)
        plc.answering = False
        await rig.net.sleep(0.03)  # one cycle without an answer
        plc.answering = True
        rig.rpdo(0, 0, toggle=1 - (plc.seen[-1][3] >> 7))
        await rig.net.sleep(0.2)
        return rig.zapi.alarm

    assert run(scenario, handshake_misses=1) == 0
    assert run(scenario) == 248


def test_sync_watchdog_trips_when_sync_stops():
    async def scenario(rig: Rig) -> tuple[int, float | None]:
        Plc(rig)
        await start_with_sync(rig)
        await rig.net.sleep(0.5)
        rig.net.sync.stop()
        stopped = rig.net.time()
        while rig.zapi.alarm == 0 and rig.net.time() < stopped + 1:
            await rig.net.sleep(0.01)
        return rig.zapi.alarm, rig.net.time() - stopped

    alarm, after = run(scenario)
    assert alarm == 248 and 0.08 <= after <= 0.12


def test_fault_to_preoperational_quirk():
    async def scenario(rig: Rig) -> tuple[str, bool]:
        Plc(rig)
        await start_with_sync(rig)
        rig.zapi.inject("alarm", code=17)
        await rig.settle()
        return rig.zapi.status()["state"], rig.zapi.power_stage_on

    assert run(scenario) == ("pre_operational", False)
    assert run(scenario, quirks={"fault_to_preoperational": False}) == ("operational", False)


def test_save_on_subindex_0_quirk_and_power_cycles():
    async def scenario(rig: Rig) -> tuple[int, int, int]:
        sdo = rig.master.sdo
        await sdo.download(0x20A8, 0, b"\x63\x00\x00\x00", size_indicated=False)
        rig.zapi.inject("power_loss")
        rig.zapi.inject("power_return")
        await rig.settle()
        unsaved = (await sdo.upload(0x20A8, 0))[0]
        await sdo.download(0x20A8, 0, b"\x63\x00\x00\x00", size_indicated=False)
        try:
            await sdo.download(0x1010, 0, SAVE)
        except SdoAbortedError as exc:
            return unsaved, -int(exc.code), 0
        rig.zapi.inject("power_loss")
        await rig.net.sleep(1.0)
        rig.zapi.inject("power_return")
        await rig.settle()
        saved = (await sdo.upload(0x20A8, 0))[0]
        await sdo.download(0x20A8, 0, b"\x62")
        await sdo.download(0x1010, 1, SAVE)  # the CiA sub-index works too
        rig.net.nmt.reset_node(NODE)
        await rig.settle()
        return unsaved, saved, (await sdo.upload(0x20A8, 0))[0]

    assert run(scenario) == (100, 99, 98)
    unsaved, code, _ = run(scenario, quirks={"save_on_subindex_0": False})
    assert unsaved == 100 and -code == SdoAbortCode.WRITE_READ_ONLY


def test_saved_parameters_in_a_file_survive_a_new_controller(tmp_path: Path):
    path = tmp_path / "zapi.json"

    async def write(rig: Rig) -> None:
        await rig.master.sdo.download(0x20A8, 0, b"\x50")
        await rig.master.sdo.download(0x1010, 0, SAVE)

    async def read(rig: Rig) -> int:
        return (await rig.master.sdo.upload(0x20A8, 0))[0]

    run(write, storage=path)
    assert run(read, storage=path) == 0x50
    assert run(read) == 100


def test_unknown_quirk_and_bad_options_are_refused():
    async def main() -> None:
        async with AsyncNetwork() as net:
            with pytest.raises(UnknownQuirkError, match="handshake"):
                ZapiAce2(net, NODE, quirks={"shake": False})
            with pytest.raises(SimulationError, match="ramp_bytes"):
                ZapiAce2(net, NODE, ramp_bytes=3)
            with pytest.raises(SimulationError, match="sync_timeout"):
                ZapiAce2(net, NODE, sync_timeout=0)
            with pytest.raises(SimulationError, match=r"327\.67"):
                ZapiAce2(net, NODE, max_speed=400)
            with pytest.raises(SimulationError, match="2000h-5FFFh"):
                ZapiAce2(net, NODE, parameters={0x20A8: ("twice", 5, 0)})  # type: ignore[dict-item]
            ZapiAce2(net, NODE).start()
            with pytest.raises(SimulationError, match="already used"):
                ZapiAce2(net, NODE).start()

    simulate(main())


# ---------------------------------------------------------------------------- model
def test_run_at_50_hz_clockwise_with_the_ramp_and_the_statusword_echo():
    async def scenario(rig: Rig) -> dict[str, Any]:
        plc = Plc(rig)
        await start_with_sync(rig)
        plc.speed, plc.control, plc.ramp = 50.0, A16 | ENABLE | CW, 100  # 10 Hz/s
        await rig.net.sleep(1.0)
        one_second = plc.actual_speed
        word = plc.statusword
        await rig.net.sleep(5.0)
        at_speed = plc.actual_speed
        plc.control = A16 | ENABLE | CCW
        await rig.net.sleep(11.0)
        reverse = plc.actual_speed
        plc.speed = 0
        await rig.net.sleep(6.0)
        return {
            "one_second": one_second,
            "word": word,
            "at_speed": at_speed,
            "reverse": reverse,
            "stopped": plc.statusword,
            "current": plc.seen[-1][7],
        }

    r = run(scenario)
    assert r["one_second"] == pytest.approx(10, abs=0.3)
    assert r["word"] & 0xFF == 0x0A  # A16 and enabled echoed
    assert r["word"] >> 8 & 0x7F == 0x04  # running: not idle; input CNA6
    assert r["at_speed"] == 50.0 and r["reverse"] == -50.0
    assert r["stopped"] >> 8 & 0x7F == 0x44 and r["current"] == 2  # idle, power stage on


def test_default_ramp_and_pedal_brake_and_2_byte_ramp():
    async def scenario(rig: Rig) -> tuple[float, float]:
        plc = Plc(rig)
        await start_with_sync(rig)
        plc.speed, plc.control = 30.0, A16 | ENABLE | CW
        await rig.net.sleep(1.0)
        default = plc.actual_speed
        await rig.net.sleep(6.0)  # at 30 Hz
        plc.pedal = 1
        await rig.net.sleep(1.0)
        return default, plc.actual_speed

    default, braked = run(scenario, default_ramp=5.0)
    assert default == pytest.approx(5, abs=0.3) and braked == pytest.approx(25, abs=0.5)

    async def wide(rig: Rig) -> float:
        plc = Plc(rig)
        await start_with_sync(rig)
        plc.speed, plc.control, plc.ramp = 50.0, A16 | ENABLE | CW, 400  # 40 Hz/s in 2 bytes
        await rig.net.sleep(1.0)
        return plc.actual_speed

    assert run(wide, ramp_bytes=2) == pytest.approx(40, abs=1)


def test_without_a16_or_enable_or_direction_the_motor_stays():
    async def scenario(rig: Rig) -> list[float]:
        plc = Plc(rig)
        await start_with_sync(rig)
        speeds = []
        for control in (ENABLE | CW, A16 | CW, A16 | ENABLE, A16 | ENABLE | CW | CCW):
            plc.speed, plc.control = 50.0, control
            await rig.net.sleep(0.5)
            speeds.append(plc.actual_speed)
        return speeds

    assert run(scenario) == [0.0, 0.0, 0.0, 0.0]


# ---------------------------------------------------------------------------- faults
def test_alarm_is_reported_and_acknowledged_once_its_cause_is_gone():
    async def scenario(rig: Rig) -> list[Any]:
        plc = Plc(rig)
        await start_with_sync(rig)
        plc.speed, plc.control = 50.0, A16 | ENABLE | CW
        await rig.net.sleep(1.0)
        rig.zapi.inject("alarm", code=17, active=True)
        await rig.settle()
        out: list[Any] = [rig.zapi.status()["alarm_text"], rig.on(TPDO2)[-1].data[0]]
        out.append((await rig.master.sdo.upload(0x2110, 0))[0])  # read by SDO in pre-op
        await start_with_sync(rig)
        plc.control |= ACK
        await rig.net.sleep(0.1)
        out.append(rig.zapi.alarm)  # cause still there: not acknowledged
        rig.zapi.inject("alarm", code=17, active=False)
        plc.control &= ~ACK
        await rig.net.sleep(0.1)
        plc.control |= ACK
        await rig.net.sleep(0.1)
        out.append(rig.zapi.alarm)
        out.append(rig.on(TPDO2)[-1].data[0])
        plc.control &= ~ACK
        await rig.net.sleep(3.0)
        out.append(plc.actual_speed)
        return out

    result = run(scenario)
    assert result[:6] == ["LOGIC FAILURE #3", 17, 17, 17, 0, 0]
    assert result[6] > 25  # runs again after the acknowledge


def test_contactor_failure_is_not_reported_back():
    async def scenario(rig: Rig) -> tuple[int, float]:
        plc = Plc(rig)
        await start_with_sync(rig)
        rig.zapi.inject("contactor_failure")
        plc.speed, plc.control = 50.0, A16 | ENABLE | CW
        await rig.net.sleep(0.5)
        return plc.statusword & 0xFF, plc.actual_speed

    word, speed = run(scenario)
    assert word == 0x08 and speed == 0.0  # enabled, but A16 not echoed, no power


def test_emergency_stop_input_stops_the_motor():
    async def scenario(rig: Rig) -> tuple[int, float, float]:
        plc = Plc(rig)
        await start_with_sync(rig)
        plc.speed, plc.control, plc.ramp = 20.0, A16 | ENABLE | CW, 200
        await rig.net.sleep(2.0)
        running = plc.actual_speed
        rig.zapi.inject("emergency_stop")
        await rig.net.sleep(2.0)
        return plc.statusword >> 11 & 1, running, plc.actual_speed

    assert run(scenario) == (1, 20.0, 0.0)


def test_temperature_and_battery_in_tpdo2_and_unknown_faults():
    async def scenario(rig: Rig) -> bytes:
        rig.zapi.inject("temperature", controller=71, motor=-5)
        rig.zapi.inject("battery", bdi=42)
        with pytest.raises(SimulationError, match=r"0\.\.100"):
            rig.zapi.inject("battery", bdi=120)
        with pytest.raises(UnknownFaultError, match="alarm, battery, contactor_failure"):
            rig.zapi.inject("flood")
        with pytest.raises(SimulationError, match=r"1\.\.255"):
            rig.zapi.raise_alarm(300)
        await rig.net.sleep(0.1)
        return rig.on(TPDO2)[-1].data

    assert run(scenario) == bytes([0, 0, 0, 0, 71, 42, 0xFB, 0])
    assert ALARM_TEXTS[248] == "CAN BUS KO"


def test_status_summarises_the_model():
    async def scenario(rig: Rig) -> dict[str, Any]:
        plc = Plc(rig)
        await start_with_sync(rig)
        plc.speed, plc.control = 50.0, A16 | ENABLE | CW
        await rig.net.sleep(0.5)
        return rig.zapi.status()

    status = run(scenario)
    assert status["kind"] == "zapi_ace2" and status["state"] == "operational"
    assert status["setpoint_hz"] == 50.0 and status["speed_hz"] == pytest.approx(5, abs=0.3)
    assert status["handshake"] == "running" and status["alarm"] == 0
    assert status["controlword"] & 0xFF == 0x4A


# ---------------------------------------------------------------------------- the application
def test_thesis_application_run_by_a_cobus_master():
    """SYNC 20 ms, start, handshake for 2 s, run at 50 Hz CW, the handshake breaks (a slow
    PLC scan), alarm 248 and pre-operational, read the alarm by SDO, start again, acknowledge,
    run again; parameters checked and saved as the parameter manager does."""

    async def scenario(rig: Rig) -> dict[str, Any]:
        sdo = rig.master.sdo
        out: dict[str, Any] = {}
        # parameter manager: read, compare, write the mismatch, save, read back
        if (await sdo.upload(0x20A8, 0))[0] != 95:
            await sdo.download(0x20A8, 0, bytes([95, 0, 0, 0]), size_indicated=False)
            await sdo.download(0x1010, 0, SAVE)
        out["parameter"] = (await sdo.upload(0x20A8, 0))[0]
        plc = Plc(rig)
        rig.net.sync.start(0.02)
        await rig.net.sleep(0.1)
        rig.net.nmt.start(NODE)
        await rig.net.sleep(2.0)
        out["handshake"] = rig.zapi.status()["handshake"]
        plc.speed, plc.control, plc.ramp = 50.0, A16 | ENABLE | CW, 250
        await rig.net.sleep(3.0)
        out["speed"] = plc.actual_speed
        out["sent"] = plc.seen[-1][2]
        plc.answering = False  # a PLC scan longer than 20 ms
        await rig.net.sleep(0.1)
        out["state"] = rig.zapi.status()["state"]
        out["alarm"] = (await sdo.upload(0x2110, 0))[0]
        plc.answering = True
        plc.control = ACK  # acknowledge, with the run command released
        rig.net.nmt.start(NODE)
        await rig.net.sleep(0.2)
        out["after_ack"] = rig.zapi.alarm
        plc.control = A16 | ENABLE | CW
        await rig.net.sleep(1.0)
        out["again"] = rig.zapi.status()["state"], plc.actual_speed > 0
        return out

    assert run(scenario) == {
        "parameter": 95,
        "handshake": "running",
        "speed": 50.0,
        "sent": 0x0A,
        "state": "pre_operational",
        "alarm": 248,
        "after_ack": 0,
        "again": ("operational", True),
    }


def test_device_state_is_none_without_power():
    async def scenario(rig: Rig) -> tuple[NmtState | None, dict[str, Any]]:
        rig.zapi.inject("power_loss")
        return rig.zapi.state, rig.zapi.status()

    state, status = run(scenario)
    assert state is None and status["state"] == "off" and not status["powered"]
