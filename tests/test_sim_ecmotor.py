"""The EC motor simulator against its document (seed 002): the golden vectors frame by frame,
the dialect with each quirk on and off, modes and their rules, latched errors and bit
operations, unit classes, the motor model, faults, and a master that configures it, runs it,
meets an overload and clears it."""

from __future__ import annotations

import asyncio
import struct
from collections.abc import Awaitable, Callable
from typing import Any

import pytest

from cobus.proto import Frame
from cobus.proto.sdo import SdoAbortCode
from cobus.runtime import AsyncNetwork
from cobus.sim import SimulatedDevice, SimulationError, UnknownFaultError
from cobus.sim._ecproto import EcDialect, EcRefusal
from cobus.sim.ecmotor import (
    BER,
    BIH,
    BPO,
    BPZ,
    BRS,
    BRU,
    BSW,
    BTM,
    BX,
    CDN,
    DEFAULT_S_ERR,
    UNITS,
    EcMotor,
)
from tests.golden import Case, load
from tests.test_sim_zapi import case_id, replay
from tests.util import simulate

ADDRESS = 3
RSDO, TSDO, EMCY, TPDO1, RPDO1 = 0x603, 0x583, 0x083, 0x183, 0x203


def make_motor(net: AsyncNetwork, case: Case) -> SimulatedDevice:
    return EcMotor(net, int(case.settings.get("node", ADDRESS)))


EC_CASES = [c.name for c in load("ec-motor")]


@pytest.mark.parametrize("title", EC_CASES, ids=case_id)
def test_golden_vectors(title: str) -> None:
    replay("ec-motor", title, make_motor)


# ---------------------------------------------------------------------------- master side
class Master:
    """The test as the motor's master: raw dialect frames, replies awaited."""

    def __init__(self, net: AsyncNetwork, motor: EcMotor) -> None:
        self.net = net
        self.motor = motor
        self.frames: list[Frame] = []
        self._replies: asyncio.Queue[Frame] = asyncio.Queue()
        net.subscribe_all(lambda frame, now: self.frames.append(frame))
        net.subscribe(TSDO, lambda frame, now: self._replies.put_nowait(frame))

    def on(self, cob_id: int) -> list[Frame]:
        return [f for f in self.frames if f.cob_id == cob_id]

    async def settle(self) -> None:
        for _ in range(4):
            await asyncio.sleep(0)

    async def request(self, data: bytes) -> Frame | None:
        """Send a request; the reply, or None when the motor does not answer (a refusal)."""
        while not self._replies.empty():
            self._replies.get_nowait()
        self.net.send(Frame(RSDO, data))
        await self.settle()
        return None if self._replies.empty() else self._replies.get_nowait()

    async def write(self, index: int, sub: int, value: int, size: int = 2) -> bool:
        data = bytes((0x22, index & 0xFF, index >> 8, sub)) + (value & 0xFFFFFFFF).to_bytes(
            4, "little"
        )
        reply = await self.request(data[: 4 + size])
        return reply is not None and reply.data[0] == 0x60

    async def read(self, index: int, sub: int = 0) -> int | None:
        reply = await self.request(bytes((0x40, index & 0xFF, index >> 8, sub)))
        if reply is None or reply.data[0] != 0x40:
            return None
        size = len(reply.data) - 4
        value = int.from_bytes(reply.data[4:], "little")
        signed = index in (0x2010, 0x2011, 0x2012, 0x2013, 0x2014, 0x2015, 0x2019, 0x2024)
        if signed and value >> (size * 8 - 1):
            value -= 1 << size * 8
        return value

    async def poll(self) -> tuple[int, int, int]:
        self.net.send(Frame(RPDO1))
        await self.settle()
        h_poz, m_eci, m_ssm = struct.unpack("<iHH", self.on(TPDO1)[-1].data)
        return h_poz, m_eci, m_ssm


def run(scenario: Callable[[Master], Awaitable[Any]], **options: Any) -> Any:
    async def main() -> Any:
        async with AsyncNetwork() as net:
            motor = EcMotor(net, ADDRESS, **options)
            master = Master(net, motor)
            motor.start()
            await master.settle()
            return await scenario(master)

    return simulate(main())


# ---------------------------------------------------------------------------- quirks
def test_read_reply_and_reply_length_quirks():
    async def scenario(m: Master) -> list[Frame | None]:
        await m.write(0x2024, 0, 0x1234)
        return [
            await m.request(bytes.fromhex("40242000")),
            await m.request(bytes.fromhex("2224200001000000")),
        ]

    read, write = run(scenario)
    assert read == Frame(TSDO, bytes.fromhex("402420003412"))
    assert write == Frame(TSDO, bytes.fromhex("60242000"))
    read, write = run(scenario, quirks={"read_reply_40": False, "short_replies": False})
    assert read == Frame(TSDO, bytes.fromhex("4B24200034120000"))  # CiA: 2 bytes, size shown
    assert write == Frame(TSDO, bytes.fromhex("6024200000000000"))
    read, _ = run(scenario, quirks={"read_reply_40": False})
    assert read == Frame(TSDO, bytes.fromhex("4B242000") + b"\x34\x12")


def test_no_abort_quirk_errors_become_emergencies():
    async def scenario(m: Master) -> tuple[Frame | None, list[Frame]]:
        reply = await m.request(bytes.fromhex("40092000"))  # 2009h is not used
        return reply, m.on(EMCY)

    reply, emcys = run(scenario)
    assert reply is None
    # m_sss brs (after power-on), c_sss bcef, m_ssm ber + bio + mode 1
    assert emcys == [Frame(EMCY, bytes.fromhex("1000004000400190"))]
    reply, emcys = run(scenario, quirks={"no_abort": False})
    assert reply == Frame(TSDO, bytes.fromhex("8009200000000206"))  # 06020000 no object
    assert len(emcys) == 1


def test_emcy_code_quirk():
    async def scenario(m: Master) -> bytes:
        await m.request(bytes.fromhex("40092000"))
        return m.on(EMCY)[0].data[:2]

    assert run(scenario) == b"\x10\x00"  # as printed
    assert run(scenario, quirks={"emcy_code_as_printed": False}) == b"\x00\x10"


def test_short_request_quirk():
    async def scenario(m: Master) -> Frame | None:
        return await m.request(bytes.fromhex("40412000"))

    assert run(scenario) == Frame(TSDO, bytes.fromhex("40412000BE00"))
    assert run(scenario, quirks={"short_requests": False}) is None


def test_no_bootup_quirk():
    async def scenario(m: Master) -> list[Frame]:
        m.net.send(Frame(0x000, bytes((0x82, ADDRESS))))
        await m.settle()
        return m.on(0x703)

    assert run(scenario) == []
    assert run(scenario, quirks={"no_bootup": False}) == [Frame(0x703, b"\x00")] * 2


# ---------------------------------------------------------------------------- dialect details
def test_requests_the_motor_refuses_each_with_an_emergency():
    async def scenario(m: Master) -> tuple[list[Frame | None], int, int]:
        replies = [
            await m.request(bytes.fromhex("4042200000000000")),  # 2042h is write-only
            await m.request(bytes.fromhex("2214200001000000")),  # h_vel is read-only
            await m.request(bytes.fromhex("40242001")),  # p_ven is 16-bit: sub 1 refused
            await m.request(bytes.fromhex("2200200004000000")),  # URAM 16-bit write: accepted
            await m.request(bytes.fromhex("230E200000000000")),  # m_sss: write by bits only
            await m.request(bytes.fromhex("21002000")),  # segmented: not supported
            await m.request(bytes.fromhex("4045")),  # too short to name an object
        ]
        c_sss = await m.read(0x200C)
        assert c_sss is not None
        return replies, len(m.on(EMCY)), c_sss

    replies, emcys, c_sss = run(scenario)
    assert replies == [None, None, None, Frame(TSDO, bytes.fromhex("60002000")), None, None, None]
    assert emcys == 6 and c_sss & 0xC000 == 0xC000  # bcef and bcer


def test_dialect_needs_an_address_of_1_to_15():
    with pytest.raises(SimulationError, match=r"1\.\.15"):
        EcDialect(16, None)  # type: ignore[arg-type]
    refusal = EcRefusal(SdoAbortCode.NO_OBJECT, "gone", unused_index=True)
    assert refusal.unused_index and str(refusal) == "gone"


def test_bit_operations_latched_errors_and_clear():
    async def scenario(m: Master) -> list[int | None]:
        out = [await m.read(0x200E)]  # brs after power-on
        await m.write(0x200F, 2, BX)
        out.append(await m.read(0x200F))
        await m.write(0x200F, 4, BX)
        out.append(await m.read(0x200F))
        await m.write(0x2001, 2, 0x00F0)  # URAM bit operations
        await m.write(0x2001, 3, 0x0030)
        out.append(await m.read(0x2001))
        await m.write(0x2045, 0, 0)
        out.append(await m.read(0x200E))
        out.append(await m.read(0x200F))
        return out

    brs, set_bx, neg_bx, uram, cleared, m_ssm = run(scenario)
    assert brs == BRS and set_bx is not None and set_bx & BX and set_bx & BER
    assert neg_bx is not None and not neg_bx & BX
    assert uram == 0x00C0 and cleared == 0
    assert m_ssm is not None and not m_ssm & BER and m_ssm & 0x1F == 1  # mode OFF


def test_status_request_by_c_sss_bits_and_debug_reads():
    async def scenario(m: Master) -> tuple[int, int, int | None, int | None]:
        await m.write(0x2023, 1, 0x01234567, 4)
        await m.write(0x200C, 2, 1 << 8)  # bcss: send the status
        await m.write(0x200C, 2, 1 << 9)  # bcse: send the emergency
        debug16 = await m.request(bytes.fromhex("4040200067030000"))
        debug32 = await m.request(bytes.fromhex("4040200165030000"))
        assert debug16 is not None and debug32 is not None
        return (
            len(m.on(TPDO1)),
            len(m.on(EMCY)),
            int.from_bytes(debug32.data[4:], "little"),
            await m.read(0x200C),
        )

    assert run(scenario) == (1, 1, 0x01234567, 0)


def test_user_programs_and_c_set_stays_as_configured():
    async def scenario(m: Master) -> list[Any]:
        await m.write(0x2043, 0, 0xFF42)
        _, _, running = await m.poll()
        await m.write(0x2043, 0, 0)
        _, _, stopped = await m.poll()
        await m.write(0x202F, 0, 0x0007)  # address 7 in RAM only
        in_ram = await m.read(0x202F)
        m.net.send(Frame(0x000, bytes((0x82, 0))))  # reset all motors
        await m.settle()
        return [running & 0x100, stopped & 0x100, in_ram, await m.read(0x202F)]

    assert run(scenario) == [0x100, 0, 0x0007, ADDRESS | 5 << 4]


# ---------------------------------------------------------------------------- modes and model
def test_velocity_mode_with_ramps_and_units():
    async def scenario(m: Master) -> dict[str, Any]:
        await m.write(0x2025, 0, 100)  # 1.46 rpm/ms
        await m.write(0x2026, 0, 400)
        await m.write(0x2024, 0, 16000)  # 3000 rpm
        await m.write(0x2042, 0, 5)
        await m.net.sleep(1.0)
        ramping = await m.read(0x2014)
        await m.net.sleep(2.0)
        out = {"ramping": ramping, "speed": await m.read(0x2014), "status": m.motor.status()}
        _, _, m_ssm = await m.poll()
        out["m_ssm"] = m_ssm
        await m.write(0x2024, 0, 0)
        await m.net.sleep(0.6)
        out["stopped"] = await m.read(0x2014)
        return out

    r = run(scenario)
    assert r["ramping"] == pytest.approx(7812, abs=80)  # 100 x 78.125 V units per second
    assert r["speed"] == 16000 and r["status"]["speed_rpm"] == 3000.0
    assert r["m_ssm"] & (BPZ | BRU) == BPZ | BRU and r["m_ssm"] & 0x1F == 5
    assert r["stopped"] == 0
    assert UNITS["P"][1] == 0.1171875


def test_position_mode_reaches_the_target_then_holds_with_cdn():
    async def scenario(m: Master) -> tuple[int | None, int, int | None]:
        await m.write(0x200D, 0, CDN)
        await m.write(0x2024, 0, 3200)  # 600 rpm
        await m.write(0x2023, 1, 3072 * 5, 4)  # five turns
        await m.write(0x2042, 0, 6)
        await m.net.sleep(2.0)
        position = await m.read(0x2012, 1)
        _, _, m_ssm = await m.poll()
        return position, m_ssm, await m.read(0x2014)

    position, m_ssm, speed = run(scenario)
    assert position == 3072 * 5 and speed == 0
    assert m_ssm & 0x1F == 3  # cdn: mode 3 once in position


def test_position_mode_in_position_bit_and_limits():
    async def scenario(m: Master) -> tuple[int, int | None, int | None]:
        await m.write(0x200D, 0, 1 << 1)  # clp: limits on
        await m.write(0x2022, 1, 3072, 4)  # P_lih one turn
        await m.write(0x2023, 1, 3072 * 3, 4)
        await m.write(0x2042, 0, 6)
        await m.net.sleep(2.0)
        _, _, m_ssm = await m.poll()
        return m_ssm, await m.read(0x2012, 1), await m.read(0x2019)

    m_ssm, position, error = run(scenario)
    assert m_ssm & BPO and m_ssm & 0x1F == 6 and position == 3072 and error == 0


def test_emergency_stop_goes_to_holding_by_itself():
    async def scenario(m: Master) -> list[int | None]:
        await m.write(0x2024, 0, 8000)
        await m.write(0x2042, 0, 5)
        await m.net.sleep(1.0)
        await m.write(0x2042, 0, 2)
        await m.net.sleep(0.05)
        return [m.motor.mode, await m.read(0x2014)]

    assert run(scenario) == [3, 0]


def test_power_stage_not_switched_on_while_turning():
    async def scenario(m: Master) -> tuple[bool, bool, int]:
        await m.write(0x2024, 0, 16000)
        await m.write(0x2042, 0, 5)
        await m.net.sleep(1.0)
        await m.write(0x2042, 0, 1)  # off: coasting
        await m.net.sleep(0.1)
        refused = not await m.write(0x2042, 0, 5)
        await m.net.sleep(1.0)
        accepted = await m.write(0x2042, 0, 5)
        return refused, accepted, len(m.on(EMCY))

    assert run(scenario) == (True, True, 1)


def test_modes_the_rules_refuse_and_torque_and_potentiometer_modes():
    async def scenario(m: Master) -> list[Any]:
        out: list[Any] = [await m.write(0x2042, 0, mode) for mode in (7, 16, 28, 29, 30)]
        m.motor.potentiometer = 1600
        await m.write(0x2042, 0, 15)
        await m.net.sleep(1.0)
        out.append(await m.read(0x2014))
        await m.write(0x2042, 0, 1)
        await m.net.sleep(1.0)
        await m.write(0x2024, 0, 1000)
        await m.write(0x2027, 0, 4000)
        await m.write(0x2042, 0, 4)  # torque mode against no load, up to |p_ven|
        await m.net.sleep(2.0)
        out.append(await m.read(0x2014))
        return out

    assert run(scenario) == [False, False, False, False, False, 1600, 1000]


def test_mode_reset_restarts_the_motor():
    async def scenario(m: Master) -> tuple[bool, int, int | None]:
        await m.write(0x2045, 0, 0)
        await m.write(0x2024, 0, 100)
        ok = await m.write(0x2042, 0, 31)
        await m.settle()
        return ok, m.motor.mode, await m.read(0x2024)

    ok, mode, p_ven = run(scenario)
    assert ok and mode == 1 and p_ven == 0


def test_zero_position_functions():
    async def scenario(m: Master) -> list[Any]:
        await m.write(0x2024, 0, 1000)
        await m.write(0x2042, 0, 5)
        await m.net.sleep(1.0)
        out: list[Any] = [await m.write(0x2045, 1, 0)]  # refused: turning
        out.append(await m.write(0x2045, 2, 0))  # zero while running in mode 5
        out.append(abs(await m.read(0x2012, 1) or 0) < 200)
        await m.write(0x2042, 0, 2)
        await m.net.sleep(0.5)
        position = await m.read(0x2012, 1) or 0
        out.append(await m.write(0x2045, 2, 0))  # mode 3 now: refused
        out.append(await m.write(0x2045, 3, 0))
        out.append(await m.read(0x2012, 1) == position % 3072)
        out.append(await m.write(0x2045, 4, 0))
        out.append(await m.read(0x2012, 1) == position % 3072 - 3072)
        out.append(await m.write(0x2045, 1, 0))
        out.append(await m.read(0x2012, 1))
        return out

    assert run(scenario) == [False, True, True, False, True, True, True, True, True, 0]


# ---------------------------------------------------------------------------- faults
def test_overload_trips_the_sw_protection_and_is_cleared():
    """The document's application: configure, run, overload fault, clear, run again."""

    async def scenario(m: Master) -> dict[str, Any]:
        out: dict[str, Any] = {}
        # configure: clear the reset flag, ramps, torque limit, speed
        assert await m.write(0x2045, 0, 0)
        for index, value in ((0x2025, 200), (0x2026, 200), (0x2027, 8000), (0x2024, 8000)):
            assert await m.write(index, 0, value)
        assert await m.write(0x2042, 0, 5)
        await m.net.sleep(1.0)
        out["running"] = m.motor.status()["speed_rpm"]
        m.motor.inject("overload", torque=2.0)
        await m.net.sleep(0.05)
        emcy = m.on(EMCY)[-1].data
        out["emcy_m_sss"], out["emcy_m_ssm"] = struct.unpack_from("<HxxH", emcy, 2)
        out["status"] = m.motor.status()["fault"]
        out["refused"] = await m.write(0x2042, 0, 5)  # not from mode 29
        # the power stage is off: no overcurrent, mode 1 leaves 29; the load trips it again
        assert await m.write(0x2042, 0, 1)
        await m.net.sleep(0.5)  # coasting to standstill
        assert await m.write(0x2042, 0, 5)
        await m.net.sleep(0.05)
        out["again_tripped"] = m.motor.mode
        m.motor.inject("overload", torque=0)
        await m.net.sleep(0.5)
        assert await m.write(0x2045, 0, 0)
        out["leave"] = await m.write(0x2042, 0, 1)
        out["again"] = await m.write(0x2042, 0, 5)
        await m.net.sleep(1.0)
        out["speed"] = await m.read(0x2014)
        return out

    r = run(scenario)
    assert r["running"] == 1500.0
    assert r["emcy_m_sss"] & (BIH | BSW) == BIH | BSW and r["emcy_m_ssm"] & 0x1F == 29
    assert r["emcy_m_ssm"] & BER and r["status"] is True
    assert (r["refused"], r["again_tripped"], r["leave"], r["again"]) == (False, 29, True, True)
    assert r["speed"] == 8000


def test_thermal_model_trips_btm_when_bih_is_masked():
    async def scenario(m: Master) -> tuple[int, float]:
        await m.write(0x200B, 0, DEFAULT_S_ERR & ~BIH & ~(1 << 8))  # no bih, no bep
        await m.write(0x2024, 0, 4000)
        await m.write(0x2042, 0, 5)
        await m.net.sleep(0.5)
        m.motor.inject("overload")
        t0 = m.net.time()
        while m.motor.mode != 29 and m.net.time() < t0 + 60:
            await m.net.sleep(0.5)
        return m.motor.m_sss & (BTM | BSW), m.net.time() - t0

    bits, after = run(scenario)
    assert bits == BTM | BSW and 10 < after < 30


def test_other_protections_and_the_bio_input():
    async def scenario(m: Master) -> list[Any]:
        out: list[Any] = []
        await m.write(0x2045, 0, 0)
        for fault, params in (
            ("overtemperature", {"celsius": 95}),
            ("supply", {"volts": 12}),
            ("supply", {"volts": 70}),
            ("hw_protection", {}),
        ):
            m.motor.inject(fault, **params)
            await m.write(0x2042, 0, 3)
            await m.net.sleep(0.05)
            out.append((m.motor.mode, m.motor.m_sss & 0xFF80))
            assert not await m.write(0x2042, 0, 1)  # the cause is still there
            m.motor.inject("overtemperature", celsius=25)
            m.motor.inject("supply", volts=48)
            m.motor.inject("hw_protection", active=False)
            await m.write(0x2045, 0, 0)
            await m.write(0x2042, 0, 1)
        await m.write(0x200D, 0, 1 << 3)  # cen: BIO enables
        m.motor.inject("bio", level=False)
        await m.write(0x2042, 0, 3)
        await m.net.sleep(0.05)
        _, _, m_ssm = await m.poll()
        out.append((m_ssm & BPZ, m.motor.m_sss & (1 << 3)))
        return out

    assert run(scenario) == [
        (29, 0x1080),  # bsw + bts
        (29, 0x1400),  # bsw + bul
        (29, 0x1800),  # bsw + buh
        (29, 0x2000),  # bhw
        (0, 1 << 3),  # ben: warning, the power stage stays off
    ]


def test_faults_and_options_are_checked():
    async def main() -> None:
        async with AsyncNetwork() as net:
            with pytest.raises(SimulationError, match=r"1\.\.15"):
                EcMotor(net, 16)
            with pytest.raises(SimulationError, match="bit-rate code"):
                EcMotor(net, 2, can_rate=9)
            with pytest.raises(SimulationError, match="adr1"):
                EcMotor(net, 2, group=16)
            with pytest.raises(SimulationError, match="tick"):
                EcMotor(net, 2, tick=0)
            motor = EcMotor(net, 2)
            with pytest.raises(UnknownFaultError, match="overload"):
                motor.inject("melt")
            with pytest.raises(SimulationError, match="unit class"):
                motor.physical("Q", 1)
            assert motor.physical("T", 2500) == 25.0

    simulate(main())


def test_power_cycle_silences_and_restarts():
    async def scenario(m: Master) -> tuple[Frame | None, str, int | None, str]:
        await m.write(0x2024, 0, 55)
        m.motor.inject("power_loss")
        silent = await m.request(bytes.fromhex("40242000"))
        off = m.motor.status()["state"]
        m.motor.inject("power_return")
        await m.settle()
        return silent, off, await m.read(0x2024), m.motor.status()["state"]

    assert run(scenario) == (None, "off", 0, "mode 1 OFF")
