"""Deviations from CiA 301 a device can be told to make (models of real devices that do):
each one against the CiA 301 behaviour it replaces."""

from __future__ import annotations

import pytest

from cobus.device import (
    SAVE_SIGNATURE,
    DeviceConfigError,
    ParametersStored,
    RpdoReceived,
    WrongLengthRpdoReceived,
)
from cobus.device.device import Deviations
from cobus.proto import Frame
from cobus.proto.sdo import SdoAbortCode, SdoAbortedError, SdoServer
from tests.test_device_support import NODE, Bench, run_bench, test_od

BOOTUP = 0x700 + NODE
TPDO1 = 0x180 + NODE
TPDO2 = 0x280 + NODE
RPDO1 = 0x200 + NODE
EMCY = 0x80 + NODE
SAVE = SAVE_SIGNATURE.to_bytes(4, "little")


async def _abort(coro: object) -> int:
    with pytest.raises(SdoAbortedError) as err:
        await coro  # type: ignore[misc]
    return int(err.value.code)


def _entry(index: int, sub: int, bits: int) -> int:
    return index << 16 | sub << 8 | bits


async def _map_tpdo(b: Bench, number: int, entries: list[int], tt: int, timer: int = 0) -> None:
    comm, mapping = 0x1800 + number - 1, 0x1A00 + number - 1
    cob = await b.sdo.read(comm, 1)
    await b.sdo.write(comm, 1, cob | 0x80000000)
    await b.sdo.write(mapping, 0, 0)
    for sub, value in enumerate(entries, 1):
        await b.sdo.write(mapping, sub, value)
    await b.sdo.write(mapping, 0, len(entries))
    await b.sdo.write(comm, 2, tt)
    await b.sdo.write(comm, 5, timer)
    await b.sdo.write(comm, 1, cob & 0x7FF)


def test_deviations_are_checked_when_made():
    with pytest.raises(DeviceConfigError, match=r"TPDO numbers are 1\.\.512"):
        Deviations(tpdos_outside_operational=frozenset({0}))
    with pytest.raises(DeviceConfigError, match=r"transmission types are 0\.\.255"):
        Deviations(transmission_types={256})
    assert Deviations(tpdos_outside_operational=[2, 4]).tpdos_outside_operational == {2, 4}


def test_without_bootup_the_device_still_enters_pre_operational():
    async def scenario(b: Bench) -> None:
        assert b.data(BOOTUP) == []
        assert b.state().name == "PRE_OPERATIONAL"
        b.net.nmt.reset_node(NODE)
        await b.settle()
        assert b.data(BOOTUP) == []
        assert b.state().name == "PRE_OPERATIONAL"

    run_bench(scenario, deviations=Deviations(send_bootup=False))

    async def cia(b: Bench) -> None:
        assert b.data(BOOTUP) == [b"\x00"]

    run_bench(cia)


def test_without_error_control_no_heartbeat_and_no_guarding_reply():
    async def scenario(b: Bench) -> list[Frame]:
        await b.sdo.write(0x1017, 0, 50)
        await b.sdo.write(0x100C, 0, 100)
        await b.sdo.write(0x100D, 0, 2)
        b.send(BOOTUP, rtr=True)
        await b.net.sleep(1.0)
        return [f for _, f in b.on(BOOTUP)][1:]  # after the boot-up message

    frames = run_bench(scenario, deviations=Deviations(error_control=False))
    assert frames == [Frame(BOOTUP, rtr=True)]  # only the master's request, no life guarding
    frames = run_bench(scenario)
    assert Frame(BOOTUP, b"\x7f") in frames and Frame(BOOTUP, b"\xff") not in frames
    assert len(frames) > 10  # heartbeat every 50 ms


def test_tpdos_outside_operational_run_in_pre_operational_not_in_stopped():
    async def scenario(b: Bench) -> tuple[int, int, int, int]:
        b.device.set(0x2000, 0, 7)
        await _map_tpdo(b, 1, [_entry(0x2000, 0, 16)], 255, timer=100)
        await _map_tpdo(b, 2, [_entry(0x2000, 0, 16)], 255, timer=100)
        t0 = b.net.time()
        await b.net.sleep(0.55)
        early, others = len(b.data(TPDO1, since=t0)), len(b.data(TPDO2, since=t0))
        b.net.nmt.stop(NODE)
        await b.settle()
        t1 = b.net.time()
        await b.net.sleep(0.5)
        stopped = len(b.data(TPDO1, since=t1))
        b.net.nmt.enter_preoperational(NODE)
        await b.settle()
        t2 = b.net.time()
        await b.net.sleep(0.25)
        return early, others, stopped, len(b.data(TPDO1, since=t2))

    early, others, stopped, again = run_bench(
        scenario, deviations=Deviations(tpdos_outside_operational={1})
    )
    assert (early, others, stopped, again) == (5, 0, 0, 2)
    assert run_bench(scenario)[0] == 0  # CiA 301: PDOs in operational only


def test_tpdo_outside_operational_answers_sync_in_pre_operational():
    async def scenario(b: Bench) -> list[bytes]:
        b.device.set(0x2000, 0, 0x1234)
        await _map_tpdo(b, 1, [_entry(0x2000, 0, 16)], 1)
        await b.sync()
        await b.sync()
        return b.data(TPDO1)

    assert (
        run_bench(scenario, deviations=Deviations(tpdos_outside_operational={1}))
        == [b"\x34\x12"] * 2
    )
    assert run_bench(scenario) == []


def test_store_on_subindex_0_saves_all_parameters():
    async def scenario(b: Bench) -> int:
        await b.sdo.write(0x200A, 0, 99)
        await b.sdo.download(0x1010, 0, SAVE)
        assert b.of(ParametersStored) == [ParametersStored(NODE, 1)]
        assert await b.sdo.read(0x1010, 0) == 3  # still the highest sub-index
        b.net.nmt.reset_node(NODE)
        await b.settle()
        value: int = await b.sdo.read(0x200A, 0)
        code = await _abort(b.sdo.download(0x1010, 0, b"\x01\x02"))
        assert code == SdoAbortCode.LENGTH_MISMATCH
        return value

    assert run_bench(scenario, deviations=Deviations(store_on_subindex_0=True)) == 99

    async def cia(b: Bench) -> int:
        return await _abort(b.sdo.download(0x1010, 0, SAVE))

    assert run_bench(cia) == SdoAbortCode.WRITE_READ_ONLY


def test_padded_writes_take_zero_upper_bytes():
    async def scenario(b: Bench) -> tuple[int, int, int]:
        accepted = 0
        try:
            await b.sdo.download(0x2002, 0, b"\x63\x00\x00\x00")
            accepted = await b.sdo.read(0x2002, 0)
        except SdoAbortedError as exc:
            accepted = -int(exc.code)
        nonzero = await _abort(b.sdo.download(0x2002, 0, b"\x63\x01\x00\x00"))
        await b.sdo.download(0x2001, 0, b"\x10\x00\x00\x00", size_indicated=False)
        return accepted, nonzero, await b.sdo.read(0x2001, 0)

    assert run_bench(scenario, deviations=Deviations(padded_writes=True)) == (
        0x63,
        SdoAbortCode.LENGTH_TOO_HIGH,
        0x10,
    )
    with pytest.raises(SdoAbortedError):
        run_bench(scenario)


def test_error_register_without_generic_bit_and_reset_with_manufacturer_data():
    async def scenario(b: Bench) -> tuple[list[bytes], int]:
        b.device.send_emergency(0x4310, 0x08, b"\x29")
        await b.settle()
        register: int = await b.sdo.read(0x1001, 0)
        b.device.clear_emergency(manufacturer_data=b"\x1e")
        await b.settle()
        return b.data(EMCY), register

    frames, register = run_bench(scenario, deviations=Deviations(generic_error_bit=False))
    assert frames == [bytes.fromhex("1043082900000000"), bytes.fromhex("0000001E00000000")]
    assert register == 0x08
    frames, register = run_bench(scenario)
    assert frames[0] == bytes.fromhex("1043092900000000") and register == 0x09


def test_communication_errors_left_to_the_application():
    async def scenario(b: Bench) -> tuple[list[bytes], int]:
        await b.sdo.write(0x1400, 1, RPDO1 | 0x80000000)
        await b.sdo.write(0x1600, 0, 0)
        await b.sdo.write(0x1600, 1, _entry(0x2001, 0, 16))
        await b.sdo.write(0x1600, 0, 1)
        await b.sdo.write(0x1400, 1, RPDO1)
        await b.start()
        b.send(RPDO1, b"\x01")
        await b.settle()
        assert len(b.of(WrongLengthRpdoReceived)) == 1
        return b.data(EMCY), await b.sdo.read(0x1001, 0)

    assert run_bench(scenario, deviations=Deviations(comm_error_emcy=False)) == ([], 0)
    frames, register = run_bench(scenario)
    assert frames == [bytes.fromhex("1082110000000000")] and register == 0


def test_sdo_served_by_the_owner_on_its_own_channel():
    async def scenario(b: Bench) -> tuple[list[bytes], int]:
        server = SdoServer(0x610, 0x590, b.device.sdo_backend)
        host = b.net.attach(server, [0x610])
        b.send(0x600 + NODE, bytes.fromhex("4000100000000000"))
        b.send(0x610, bytes.fromhex("4005200000000000"))
        await b.settle()
        host.close()
        return b.data(0x580 + NODE), int.from_bytes(b.data(0x590)[0][4:], "little")

    replies, value = run_bench(scenario, deviations=Deviations(serve_sdo=False))
    assert replies == [] and value == 42
    replies, _ = run_bench(scenario)
    assert len(replies) == 1


def _plus_node(kind: str, number: int, value: int) -> int:
    """A bare function code means "plus the node-ID" (as some drives read their PDO COB-IDs)."""
    if kind == "emcy" and value == 0x80:
        return 0x80 + NODE
    if kind in ("tpdo", "rpdo") and value & 0x7F == 0 and not value & 0x7FFFF800:
        return value + NODE
    return value


def test_cob_id_rule_reads_a_bare_function_code_as_plus_node_id():
    async def scenario(b: Bench) -> tuple[int, list[bytes], list[bytes]]:
        b.device.set(0x2000, 0, 0x0102)
        await b.sdo.write(0x1800, 1, 0x80000180)
        await b.sdo.write(0x1A00, 0, 0)
        await b.sdo.write(0x1A00, 1, _entry(0x2000, 0, 16))
        await b.sdo.write(0x1A00, 0, 1)
        await b.sdo.write(0x1800, 2, 1)
        await b.sdo.write(0x1800, 1, 0x180)
        await b.sdo.write(0x1014, 0, 0x80)
        await b.start()
        await b.sync()
        b.device.send_emergency(0x5000)
        await b.settle()
        return await b.sdo.read(0x1800, 1), b.data(TPDO1), b.data(EMCY)

    stored, tpdos, emcys = run_bench(scenario, deviations=Deviations(cob_id_rule=_plus_node))
    assert stored == 0x180 and tpdos == [b"\x02\x01"] and len(emcys) == 1
    with pytest.raises(SdoAbortedError) as err:  # CiA 301: 180h is a restricted identifier
        run_bench(scenario)
    assert err.value.code == SdoAbortCode.INVALID_VALUE


def test_cob_id_rule_can_read_sdo_bit_31_the_other_way():
    def inverted(kind: str, number: int, value: int) -> int:
        return value ^ 0x80000000 if kind.startswith("sdo") else value

    async def scenario(b: Bench) -> list[bytes]:
        await b.sdo.write(0x1201, 1, 0x80000641)
        await b.sdo.write(0x1201, 2, 0x800005C1)
        b.send(0x641, bytes.fromhex("4000100000000000"))
        await b.settle()
        return b.data(0x5C1)

    od = test_od(sdo_servers=2)
    for sub in (1, 2):  # bit 31 clear: disabled, in this polarity
        var = od.get_variable(0x1201, sub)
        assert var is not None
        var.default = 0
    assert len(run_bench(scenario, od, deviations=Deviations(cob_id_rule=inverted))) == 1
    assert run_bench(scenario, test_od(sdo_servers=2)) == []


def test_pdo_parameters_while_valid():
    async def scenario(b: Bench) -> int:
        await b.sdo.write(0x1800, 3, 100)
        value: int = await b.sdo.read(0x1800, 3)
        return value

    assert run_bench(scenario, deviations=Deviations(pdo_params_while_valid=True)) == 100
    with pytest.raises(SdoAbortedError) as err:
        run_bench(scenario)
    assert err.value.code == SdoAbortCode.INVALID_VALUE


def test_direct_mapping_fills_in_the_bit_length_and_rebuilds_at_once():
    async def scenario(b: Bench) -> tuple[int, list[bytes], int, int]:
        b.device.set(0x2000, 0, 0x0A0B)
        await b.sdo.write(0x1800, 2, 1)
        await b.sdo.write(0x1A00, 2, 0x20000000)  # entry 2, no bit length; entry 1 unused
        await b.start()
        await b.sync()
        too_long = await _abort(b.sdo.write(0x1A00, 1, 0x20090040))
        sub0 = await _abort(b.sdo.write(0x1A00, 0, 1))
        return await b.sdo.read(0x1A00, 2), b.data(TPDO1), too_long, sub0

    entry, frames, too_long, sub0 = run_bench(
        scenario, deviations=Deviations(direct_pdo_mapping=True)
    )
    assert entry == 0x20000010 and frames == [b"\x0b\x0a"]
    assert too_long == SdoAbortCode.MAPPING_TOO_LONG
    assert sub0 == SdoAbortCode.WRITE_READ_ONLY
    with pytest.raises(SdoAbortedError) as err:  # CiA 301: not while the TPDO is valid
        run_bench(scenario)
    assert err.value.code == SdoAbortCode.PARAMETER_INCOMPATIBLE


def test_partial_rpdo_writes_the_objects_it_covers():
    async def scenario(b: Bench) -> tuple[int, int, list[bytes], list[RpdoReceived]]:
        await b.sdo.write(0x1400, 1, RPDO1 | 0x80000000)
        await b.sdo.write(0x1600, 0, 0)
        await b.sdo.write(0x1600, 1, _entry(0x2001, 0, 16))
        await b.sdo.write(0x1600, 2, _entry(0x2002, 0, 8))
        await b.sdo.write(0x1600, 0, 2)
        await b.sdo.write(0x1400, 1, RPDO1)
        await b.sdo.write(0x2002, 0, 5)
        await b.start()
        b.send(RPDO1, b"\x07\x00")
        b.send(RPDO1, b"\x07")
        b.send(RPDO1, b"\x08\x00\x09\xff\xff")
        await b.settle()
        seen = b.of(RpdoReceived)
        return await b.sdo.read(0x2001, 0), await b.sdo.read(0x2002, 0), b.data(EMCY), seen

    setpoint, flags, emcys, seen = run_bench(scenario, deviations=Deviations(partial_rpdos=True))
    assert (setpoint, flags, emcys) == (8, 9, [])
    assert [e.values for e in seen] == [(7,), (), (8, 9)]
    setpoint, flags, emcys, _ = run_bench(scenario)
    assert (setpoint, flags) == (8, 9) and len(emcys) == 3  # short, short, long


def test_transmission_types_limited_to_the_device_s():
    async def scenario(b: Bench) -> int:
        await b.sdo.write(0x1800, 1, TPDO1 | 0x80000000)
        await b.sdo.write(0x1800, 2, 254)
        try:
            await b.sdo.write(0x1800, 2, 255)
        except SdoAbortedError as exc:
            return int(exc.code)
        return 0

    allowed = Deviations(transmission_types={*range(241), 254})
    assert run_bench(scenario, deviations=allowed) == SdoAbortCode.INVALID_VALUE
    assert run_bench(scenario) == 0


def test_emergencies_in_stopped():
    async def scenario(b: Bench) -> list[bytes]:
        b.net.nmt.stop(NODE)
        await b.settle()
        b.device.send_emergency(0x5000)
        b.device.clear_emergency()
        await b.settle()
        return b.data(EMCY)

    frames = run_bench(scenario, deviations=Deviations(emcy_in_stopped=True))
    assert frames == [bytes.fromhex("0050010000000000"), bytes(8)]
    assert run_bench(scenario) == []


def test_reset_communication_keeps_the_communication_values():
    async def scenario(b: Bench) -> tuple[int, int, list[bytes]]:
        await b.sdo.write(0x1017, 0, 100)
        await b.sdo.write(0x200A, 0, 11)
        b.net.nmt.reset_communication(NODE)
        await b.settle()
        kept = await b.sdo.read(0x1017, 0)
        t = b.net.time()
        await b.net.sleep(0.25)
        beats = b.data(BOOTUP, since=t + 0.001)
        b.net.nmt.reset_node(NODE)
        await b.settle()
        return kept, await b.sdo.read(0x1017, 0), beats

    kept, after_node, beats = run_bench(
        scenario, deviations=Deviations(reset_communication_keeps_values=True)
    )
    assert kept == 100 and after_node == 0 and beats == [b"\x7f"] * 2
    kept, _, beats = run_bench(scenario)
    assert kept == 0 and beats == []
