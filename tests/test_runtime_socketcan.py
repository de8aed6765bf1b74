"""cobus on SocketCAN, through python-can's own ``SocketcanBus`` with socket pairs in place of
the kernel's sockets (``tests/socketcan_standin.py``: this kernel has no SocketCAN).

What runs for real: python-can's SocketCAN code (``struct can_frame`` both ways, timestamps,
error frames, ``select`` before each send, the broadcast manager's ``TX_SETUP`` and
``TX_DELETE``) and cobus's choices for it: the loop reads the socket itself, error frames
are the controller's own, a full transmit queue fills the backlog, and SYNC by the interface
is one broadcast manager task.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Iterator

import can
import pytest
from can.interfaces.socketcan import constants

from cobus.device import DictionaryBuilder, add_device
from cobus.od import DataType
from cobus.proto import Frame
from cobus.runtime import (
    AsyncNetwork,
    BusState,
    BusStateChanged,
    InterfaceTimingError,
    Network,
    TxQueueFull,
    TxResumed,
)
from tests.socketcan_standin import TX_DELETE, TX_SETUP, KernelStandIn
from tests.test_runtime_fd_read import _on_real_time_loop as _real_time
from tests.test_runtime_fd_read import _until
from tests.test_runtime_periodic import _state

SETTIMER_STARTTIMER = constants.SETTIMER | constants.STARTTIMER


@pytest.fixture
def kernel(monkeypatch: pytest.MonkeyPatch) -> Iterator[KernelStandIn]:
    standin = KernelStandIn().install(monkeypatch)
    yield standin
    standin.close()


def _msg(cob_id: int, data: bytes = b"", **kw: object) -> can.Message:
    return can.Message(arbitration_id=cob_id, data=data, is_extended_id=False, **kw)  # type: ignore[arg-type]


def test_the_loop_reads_the_socket_and_frames_go_out_as_the_kernels_can_frames(kernel):
    async def main() -> None:
        async with AsyncNetwork(interface="socketcan", channel="vcan0") as net:
            assert kernel.bound == ["vcan0"]
            options = kernel.can_options()
            assert options[constants.CAN_RAW_RECV_OWN_MSGS] == 0  # cobus never asks for its own
            assert options[constants.CAN_RAW_ERR_FILTER] == 0x1FFFFFFF  # error frames: all
            assert net._fd is not None and net._reader is None  # the loop reads: no thread
            heard: list[Frame] = []
            net.subscribe_all(lambda f, now: heard.append(f))
            kernel.inject(_msg(0x181, b"\x01\x02"))
            kernel.inject(
                can.Message(arbitration_id=0x1ABCDE0, data=b"\xff" * 8, is_extended_id=True)
            )
            kernel.inject(_msg(0x705, is_remote_frame=True, dlc=1))
            await _until(lambda: len(heard) == 3)
            assert heard == [
                Frame(0x181, b"\x01\x02"),
                Frame(0x1ABCDE0, b"\xff" * 8, extended=True),
                Frame(0x705, rtr=True, dlc=1),
            ]
            assert net.frames_received == 3

            net.send(Frame(0x605, b"\x40\x00\x10\x00\x00\x00\x00\x00"))
            net.send(Frame(0x18FF0001, b"\x07", extended=True))
            net.send(Frame(0x701, rtr=True, dlc=1))
            sent = kernel.sent()
            assert [(m.arbitration_id, m.is_extended_id, m.is_remote_frame) for m in sent] == [
                (0x605, False, False),
                (0x18FF0001, True, False),
                (0x701, False, True),
            ]
            assert sent[0].data == b"\x40\x00\x10\x00\x00\x00\x00\x00"
            assert sent[1].data == b"\x07" and sent[2].dlc == 1
            assert len(heard) == 3  # nothing of its own came back: SocketCAN sends none

    _real_time(main)


def _blob_od(blob: bytes):
    b = DictionaryBuilder(device_name="standin")
    b.variable(0x2000, "Blob", DataType.DOMAIN, default=blob)
    return b.build()


def test_a_blocking_client_and_a_device_talk_over_a_vcan_interface(kernel):
    """Two blocking networks on one vcan, each read by its reading role (a reader thread, or
    the blocking caller waiting for its answer): expedited, segmented and block uploads, and
    a download."""
    kernel.start_vcan()
    blob = bytes(range(256)) * 16
    with (
        Network(interface="socketcan", channel="vcan0") as field,
        Network(interface="socketcan", channel="vcan0") as master,
    ):
        assert master.aio._reading is not None and master.aio._reader is None
        add_device(field, 5, _blob_od(blob))
        sdo = master.add_remote(5).sdo
        assert sdo.upload(0x1000) == field.devices[5].od[0x1000].default.to_bytes(4, "little")
        assert sdo.upload(0x1008) == b"standin"
        assert sdo.upload(0x2000, block=True) == blob
        sdo.download(0x2000, 0, b"new value")
        assert sdo.upload(0x2000) == b"new value"


def test_error_frames_report_this_sides_controller(kernel):
    """On SocketCAN an error frame is the controller's own (not another participant's, as on
    python-can's virtual bus): bus-off, then restarted."""

    async def main() -> None:
        async with AsyncNetwork(interface="socketcan", channel="can0") as net:
            changes: list[BusStateChanged] = []
            net.add_listener(
                lambda e: changes.append(e) if isinstance(e, BusStateChanged) else None
            )
            kernel.inject(_msg(0x040, bytes(8), is_error_frame=True))  # CAN_ERR_BUSOFF
            await _until(lambda: net.bus_state is BusState.BUS_OFF)
            kernel.inject(_msg(0x100, bytes(8), is_error_frame=True))  # CAN_ERR_RESTARTED
            await _until(lambda: net.bus_state is BusState.ACTIVE)
            assert [(c.old, c.new) for c in changes] == [
                (BusState.ACTIVE, BusState.BUS_OFF),
                (BusState.BUS_OFF, BusState.ACTIVE),
            ]
            assert net.frames_received == 0  # error frames are no frames of the network

    _real_time(main)


def test_a_full_transmit_queue_keeps_frames_in_the_backlog_until_the_socket_takes_them(kernel):
    """python-can's SocketCAN send waits for the socket to be writable (``select``); with
    ``timeout=0`` a queue the kernel has not emptied refuses the frame, the network keeps it
    and every later one in order, and sends them once the socket takes frames again."""

    async def main() -> None:
        async with AsyncNetwork(interface="socketcan", channel="can0") as net:
            events: list[object] = []
            net.add_listener(events.append)
            for i in range(300):
                net.send(Frame(0x200 + (i % 0x100), i.to_bytes(2, "big")))
            assert any(isinstance(e, TxQueueFull) for e in events)
            assert net.frames_sent < 300  # some wait in the backlog
            sent: list[can.Message] = []
            deadline = time.monotonic() + 5
            while len(sent) < 300:
                assert time.monotonic() < deadline, f"{len(sent)} of 300 frames"
                sent += kernel.sent(timeout=0)
                await asyncio.sleep(0.002)  # the network's retry runs on its loop
            assert [int.from_bytes(m.data, "big") for m in sent] == list(range(300))
            assert net.frames_sent == 300
            assert isinstance(events[-1], TxResumed)

    _real_time(main)


def test_sync_by_the_interface_is_one_broadcast_manager_task(kernel):
    """One TX_SETUP with every counter value: the kernel sends them in turn, one per period,
    from now on (no count, no first interval). A new start deletes the old task first; stop
    and a disconnect from a bus the user keeps delete it."""
    bus = can.Bus(interface="socketcan", channel="vcan0")

    async def main() -> None:
        net = await AsyncNetwork(bus).connect()
        net.sync.start(0.001, overflow=3, by_interface=True)
        (setup,) = kernel.bcm_ops()
        assert setup[:5] == (TX_SETUP, SETTIMER_STARTTIMER, 0, 0, 1000)
        assert [(m.arbitration_id, bytes(m.data)) for m in setup.frames] == [
            (0x80, b"\x01"),
            (0x80, b"\x02"),
            (0x80, b"\x03"),
        ]

        # python-can cuts a period to whole microseconds: 1001 us stays 1001 us
        net.sync.start(0.001001, by_interface=True)
        delete, setup2 = kernel.bcm_ops()
        assert (delete.opcode, delete.task_id) == (TX_DELETE, setup.task_id)
        assert (setup2.opcode, setup2.ival2_us) == (TX_SETUP, 1001)
        assert [(m.arbitration_id, m.dlc) for m in setup2.frames] == [(0x80, 0)]  # no counter

        net.sync.stop()
        (delete2,) = kernel.bcm_ops()
        assert (delete2.opcode, delete2.task_id) == (TX_DELETE, setup2.task_id)

        net.sync.start(0.002, overflow=240, by_interface=True)
        (setup3,) = kernel.bcm_ops()
        assert len(setup3.frames) == 240 and setup3.frames[-1].data == bytes([240])
        await net.disconnect()  # the bus stays open: its task must not go on
        (delete3,) = kernel.bcm_ops()
        assert (delete3.opcode, delete3.task_id) == (TX_DELETE, setup3.task_id)

    try:
        _real_time(main)
    finally:
        bus.shutdown()


def test_closing_a_network_that_opened_its_bus_deletes_the_task_and_closes_the_socket(kernel):
    """The timer deletes its task on the way out; the bus's shutdown then closes the broadcast
    manager's socket (the kernel would delete what was left on it)."""

    async def main() -> None:
        net = await AsyncNetwork(interface="socketcan", channel="vcan0").connect()
        net.sync.start(0.001, overflow=2, by_interface=True)
        await net.disconnect()

    _real_time(main)
    setup, delete = kernel.bcm_ops()
    assert (setup.opcode, delete.opcode, delete.task_id) == (TX_SETUP, TX_DELETE, setup.task_id)
    assert kernel.closed_bcm == 1


def test_a_network_hears_the_sync_the_kernel_sends_for_it_as_the_others_do(kernel):
    """On vcan the kernel loops the broadcast manager's frames back to every raw socket, the
    producing bus's own included: both networks hear each SYNC once, counter in turn."""
    kernel.start_vcan()

    async def main() -> None:
        async with (
            AsyncNetwork(interface="socketcan", channel="vcan0") as master,
            AsyncNetwork(interface="socketcan", channel="vcan0") as field,
        ):
            mine: list[bytes] = []
            theirs: list[bytes] = []
            master.subscribe(0x80, lambda f, now: mine.append(f.data))
            field.subscribe(0x80, lambda f, now: theirs.append(f.data))
            master.sync.start(0.002, overflow=3, by_interface=True)
            await _until(lambda: len(mine) >= 7 and len(theirs) >= 7)
            master.sync.stop()
            await asyncio.sleep(0.02)
            heard = len(mine)
            await asyncio.sleep(0.03)
            assert len(mine) == heard
            assert mine == theirs
            assert mine[:6] == [b"\x01", b"\x02", b"\x03"] * 2  # the first at once

    _real_time(main)


def test_a_device_producing_sync_has_the_kernel_time_it_and_hears_it_back(kernel):
    """A device whose 1005h makes it the SYNC producer, ``sync_by_interface=True``: its
    broadcast manager task starts after its boot-up; the kernel's SYNC, looped back to the
    device's own socket, triggers its synchronous TPDO; stopped, the task is deleted."""
    kernel.start_vcan()
    b = DictionaryBuilder(device_name="producer")
    b.variable(0x2000, "Counter", DataType.UNSIGNED16, access="ro", mappable=True)
    b.tpdo(1, [(0x2000, 0)], transmission_type=1)  # every SYNC

    async def main() -> None:
        async with (
            AsyncNetwork(interface="socketcan", channel="vcan0") as field,
            AsyncNetwork(interface="socketcan", channel="vcan0") as master,
        ):
            device = add_device(field, 5, b.build(), sync_by_interface=True)
            heard: list[int] = []
            master.subscribe(0x80, lambda f, now: heard.append(0x80))
            master.subscribe(0x185, lambda f, now: heard.append(0x185))
            master.nmt.start(5)
            device.set(0x1005, 0, 0x40000080)
            device.set(0x1006, 0, 5000)  # 5 ms
            await _until(lambda: heard.count(0x185) >= 3)  # its TPDO on each SYNC
            assert heard.count(0x80) >= 3
            setups = [op for op in kernel.ops if op.opcode == TX_SETUP]
            assert setups[-1].ival2_us == 5000
            master.nmt.stop(5)
            await _until(lambda: kernel.ops[-1].opcode == TX_DELETE)
            assert kernel.ops[-1].task_id == setups[-1].task_id

    _real_time(main)


def test_a_broadcast_manager_that_refuses_the_task_is_a_clear_error(kernel):
    """The kernel refusing TX_SETUP (here: its socket gone; on a host, an interface that is
    down) raises InterfaceTimingError naming the frame, and no SYNC is left running."""

    async def main() -> None:
        async with AsyncNetwork(interface="socketcan", channel="vcan0") as net:
            net.sync.start(0.01, by_interface=True)
            net.sync.stop()
            kernel.bcm[0].close()
            with pytest.raises(InterfaceTimingError, match="refused to send frame 0x80"):
                net.sync.start(0.01, overflow=4, by_interface=True)
            assert _state(net.sync) == (False, False, None)
            net.sync.start(0.01)  # the loop's producer still can
            assert _state(net.sync) == (True, False, 0.01)
            net.sync.stop()

    _real_time(main)
