"""What the cobus master needs to drive the document devices the way their documents' masters do
(issue 6: "a scenario test driven by the master"), each on its own: from the master SYNC before
the first NMT start, TPDO listeners and ``send_rpdo``; from the STÖBER simulator a fault that
outlasts an NMT reset node, reported again.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from cobus.master import (
    MasterValueError,
    NetworkConfig,
)
from cobus.proto.nmt import NmtState
from cobus.runtime import AsyncNetwork, HandlerFailed
from cobus.sim.stober import StoberMds5000
from tests.test_master_support import (
    Rig,
    network,
    nmt,
    rig_test,
)
from tests.util import simulate


def first(rig: Rig, cob_id: int, data: bytes | None = None) -> float:
    """When the first frame on ``cob_id`` (with ``data``) went over the bus."""
    return next(t for t, f in rig.on(cob_id) if data is None or f.data == data)


def place(rig: Rig, cob_id: int, data: bytes | None = None) -> int:
    """Where the first frame on ``cob_id`` (with ``data``) is in the bus order."""
    return next(
        n
        for n, (_, f) in enumerate(rig.frames)
        if f.cob_id == cob_id and (data is None or f.data == data)
    )


# ================================================================================ STÖBER
MDS = 1
ENABLE_BIT, ACK_BIT = 1 << 0, 1 << 2  # A180 device control (the simulator's choice)
OPERATION_ENABLED, FAULT, SWITCH_ON_DISABLED = 4, 7, 1


def test_stober_fault_outlasting_a_reset_node_is_reported_again_and_acknowledged() -> None:
    """NMT reset node clears the CANopen errors, not the inverter's fault: the drive reports
    the event once more after its boot-up (1001h shows it), and the acknowledge sends
    0000h as the manual says; reset communication keeps the error and sends nothing."""

    async def main() -> list[tuple[int, bytes]]:
        async with AsyncNetwork() as net:
            frames: list[tuple[int, bytes]] = []
            net.subscribe_all(lambda f, now: frames.append((f.cob_id, f.data)))
            mds = StoberMds5000(net, MDS)
            mds.start()
            mds.inject("event", number=44, cause=7)  # external fault
            await net.sleep(0.1)
            net.nmt.reset_communication(MDS)
            await net.sleep(0.1)
            net.nmt.reset_node(MDS)
            await net.sleep(0.1)
            device = mds.device
            assert device is not None and device.get(0x1001) == 0x01
            mds.inject("event", number=44, active=False)
            assert mds.acknowledge()
            await net.sleep(0.01)
            assert device.get(0x1001) == 0
            mds.close()
            return [(c, d) for c, d in frames if c in (0x081, 0x701)]

    fault = (0x081, bytes.fromhex("0090012C07000000"))  # 9000h, register 01, event 44, cause 7
    assert simulate(main()) == [
        (0x701, b"\x00"),  # power-on
        fault,
        (0x701, b"\x00"),  # reset communication: the error is kept, nothing sent
        (0x701, b"\x00"),  # reset node: the error is gone from 1001h ...
        fault,  # ... and reported again
        (0x081, bytes.fromhex("0000001E00000000")),  # acknowledged: 0000h, event 30
    ]


# ================================================================================ the master
# What the scenarios needed from the master, each on its own with the master tests' I/O node.
IO_NODE = """
  a:
    node_id: 5
    eds: io.eds
    tpdo1: {{mapping: [counter], transmission_type: 255}}
    rpdo1: {{mapping: [flags], transmission_type: {rpdo1}}}
"""


def io_network(tmp_path: Path, master: str, extra: str = "", rpdo1: int = 255) -> NetworkConfig:
    text = f"master: {master}\nnodes:" + IO_NODE.format(rpdo1=rpdo1) + extra
    return network(tmp_path, text)


@pytest.mark.parametrize("sync", [True, False], ids=["sync", "no-sync"])
def test_the_master_starts_nodes_once_its_first_sync_is_out(tmp_path: Path, sync: bool) -> None:
    """A node that needs no boot-up is ready at once; with SYNC configured the master waits
    for its first SYNC (one period) before the NMT start, as the ZAPI ACE2 requires."""
    master = "{sync_period: 50}" if sync else "{}"
    cfg = io_network(tmp_path, master, "    do_not_initialise: true\n")

    async def scenario(rig: Rig) -> None:
        rig.add(5)
        await rig.master.boot(timeout=5)
        start = place(rig, 0x000, b"\x01\x05")
        if sync:
            assert first(rig, 0x000, b"\x01\x05") == pytest.approx(0.05)
            assert place(rig, 0x80) < start
        else:
            assert first(rig, 0x000, b"\x01\x05") == 0.0 and rig.on(0x80) == []
        assert nmt(rig.devices[5]) is NmtState.OPERATIONAL

    rig_test(cfg, scenario)


def test_tpdo_listeners_see_each_tpdo_once_it_is_in_the_process_image(tmp_path: Path) -> None:
    cfg = io_network(tmp_path, "{}")

    async def scenario(rig: Rig) -> None:
        master = rig.master
        seen: list[tuple[int, int, float, object]] = []

        def listener(node_id: int, number: int, now: float) -> None:
            seen.append((node_id, number, now, master.inputs["a.counter"]))

        def broken(node_id: int, number: int, now: float) -> None:
            raise RuntimeError("application bug")

        failures: list[HandlerFailed] = []
        rig.net.add_listener(lambda e: failures.append(e) if isinstance(e, HandlerFailed) else None)
        master.add_tpdo_listener(broken)
        master.add_tpdo_listener(listener)
        device = rig.add(5)
        rig.send(0x185, b"\x07\x00")  # before the start: not taken, not reported
        await rig.settle()
        await master.boot(timeout=5)
        device.set(0x2000, 0, 42)
        await rig.run(0.01)
        # called when the TPDO arrives, with its value already in the image
        assert seen == [(5, 1, first(rig, 0x185, b"\x2a\x00"), 42)]
        assert len(failures) == 1 and "application bug" in failures[0].error
        master.remove_tpdo_listener(listener)
        master.remove_tpdo_listener(broken)
        device.set(0x2000, 0, 43)
        await rig.run(0.01)
        assert len(seen) == 1 and master.inputs["a.counter"] == 43

    rig_test(cfg, scenario)


def test_send_rpdo_sends_the_outputs_changed_or_not(tmp_path: Path) -> None:
    cfg = io_network(tmp_path, "{sync_period: 10}")

    async def scenario(rig: Rig) -> None:
        master = rig.master
        rig.add(5)
        master.start()
        assert master.send_rpdo("a", 1) is False  # not started yet: nothing
        await master.boot(timeout=5)
        master.outputs["a.flags"] = 3
        master.outputs["a.flags"] = 3  # unchanged: no frame
        await rig.settle()
        assert rig.data(0x205) == [b"\x00", b"\x03"]  # the start, the change
        assert master.send_rpdo(5, 1) is True
        await rig.settle()
        assert rig.data(0x205) == [b"\x00", b"\x03", b"\x03"]
        assert master.nodes[5].rpdo_sent[1] == 3
        with pytest.raises(MasterValueError, match=r"no RPDO 2 .*its RPDOs: 1"):
            master.send_rpdo("a", 2)

    rig_test(cfg, scenario)
