"""Frames per second through the receive path: python-can message in, handler called.

Four figures, each side by side with python-canopen in the same run:
- dispatch only: messages already read from the interface, through each stack's receive path
  to a subscribed handler (cobus: message -> Frame -> dispatch table; python-canopen: its
  python-can listener -> Network.notify);
- end to end on python-can's virtual bus: frames waiting in the interface's queue, read by each
  stack's own reader and dispatched, until the handler has seen them all;
- a device serving expedited reads: an upload request already read, through each stack's
  receive path to its SDO server (cobus ``Device``, python-canopen ``LocalNode``) and the
  answer handed to the interface (python-can's virtual bus, nobody else on it) — a device's
  own share of every SDO round trip (issue 20);
- a blocking client's own work per expedited read: ``sdo.upload`` of the blocking API, the
  answer fed through each stack's receive path from the interface's send, all in one thread
  (cobus: a blocking ``Network`` whose reader thread is stopped, the answer dispatched
  under the protocol lock the caller holds; python-canopen: ``RemoteNode.sdo.upload``
  through its ``MessageListener``) — the client's share, its facade included.
"""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Callable

import can
import canopen

from benchmarks.common import (
    best_of,
    canopen_device_type_od,
    cobus_receive_rate,
    header,
    row,
)
from cobus.device import Device, minimal_od
from cobus.runtime import AsyncNetwork, Network

N = 20_000


def _messages() -> list[can.Message]:
    return [
        can.Message(
            arbitration_id=0x181 + (i % 4), data=bytes([i & 0xFF] * 8), is_extended_id=False
        )
        for i in range(N)
    ]


def dispatch_cobus(msgs: list[can.Message]) -> float:
    count = [0]

    def handler(frame: object, now: float) -> None:
        count[0] += 1

    def setup(net: AsyncNetwork) -> None:
        for cob_id in range(0x181, 0x185):
            net.subscribe(cob_id, handler)

    return cobus_receive_rate(setup, msgs)


def dispatch_canopen(msgs: list[can.Message]) -> float:
    network = canopen.Network()
    count = [0]

    def handler(can_id: int, data: bytearray, timestamp: float) -> None:
        count[0] += 1

    for cob_id in range(0x181, 0x185):
        network.subscribe(cob_id, handler)
    listener = network.listeners[0]

    def run() -> None:
        for msg in msgs:
            listener.on_message_received(msg)

    return N / best_of(run)


_NODE = 5
_READ = can.Message(
    arbitration_id=0x600 + _NODE, data=bytes([0x40, 0, 0x10, 0, 0, 0, 0, 0]), is_extended_id=False
)


def serve_cobus() -> float:
    def setup(net: AsyncNetwork) -> None:
        Device(net, _NODE, minimal_od()).start()

    return cobus_receive_rate(setup, [_READ] * N)


def serve_canopen() -> float:
    network = canopen.Network()
    network.connect(interface="virtual", channel="bench-serve-canopen")
    network.add_node(canopen.LocalNode(_NODE, canopen_device_type_od()))
    listener = network.listeners[0]

    def run() -> None:
        for _ in range(N):
            listener.on_message_received(_READ)

    try:
        return N / best_of(run)
    finally:
        network.disconnect()


_ANSWER = can.Message(
    arbitration_id=0x580 + _NODE,
    data=bytes([0x43, 0, 0x10, 0, 0x91, 1, 0, 0]),
    is_extended_id=False,
)
_READS = 5_000


def cobus_client(channel: str) -> tuple[Network, Callable[[], object]]:
    """A blocking cobus ``Network`` whose interface's send dispatches the answer at once,
    its reader thread stopped, and one read through the blocking API, written as
    python-canopen's below (``node.sdo`` is read in the caller's thread: it never changes)."""
    net = Network(interface="virtual", channel=channel)
    aio = net.aio
    answer = [_ANSWER]
    aio.bus.send = lambda msg, timeout=None: aio._on_messages(answer)  # type: ignore[method-assign]
    aio._reader_stop.set()  # nothing arrives on the bus: the reader would only poll
    node = net.add_remote(_NODE)
    return net, lambda: node.sdo.upload(0x1000, 0)


def client_cobus() -> float:
    net, read = cobus_client("bench-client-cobus")

    def run() -> None:
        for _ in range(_READS):
            read()

    try:
        return _READS / best_of(run)
    finally:
        net.close()


def canopen_client(channel: str) -> tuple[canopen.Network, Callable[[], None]]:
    """python-canopen's ``RemoteNode`` and one read: the answer is fed through its listener
    from the interface's send, in the same thread."""
    network = canopen.Network()
    network.connect(interface="virtual", channel=channel)
    node = canopen.RemoteNode(_NODE, canopen.ObjectDictionary())
    network.add_node(node)
    listener = canopen.network.MessageListener(network)

    def send(msg: can.Message, timeout: float | None = None) -> None:
        listener.on_message_received(_ANSWER)  # the server's answer, at once

    assert network.bus is not None
    network.bus.send = send  # type: ignore[method-assign]
    return network, lambda: node.sdo.upload(0x1000, 0)


def client_canopen() -> float:
    network, read = canopen_client("bench-client-canopen")

    def run() -> None:
        for _ in range(_READS):
            read()

    try:
        return _READS / best_of(run)
    finally:
        network.disconnect()


def _fill(channel: str, msgs: list[can.Message]) -> None:
    sender = can.Bus(interface="virtual", channel=channel)
    for msg in msgs:
        sender.send(msg)
    sender.shutdown()


def end_to_end_cobus(msgs: list[can.Message]) -> float:
    async def main() -> float:
        bus = can.Bus(interface="virtual", channel="bench-e2e-cobus", rx_queue_size=0)
        _fill("bench-e2e-cobus", msgs)
        done = asyncio.get_running_loop().create_future()
        count = [0]

        def handler(frame: object, now: float) -> None:
            count[0] += 1
            if count[0] == N and not done.done():
                done.set_result(None)

        net = AsyncNetwork(bus)
        for cob_id in range(0x181, 0x185):
            net.subscribe(cob_id, handler)
        t0 = time.perf_counter()
        await net.connect()
        await done
        elapsed = time.perf_counter() - t0
        await net.disconnect()
        bus.shutdown()
        return elapsed

    return N / asyncio.run(main())


def end_to_end_canopen(msgs: list[can.Message]) -> float:
    bus = can.Bus(interface="virtual", channel="bench-e2e-canopen")
    _fill("bench-e2e-canopen", msgs)
    done = threading.Event()
    count = [0]

    def handler(can_id: int, data: bytearray, timestamp: float) -> None:
        count[0] += 1
        if count[0] == N:
            done.set()

    network = canopen.Network(bus)
    for cob_id in range(0x181, 0x185):
        network.subscribe(cob_id, handler)
    t0 = time.perf_counter()
    network.connect()
    done.wait(60)
    elapsed = time.perf_counter() - t0
    network.disconnect()
    return N / elapsed


def main() -> None:
    msgs = _messages()
    print(header(f"Dispatch ({N:,} frames, 4 COB-IDs)"))
    print(row("dispatch only", dispatch_cobus(msgs), dispatch_canopen(msgs), "frames/s", True))
    print(
        row(
            "end to end, virtual bus reader",
            max(end_to_end_cobus(msgs) for _ in range(3)),
            max(end_to_end_canopen(msgs) for _ in range(3)),
            "frames/s",
            True,
        )
    )
    print(row("a device serving expedited reads", serve_cobus(), serve_canopen(), "req/s", True))
    print(
        row(
            "a blocking client's own work per read",
            client_cobus(),
            client_canopen(),
            "reads/s",
            True,
        )
    )


if __name__ == "__main__":
    main()
