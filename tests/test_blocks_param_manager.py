"""The parameter manager against the simulated ZAPI ACE2 on the simulated clock: a
factory-fresh controller re-parameterised and saved the ZAPI way (1010h sub 0), each step's
failure injected (no answer, refusal, a value that does not stick, abort) and recovered."""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable
from dataclasses import replace
from typing import Any

import pytest

from cobus.blocks import (
    AsyncParameterManager,
    ParameterReport,
    ParameterSet,
    ParameterStep,
    loads_parameters,
)
from cobus.blocks.param_manager import CommandsInSetError, ParameterFault
from cobus.device import export_eds
from cobus.od import DataType, ObjectDictionary, loads
from cobus.proto import Frame
from cobus.proto.sdo import SdoAbort, SdoAbortCode
from cobus.runtime import AsyncNetwork
from cobus.runtime.remote import AsyncRemoteNode
from cobus.sim.zapi import ZapiAce2

from .util import simulate

NODE = 8
EXTRA = {
    0x2001: ("acceleration time", DataType.UNSIGNED16, 10),
    0x2002: ("deceleration time", DataType.UNSIGNED16, 10),
    0x2003: ("max speed forward", DataType.UNSIGNED16, 200),
}
SET = """
save: {subindex: 0}
parameters:
  main contactor voltage: 90
  acceleration time: 25
  deceleration time: 10
  max speed forward: 150
"""


class Bench:
    def __init__(
        self, net: AsyncNetwork, zapi: ZapiAce2, node: AsyncRemoteNode, od: ObjectDictionary
    ):
        self.net, self.zapi, self.node, self.od = net, zapi, node, od
        self.frames: list[Frame] = []
        net.subscribe_all(lambda frame, now: self.frames.append(frame))

    @property
    def device(self) -> Any:
        return self.zapi.device

    def sdo_requests(self) -> list[str]:
        return [f"{f.cob_id:03X}: {f.data.hex(' ')}" for f in self.frames if f.cob_id == 0x608]

    def parameters(self, text: str = SET) -> ParameterSet:
        return loads_parameters(text, od=self.od, path="zapi.yml")

    async def power_cycle(self) -> None:
        self.zapi.power_off()
        await asyncio.sleep(0.1)
        self.zapi.power_on()
        await asyncio.sleep(0.2)


def run(scenario: Callable[[Bench], Awaitable[Any]]) -> Any:
    async def main() -> Any:
        async with AsyncNetwork() as net:
            zapi = ZapiAce2(net, NODE, parameters=EXTRA)
            zapi.start()
            await asyncio.sleep(0.2)
            od = loads(export_eds(zapi.od))  # what a user has: the EDS
            node = net.add_remote(NODE, od, sdo_timeout=0.5)
            return await scenario(Bench(net, zapi, node, od))

    return simulate(main())


def test_a_factory_fresh_zapi_is_re_parameterised_saved_on_sub_0_and_keeps_it() -> None:
    async def scenario(b: Bench) -> tuple[ParameterReport, ParameterReport, list[Any]]:
        seen: list[tuple[ParameterStep, int, int]] = []
        manager = AsyncParameterManager(b.node, b.parameters(), progress=lambda *a: seen.append(a))
        first = await manager.apply()
        saved = [b.device.get(0x20A8, 0), b.device.get(0x2001, 0), b.device.get(0x2003, 0)]
        await b.power_cycle()
        again = await manager.apply()  # after a power cycle: kept, so up to date
        return first, again, [saved, seen, b.sdo_requests()]

    first, again, (saved, seen, requests) = run(scenario)
    assert first.ok and first.verified and first.saved is True
    assert [p.index for p, _ in first.differences] == [0x20A8, 0x2001, 0x2003]
    assert [held for _, held in first.differences] == [100, 10, 200]
    assert [p.index for p in first.written] == [0x20A8, 0x2001, 0x2003]
    assert first.summary == "node 8: re-parameterised, 3 of 4 written, saved and verified"
    assert first.code == 0 and first.attempts == 1
    assert saved == [90, 25, 150]
    # the ZAPI's save command, as the thesis prints it: 1010h sub 0 "save"
    assert "608: 23 10 10 00 73 61 76 65" in requests  # (23: with size)
    assert again.up_to_date and again.ok and not again.written
    assert again.summary == "node 8: up to date (4 parameters)"
    steps = [s for s, _, _ in seen]
    assert steps.index(ParameterStep.READ) < steps.index(ParameterStep.WRITE)
    assert steps.index(ParameterStep.SAVE) < steps.index(ParameterStep.READ_BACK)
    assert (ParameterStep.WRITE, 3, 3) in seen


def test_without_save_the_values_are_lost_at_the_next_power_up() -> None:
    async def scenario(b: Bench) -> tuple[ParameterReport, ParameterReport]:
        manager = AsyncParameterManager(b.node, b.parameters(), save=False)
        applied = await manager.apply()
        await b.power_cycle()
        return applied, await manager.diff()

    applied, diff = run(scenario)
    assert applied.ok and applied.saved is None
    assert diff.dry_run and not diff.ok and diff.code == 99
    assert len(diff.differences) == 3 and not diff.written
    assert diff.summary == "node 8: 3 of 4 parameters differ"


def test_a_refused_write_is_reported_the_others_go_on_and_nothing_is_saved() -> None:
    def refuse(value: Any) -> None:
        raise SdoAbort(SdoAbortCode.VALUE_TOO_HIGH)

    async def scenario(b: Bench) -> ParameterReport:
        b.device.on_write(0x2001, 0, refuse)
        return await AsyncParameterManager(b.node, b.parameters()).apply()

    report = run(scenario)
    assert not report.ok and report.saved is False and not report.verified
    assert [p.index for p in report.written] == [0x20A8, 0x2003]
    (failure,) = report.failures
    assert failure.step is ParameterStep.WRITE and failure.fault is ParameterFault.REFUSED
    assert failure.code == 32 and report.code == 32
    assert failure.abort_code == 0x06090031
    assert str(failure).startswith("[32] write 0x2001:00 acceleration time = 25: refused: ")
    assert "value of parameter written too high" in str(failure).lower()
    assert report.summary.startswith("node 8: failed, 1 problem(s): [32] write 0x2001:00")
    assert report.to_dict()["failures"][0]["abort_code"] == 0x06090031


def test_a_value_that_does_not_stick_fails_verify_after_the_restarts() -> None:
    async def scenario(b: Bench) -> ParameterReport:
        b.device.on_read(0x2003, 0, lambda: 200)  # reads the old value whatever is written
        return await AsyncParameterManager(b.node, b.parameters(), restarts=2).apply()

    report = run(scenario)
    assert not report.ok and report.attempts == 3
    (failure,) = report.failures
    assert failure.code == 64 and failure.actual == 200
    assert str(failure) == (
        "[64] verify 0x2003:00 max speed forward = 150: reads back a different value: reads 200"
    )


def test_no_answer_is_retried_then_the_sequence_restarts_and_recovers() -> None:
    async def scenario(b: Bench) -> tuple[ParameterReport, ParameterReport]:
        b.zapi.power_off()  # silent: every request times out (0.5 s)

        async def recover() -> None:
            await asyncio.sleep(1.2)  # during the third try of the first read
            b.zapi.power_on()

        task = asyncio.get_running_loop().create_task(recover())
        recovered = await AsyncParameterManager(b.node, b.parameters(), retries=2).apply()
        await task
        b.zapi.power_off()
        lost = await AsyncParameterManager(b.node, b.parameters(), retries=1, restarts=0).diff()
        return recovered, lost

    recovered, lost = run(scenario)
    assert recovered.ok and recovered.attempts == 2 and recovered.saved
    assert not lost.ok and lost.attempts == 1
    (failure,) = lost.failures
    assert failure.code == 11  # read, no answer
    assert str(failure).startswith("[11] read 0x20A8:00 main contactor voltage = 90: no answer")
    assert "(2 attempt(s))" in str(failure)


def test_abort_stops_before_the_next_transfer() -> None:
    async def scenario(b: Bench) -> tuple[ParameterReport, int]:
        manager: AsyncParameterManager

        def progress(step: ParameterStep, done: int, total: int) -> None:
            if step is ParameterStep.WRITE and done == 1:
                manager.abort()

        manager = AsyncParameterManager(b.node, b.parameters(), progress=progress)
        report = await manager.apply()
        return report, b.device.get(0x2001, 0)

    report, acceleration = run(scenario)
    assert report.aborted and not report.ok and report.code == 35  # aborted in the write step
    assert [p.index for p in report.written] == [0x20A8]
    assert acceleration == 10  # never written
    assert report.summary == "node 8: aborted"


def test_a_refused_read_is_written_and_verified() -> None:
    def refuse() -> int:
        raise SdoAbort(SdoAbortCode.READ_WRITE_ONLY)

    async def scenario(b: Bench) -> ParameterReport:
        b.device.on_read(0x2002, 0, refuse)
        return await AsyncParameterManager(b.node, b.parameters()).apply()

    report = run(scenario)
    assert [p.index for p, held in report.differences if held is None] == [0x2002]
    assert 0x2002 in [p.index for p in report.written]
    assert [f.code for f in report.failures] == [52]  # read back refused: cannot verify
    assert not report.ok


def test_snapshot_captures_a_node_into_a_file_that_reads_back_up_to_date(tmp_path: Any) -> None:
    async def scenario(b: Bench) -> tuple[ParameterSet, list[Any], ParameterReport]:
        b.device.set(0x2001, 0, 33)
        manager = AsyncParameterManager(b.node)
        snap, failures = await manager.snapshot()
        snap.write(tmp_path / "snap.yml")
        checked = await AsyncParameterManager(b.node, tmp_path / "snap.yml").diff()
        return snap, failures, checked

    snap, failures, checked = run(scenario)
    assert not failures
    assert {(p.index, p.value) for p in snap} >= {(0x20A8, 100), (0x2001, 33), (0x2003, 200)}
    assert all(p.index >= 0x2000 for p in snap)
    assert checked.up_to_date and checked.checked == len(snap)


def test_arguments_are_checked() -> None:
    async def scenario(b: Bench) -> None:
        with pytest.raises(ValueError, match="retries=-1"):
            AsyncParameterManager(b.node, b.parameters(), retries=-1)
        with pytest.raises(TypeError, match="has no SDO"):
            AsyncParameterManager(object(), b.parameters())
        with pytest.raises(ValueError, match="no parameter set"):
            await AsyncParameterManager(b.node).apply()

    run(scenario)


def test_a_save_that_timed_out_is_sent_again_by_the_restart() -> None:
    class LostSave:
        """The node's SDO, except that the first save goes unanswered."""

        def __init__(self, sdo: Any) -> None:
            self.sdo, self.lost = sdo, 0

        async def upload(self, index: int, subindex: int) -> bytes:
            data: bytes = await self.sdo.upload(index, subindex)
            return data

        async def download(self, index: int, subindex: int, data: bytes) -> None:
            if index == 0x1010 and not self.lost:
                self.lost += 1
                raise TimeoutError("no answer")
            await self.sdo.download(index, subindex, data)

    async def scenario(b: Bench) -> tuple[ParameterReport, ParameterReport, list[str]]:
        port = LostSave(b.node.sdo)
        first = await AsyncParameterManager(port, b.parameters(), retries=0).apply()
        await b.power_cycle()
        after = await AsyncParameterManager(b.node, b.parameters()).diff()
        return first, after, b.sdo_requests()

    first, after, requests = run(scenario)
    assert first.ok and first.attempts == 2 and first.saved is True and first.verified
    assert len(first.differences) == 3 and len(first.written) == 3  # as the node was at first
    assert not first.up_to_date
    assert requests.count("608: 23 10 10 00 73 61 76 65") == 1  # sent by the restart
    assert after.up_to_date  # the values survived the power cycle: they were saved


def test_odd_answers_write_only_objects_and_a_failing_progress_display() -> None:
    from cobus.blocks import Parameter

    p = Parameter(0x2000, 0, -1, DataType.INTEGER16)
    assert p.decode(b"\xff\xff\xff\xff") == -1  # expedited without size: 4 bytes
    assert p.decode(b"\xff") == -1  # fewer bytes than the type takes
    assert Parameter(0x2000, 0, 0.0, DataType.REAL32).holds(-0.0)

    async def scenario(b: Bench) -> tuple[ParameterReport, ParameterReport]:
        pset = b.parameters()
        only_written = replace(pset[0], readable=False)
        pset.parameters = (only_written, *pset.parameters[1:])

        def broken(*args: Any) -> None:
            raise RuntimeError("the display is gone")

        manager = AsyncParameterManager(b.node, pset, progress=broken)
        return await manager.apply(), await manager.apply()

    first, second = run(scenario)
    assert first.ok and second.ok
    assert [p.index for p, _ in second.differences] == [0x20A8]  # never read: always written


def test_snapshot_lists_what_the_node_refuses_and_skips_what_is_no_parameter() -> None:
    def refuse() -> int:
        raise SdoAbort(SdoAbortCode.READ_WRITE_ONLY)

    async def scenario(b: Bench) -> tuple[ParameterSet, list[Any]]:
        b.device.on_read(0x2001, 0, refuse)
        manager = AsyncParameterManager(b.node)
        return await manager.snapshot([0x1000, 0x1017, 0x1010, 0x1400, 0x2001, 0x20A8])

    snap, failures = run(scenario)
    assert [p.index for p in snap] == [0x1017, 0x20A8]  # 1000h ro, 1010h, PDO: no parameters
    assert [f.code for f in failures] == [12]
    assert "0x2001:00 acceleration time" in str(failures[0])


def test_a_set_holding_commands_is_refused_before_anything_is_written() -> None:
    """Issue 38 (1): a parameter is configuration; the ZAPI's speed set-point and controlword
    are process data its EDS maps to RPDO 1 (and 1011h restores the factory defaults)."""
    text = SET + "  controlword: 0x0C\n  speed setpoint: 1500\n"

    async def scenario(b: Bench) -> tuple[str, list[str], dict[str, int], ParameterReport]:
        manager = AsyncParameterManager(b.node, b.parameters(text))
        with pytest.raises(CommandsInSetError) as refused:
            await manager.apply()
        requests = b.sdo_requests()
        before = {"controlword": b.device.get(0x2201, 0), "setpoint": b.device.get(0x2200, 0)}
        allowed = await AsyncParameterManager(
            b.node, b.parameters(text), allow_commands=True
        ).apply()
        return str(refused.value), requests, before, allowed

    message, requests, before, allowed = run(scenario)
    assert requests == []  # refused before the first transfer
    assert before == {"controlword": 0, "setpoint": 0}
    assert message.startswith("node 8: the set writes 2 command(s), not parameters - ")
    assert "0x2201:00 controlword: process data the device receives: the EDS maps it to RPDO 1" in (
        message
    )
    assert "allow_commands=True" in message
    assert allowed.ok and {p.index for p in allowed.written} >= {0x2200, 0x2201}


def test_a_snapshot_leaves_process_data_out_unless_named() -> None:
    async def scenario(b: Bench) -> tuple[ParameterSet, list[Any], ParameterSet]:
        manager = AsyncParameterManager(b.node)
        snap, _ = await manager.snapshot()
        left_out = list(manager.left_out)
        named, _ = await manager.snapshot(["speed setpoint", 0x2001])
        return snap, left_out, named

    snap, left_out, named = run(scenario)
    assert not {p.index for p in snap} & {0x2200, 0x2201, 0x2202, 0x2203, 0x2204}
    assert [(v.index, why.split(":")[0]) for v, why in left_out] == [
        (i, "process data the device receives") for i in range(0x2200, 0x2205)
    ]
    assert [p.index for p in named] == [0x2200, 0x2001]


def test_a_dcf_set_leaves_its_commands_out_and_says_so() -> None:
    from cobus.sim.drive402 import SimulatedDrive402 as Servo

    async def main() -> ParameterSet:
        async with AsyncNetwork() as net:
            od = loads(export_eds(Servo(net, 10).od))
        for index, value in ((0x6040, 0x0F), (0x6060, 1), (0x607A, 5000), (0x6065, 700)):
            var = od.get_variable(index, 0)
            assert var is not None
            var.parameter_value = value
        return ParameterSet.from_dcf(od, path="servo.dcf")

    pset = simulate(main())
    assert [p.index for p in pset] == [0x6065]
    assert [(p.index, why.split(" (")[0].split(":")[0]) for p, why in pset.left_out] == [
        (0x6040, "the CiA 402 controlword"),
        (0x6060, "the CiA 402 modes of operation"),
        (0x607A, "a CiA 402 set-point"),
    ]


def test_a_refused_save_is_a_failure_and_the_values_stay_unsaved() -> None:
    """The node refuses 1010h (08000020, cannot be stored): the report says NOT saved and
    names the save, the manager keeps them unsaved, and a power cycle loses them."""
    from cobus.proto.sdo import SdoAbortedError

    class RefusedSave:
        def __init__(self, sdo: Any) -> None:
            self.sdo = sdo

        async def upload(self, index: int, subindex: int) -> bytes:
            data: bytes = await self.sdo.upload(index, subindex)
            return data

        async def download(self, index: int, subindex: int, data: bytes) -> None:
            if index == 0x1010:
                raise SdoAbortedError(
                    SdoAbortCode.CANNOT_STORE, index=index, subindex=subindex, node=NODE
                )
            await self.sdo.download(index, subindex, data)

    async def scenario(b: Bench) -> tuple[ParameterReport, bool, ParameterReport]:
        manager = AsyncParameterManager(RefusedSave(b.node.sdo), b.parameters())
        report = await manager.apply()
        unsaved = manager.unsaved
        await b.power_cycle()
        after = await AsyncParameterManager(b.node, b.parameters()).diff()
        return report, unsaved, after

    report, unsaved, after = run(scenario)
    assert report.saved is False and not report.ok
    (failure,) = report.failures
    assert failure.step is ParameterStep.SAVE and failure.fault is ParameterFault.REFUSED
    assert "save 0x1010:00" in report.summary and "refused" in report.summary
    assert unsaved
    assert not after.up_to_date and len(after.differences) == 3  # lost at the power cycle
