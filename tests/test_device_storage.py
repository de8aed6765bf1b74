"""Store (1010h) and restore (1011h) of parameters: signatures, groups, effect through resets,
a file written atomically, and a save interrupted before the rename."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from cobus.device import (
    LOAD_SIGNATURE,
    SAVE_SIGNATURE,
    EntryRefusedError,
    FileStorage,
    ParametersRestored,
    ParametersStored,
    StorageError,
    StorageProblem,
    add_device,
)
from cobus.device import storage as storage_module
from cobus.proto.sdo import SdoAbortCode, SdoAbortedError
from cobus.runtime import AsyncNetwork
from tests.test_device_support import NODE, Bench, bench, run_bench, simulate, test_od


async def _abort(coro) -> int:
    with pytest.raises(SdoAbortedError) as err:
        await coro
    return int(err.value.code)


def _boot_from(path: Path, node_id: int = NODE) -> dict[str, int]:
    """A new device (a power cycle) on the same file: what it starts with."""

    async def main():
        async with AsyncNetwork() as net:
            b = bench(net, node_id=node_id, storage=path)
            await b.settle()
            return {
                "setpoint": b.device.get(0x2001),
                "parameter": b.device.get(0x200A),
                "heartbeat": b.device.get(0x1017),
                "tpdo1": b.device.get(0x1800, 1),
                "tpdo1_type": b.device.get(0x1800, 2),
            }

    return simulate(main())


def test_save_signature_and_sub_indices():
    async def scenario(b: Bench):
        assert await b.sdo.read(0x1010, 0) == 3
        assert await b.sdo.read(0x1010, 1) == 1  # saves on command
        assert await b.sdo.read(0x1011, 1) == 1
        assert await _abort(b.sdo.write(0x1010, 1, 0x12345678)) == SdoAbortCode.CANNOT_STORE
        assert await _abort(b.sdo.write(0x1011, 1, SAVE_SIGNATURE)) == SdoAbortCode.CANNOT_STORE
        assert await _abort(b.sdo.write(0x1010, 0, 3)) == SdoAbortCode.WRITE_READ_ONLY
        assert not b.of(ParametersStored)
        await b.sdo.write(0x1010, 1, SAVE_SIGNATURE)
        await b.sdo.write(0x1011, 2, LOAD_SIGNATURE)
        assert b.of(ParametersStored) == [ParametersStored(NODE, 1)]
        assert b.of(ParametersRestored) == [ParametersRestored(NODE, 2)]
        with pytest.raises(EntryRefusedError) as err:
            b.device.store_parameters(4)
        assert err.value.code == SdoAbortCode.CANNOT_STORE

    run_bench(scenario)


def test_stored_values_survive_a_power_cycle(tmp_path):
    path = tmp_path / "node5.json"

    async def scenario(b: Bench):
        await b.sdo.write(0x2001, 0, -77)
        await b.sdo.write(0x200A, 0, 1234)
        await b.sdo.write(0x1017, 0, 250)
        await b.sdo.write(0x1800, 1, 0x80000000 | 0x185)
        await b.sdo.write(0x1800, 2, 5)
        await b.sdo.write(0x1800, 1, 0x185)
        await b.sdo.write(0x1010, 1, SAVE_SIGNATURE)

    run_bench(scenario, storage=path)
    doc = json.loads(path.read_text())
    assert doc["format"] == "cobus device parameters"
    assert doc["application"]["2001:00"] == {"data": "b3ff"}
    # a value that still holds its $NODEID default is kept relative to the node-ID
    assert doc["communication"]["1800:01"] == {"node_id_offset": 0x180}
    assert _boot_from(path) == {
        "setpoint": -77,
        "parameter": 1234,
        "heartbeat": 250,
        "tpdo1": 0x185,
        "tpdo1_type": 5,
    }
    # the same file on another node-ID: the pre-defined COB-ID follows the node-ID
    assert _boot_from(path, node_id=9)["tpdo1"] == 0x189


def test_groups_store_and_restore_separately_and_take_effect_at_resets():
    async def scenario(b: Bench):
        device = b.device
        await b.sdo.write(0x200A, 0, 1)
        await b.sdo.write(0x1017, 0, 100)
        await b.sdo.write(0x1010, 3, SAVE_SIGNATURE)  # application only
        await b.sdo.write(0x200A, 0, 2)
        await b.sdo.write(0x1017, 0, 200)
        b.net.nmt.reset_node(NODE)
        await b.settle()
        assert device.get(0x200A) == 1  # stored
        assert device.get(0x1017) == 0  # never stored: default
        await b.sdo.write(0x1017, 0, 300)
        await b.sdo.write(0x1010, 2, SAVE_SIGNATURE)  # communication only
        await b.sdo.write(0x200A, 0, 3)
        b.net.nmt.reset_communication(NODE)
        await b.settle()
        assert device.get(0x1017) == 300 and device.get(0x200A) == 3
        # restore: nothing changes until the next reset
        await b.sdo.write(0x1011, 2, LOAD_SIGNATURE)
        assert device.get(0x1017) == 300
        b.net.nmt.reset_node(NODE)
        await b.settle()
        assert device.get(0x1017) == 0  # communication defaults
        assert device.get(0x200A) == 1  # the stored application value stays
        await b.sdo.write(0x1011, 1, LOAD_SIGNATURE)
        b.net.nmt.reset_node(NODE)
        await b.settle()
        assert device.get(0x200A) == 7  # the dictionary's default

    run_bench(scenario)


def test_local_store_and_restore():
    async def scenario(b: Bench):
        b.device.set(0x200A, 0, 55)
        b.device.store_parameters()
        b.device.set(0x200A, 0, 56)
        b.net.nmt.reset_node(NODE)
        await b.settle()
        assert b.device.get(0x200A) == 55
        b.device.restore_defaults(3)
        b.net.nmt.reset_node(NODE)
        await b.settle()
        assert b.device.get(0x200A) == 7

    run_bench(scenario)


def test_a_save_interrupted_before_the_rename_keeps_the_old_values(tmp_path, monkeypatch):
    path = tmp_path / "params.json"

    async def scenario(b: Bench):
        await b.sdo.write(0x200A, 0, 111)
        await b.sdo.write(0x1010, 1, SAVE_SIGNATURE)
        before = path.read_bytes()

        def crash(src, dst):
            raise OSError(5, "power lost")

        monkeypatch.setattr(os, "replace", crash)
        await b.sdo.write(0x200A, 0, 222)
        assert await _abort(b.sdo.write(0x1010, 1, SAVE_SIGNATURE)) == SdoAbortCode.CANNOT_STORE
        assert path.read_bytes() == before
        assert sorted(p.name for p in tmp_path.iterdir()) == ["params.json"]  # no temp file left
        monkeypatch.undo()
        b.net.nmt.reset_node(NODE)
        await b.settle()
        assert b.device.get(0x200A) == 111

    run_bench(scenario, storage=path)
    assert _boot_from(path)["parameter"] == 111


def test_atomic_write_syncs_file_and_directory(tmp_path, monkeypatch):
    synced: list[int] = []
    real_fsync = os.fsync

    def fsync(fd: int) -> None:
        synced.append(fd)
        real_fsync(fd)

    monkeypatch.setattr(os, "fsync", fsync)
    target = tmp_path / "x.json"
    storage_module.atomic_write(target, b"one")
    storage_module.atomic_write(target, b"two")
    assert target.read_bytes() == b"two"
    assert len(synced) == 4  # file and directory, twice


def test_unreadable_parameter_files(tmp_path):
    broken = tmp_path / "broken.json"
    broken.write_text("{not json")
    with pytest.raises(StorageError, match="delete it"):
        FileStorage(broken).load()

    async def start_on_broken():
        async with AsyncNetwork() as net:
            events = []
            net.add_listener(events.append)
            emcys = []
            net.subscribe(0x80 + NODE, lambda frame, now: emcys.append(bytes(frame.data)))
            device = add_device(net, NODE, test_od(), storage=broken)  # it starts all the same
            await net.sleep(0.01)
            assert any(isinstance(e, StorageProblem) and "delete it" in e.reason for e in events)
            assert emcys and emcys[0][:2] == b"\x00\x63"  # EMCY 6300h "data set"
            assert device.get(0x1017) == 0  # on its defaults

    simulate(start_on_broken())
    foreign = tmp_path / "foreign.json"
    foreign.write_text('{"format": "something else"}')
    with pytest.raises(StorageError, match="not a cobus parameter file"):
        FileStorage(foreign).load()
    # entries that do not fit the dictionary are reported and skipped
    odd = tmp_path / "odd.json"
    odd.write_text(
        json.dumps(
            {
                "format": "cobus device parameters",
                "version": 1,
                "communication": {"1017:00": {"data": "e803"}, "1000:00": {"data": "00000000"}},
                "application": {"2001:00": {"data": "ffffffff"}, "7777:00": {"data": "00"}},
            }
        )
    )

    async def start_on_odd():
        async with AsyncNetwork() as net:
            b = bench(net, storage=odd)
            await b.settle()
            assert b.device.get(0x1017) == 1000
            assert b.device.get(0x2001) == 0
            return [e.reason for e in b.of(StorageProblem)]

    problems = simulate(start_on_odd())
    assert len(problems) == 3
    assert any("1000:00" in p for p in problems)
    assert any("2001:00" in p for p in problems)


@pytest.mark.parametrize(
    ("content", "reason"),
    [
        (b'{"format": "cobus device parameters", \xff\xfe}', "byte 38 is not UTF-8"),
        (b"[" * 100_000 + b"]" * 100_000, "nested too deeply"),
        (b'{"version": ' + b"9" * 5000 + b"}", "not a parameter file"),
    ],
    ids=["not UTF-8", "deep nesting", "5000-digit number"],
)
def test_a_hostile_parameter_file_is_a_storage_error(tmp_path, content, reason):
    path = tmp_path / "node5.json"
    path.write_bytes(content)
    with pytest.raises(StorageError, match=reason):
        FileStorage(path).load()

    # after an NMT reset the device still boots, on its defaults, and says why
    async def scenario(b: Bench):
        path.write_bytes(content)  # broken while the device runs
        b.net.nmt.reset_node(NODE)
        await b.net.sleep(0.1)
        assert b.data(0x700 + NODE)[-1] == b"\x00"  # the boot-up came
        assert await b.sdo.read(0x1017) == 0  # and it answers, on its defaults
        problems = [e for e in b.events if isinstance(e, StorageProblem)]
        assert problems and reason in problems[-1].reason

    path.unlink()
    run_bench(scenario, storage=path)


def test_a_stored_offset_of_infinity_is_a_problem_not_a_crash(tmp_path):
    path = tmp_path / "node5.json"
    path.write_text(
        '{"format": "cobus device parameters", "version": 1, "application": {}, '
        '"communication": {"1800:01": {"node_id_offset": Infinity}}}'
    )

    async def scenario(b: Bench):
        problems = [e for e in b.events if isinstance(e, StorageProblem)]
        assert problems and "1800:01" in problems[0].reason
        assert await b.sdo.read(0x1800, 1) == 0x180 + NODE  # the default

    run_bench(scenario, storage=path)


def test_a_damaged_file_is_refused_whole_never_half_applied(tmp_path):
    """1 000 random single-bit flips of a stored file: each load gives exactly what was
    stored, or a StorageError (then the device starts on its defaults) — never a mix."""
    import random

    path = tmp_path / "node5.json"

    async def scenario(b: Bench):
        await b.sdo.write(0x2001, 0, -77)
        await b.sdo.write(0x200A, 0, 1234)
        await b.sdo.write(0x1017, 0, 250)
        await b.sdo.write(0x1010, 1, SAVE_SIGNATURE)

    run_bench(scenario, storage=path)
    good = path.read_bytes()
    stored = FileStorage(path).load()
    rng = random.Random(17)
    outcomes = {"same": 0, "refused": 0}
    for _ in range(1000):
        damaged = bytearray(good)
        bit = rng.randrange(len(damaged) * 8)
        damaged[bit // 8] ^= 1 << bit % 8
        path.write_bytes(bytes(damaged))
        try:
            assert FileStorage(path).load() == stored
            outcomes["same"] += 1
        except StorageError:
            outcomes["refused"] += 1
    assert outcomes["refused"] > 900  # (a flip in the layout's white space changes nothing)
    # a device on a damaged file comes up on its defaults and answers
    path.write_bytes(good.replace(b'"b3ff"', b'"b4ff"'))
    assert _boot_from(path)["setpoint"] == 0 and _boot_from(path)["heartbeat"] == 0


def test_a_save_interrupted_leaves_no_temporary_file_behind(tmp_path):
    path = tmp_path / "node5.json"
    stale = tmp_path / ".node5.json.abc123.tmp"
    stale.write_text("half a save")
    FileStorage(path).load()
    assert not stale.exists()
