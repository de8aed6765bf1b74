"""Where one expedited SDO round trip spends its time, hop by hop (issue 20), beside
python-canopen's path and a bare python-can ping-pong.

Every stack reaches the bus through python-can, so the trip is cut where a frame crosses
python-can: each bus object's ``send`` and ``recv`` are wrapped to note the time
(``perf_counter_ns``) when the request or the answer is handed to the interface and when it
is read from it. Per trip:

1. caller -> request handed to the interface: the client stack's way out (cobus: the
   blocking call begins the transfer in the caller's thread; python-canopen: its
   ``upload`` sends there too);
2. request handed over -> read by the server: python-can's ``virtual`` bus (its ``send``
   copies the message for each receiver) and the wake-up of the server's reading thread;
3. the server's work: read -> answer handed to the interface (cobus device, python-canopen
   ``LocalNode`` or the bare thread);
4. answer handed over -> read on the client's side: the bus again and the wake-up of the
   client's reading thread (the caller itself in the bare ping-pong);
5. answer read -> the caller has its value: the client stack's way in and the hand-over to
   the waiting caller (none in the bare ping-pong, which reads in the caller).

All in this process on ``virtual`` buses in real time, one arrangement after the other in
interleaved rounds; medians of every trip per hop (the hops' medians need not add up to the
total's). The asyncio client runs on ``cobus.runtime.run`` with the device on a second
network of the same loop (hop 5 is then the reader thread's dispatch and the loop's wake-up
to resume the awaiting task). Then the clients' side over python-can-remote, with
``bench_latency``'s servers in a child process: hops 1 and 5, and 2-4 as one; then the same
through python-can's ``udp_multicast``. There each client is connected only while measured
(every connection hears every frame). A wrapper costs
each stack the same, about half a microsecond per stamp. Run alone:
``python -m benchmarks.bench_hops``.
"""

from __future__ import annotations

import functools
import itertools
import os
import statistics
import time
from collections.abc import Callable
from typing import Any

import can
import canopen

from benchmarks.bench_latency import (
    NODE,
    PONG_NODE,
    _canopen_client,
    _canopen_server,
    _cobus_pair,
    _PingPong,
    _RemotePing,
    multicast_servers,
    remote_servers,
)
from benchmarks.bench_latency import Arrangement as Opener
from cobus.device import add_device, minimal_od
from cobus.runtime import AsyncNetwork, Network, run

TRIPS = 300
ROUNDS = 5
HOPS = (
    "1. caller -> request handed to the interface",
    "2. the bus, the server's reader wakes",
    "3. the server's work",
    "4. the bus, the client's reader wakes",
    "5. answer read -> the caller has it",
)
REMOTE_HOPS = (
    HOPS[0],
    "2-4. to the server's process and back",
    HOPS[4],
)


class _Trip:
    """The time stamps of the trip under way (ns): request sent and read, answer sent and
    read."""

    __slots__ = ("ans_rx", "ans_tx", "req_rx", "req_tx")

    def __init__(self) -> None:
        self.req_tx = self.req_rx = self.ans_tx = self.ans_rx = 0


def _watch(
    bus: can.BusABC | None, trip: _Trip, *, client: bool, node: int = NODE, sender: Any = None
) -> None:
    """Stamp the request to and the answer of ``node`` where they cross ``bus`` (one object:
    the wrappers are attributes of the instance, found before the class's methods), and
    where ``sender`` sends when it is not the bus (a cobus network's echo-free sender on
    ``udp_multicast``)."""
    assert bus is not None, "a network not connected"
    clock = time.perf_counter_ns
    sender = bus if sender is None else sender
    send, recv = sender.send, bus.recv
    request, answer = 0x600 + node, 0x580 + node
    sent_id, read_id = (request, answer) if client else (answer, request)

    def stamped_send(msg: can.Message, timeout: float | None = None) -> None:
        if msg.arbitration_id == sent_id:
            now = clock()
            if client:
                trip.req_tx = now
            else:
                trip.ans_tx = now
        send(msg, timeout)

    def stamped_recv(timeout: float | None = None) -> can.Message | None:
        msg = recv(timeout)
        if msg is not None and msg.arbitration_id == read_id:
            now = clock()
            if client:
                trip.ans_rx = now
            else:
                trip.req_rx = now
        return msg

    sender.send = stamped_send
    bus.recv = stamped_recv  # type: ignore[method-assign]


#: An arrangement: a round of ``n`` trips (per trip the hops and the total, in ns) and how to
#: close it.
Arrangement = tuple[Callable[[int], list[tuple[int, ...]]], Callable[[], None]]


def _blocking(call: Callable[[], object], trip: _Trip, close: Callable[[], None]) -> Arrangement:
    """A blocking client and its server, both in this process and kept for every round."""
    return functools.partial(_round, call, trip), close


def _both(first: Callable[[], object], second: Callable[[], object]) -> Callable[[], None]:
    """Close a client and its server."""

    def close() -> None:
        first()
        second()

    return close


def _arrangements(trip: _Trip) -> dict[str, Arrangement]:
    """Each arrangement's trip and how to close it, its buses watched."""
    pid = os.getpid()
    out: dict[str, Arrangement] = {}

    ping = _PingPong(f"hops-ping-{pid}")
    _watch(ping.client, trip, client=True)
    _watch(ping.server, trip, client=False)
    out["bare python-can ping-pong"] = _blocking(ping.trip, trip, ping.close)

    co_server = _canopen_server(f"hops-co-{pid}")
    co_net, co_node = _canopen_client(f"hops-co-{pid}")
    _watch(co_net.bus, trip, client=True)
    _watch(co_server.bus, trip, client=False)

    out["python-canopen at both ends"] = _blocking(
        lambda: co_node.sdo.upload(0x1000, 0), trip, _both(co_net.disconnect, co_server.disconnect)
    )

    cob_client, cob_server, cob_sdo = _cobus_pair(f"hops-cob-{pid}", minimal_od())
    _watch(cob_client.aio.bus, trip, client=True)
    _watch(cob_server.aio.bus, trip, client=False)

    out["cobus at both ends"] = _blocking(
        lambda: cob_sdo.upload(0x1000), trip, _both(cob_client.close, cob_server.close)
    )

    mixed_server = _canopen_server(f"hops-m1-{pid}")
    mixed_client = Network(interface="virtual", channel=f"hops-m1-{pid}")
    mixed_sdo = mixed_client.add_remote(NODE).sdo
    _watch(mixed_client.aio.bus, trip, client=True)
    _watch(mixed_server.bus, trip, client=False)

    out["cobus client, python-canopen server"] = _blocking(
        lambda: mixed_sdo.upload(0x1000), trip, _both(mixed_client.close, mixed_server.disconnect)
    )

    device_net = Network(interface="virtual", channel=f"hops-m2-{pid}")
    add_device(device_net, NODE, minimal_od())
    co_client, co_client_node = _canopen_client(f"hops-m2-{pid}")
    _watch(device_net.aio.bus, trip, client=False)
    _watch(co_client.bus, trip, client=True)

    out["python-canopen client, cobus device"] = _blocking(
        lambda: co_client_node.sdo.upload(0x1000, 0),
        trip,
        _both(co_client.disconnect, device_net.close),
    )
    out["cobus asyncio client, cobus device"] = (
        functools.partial(_asyncio_round, trip, f"hops-aio-{pid}"),
        lambda: None,
    )
    return out


def _asyncio_round(trip: _Trip, channel: str, trips: int) -> list[tuple[int, ...]]:
    """A round of the asyncio client against a cobus device on a second network of the same
    ``RealTimeLoop`` (``cobus.runtime.run``: the reader threads dispatch), set up for it."""
    clock = time.perf_counter_ns

    async def main() -> list[tuple[int, ...]]:
        async with (
            AsyncNetwork(interface="virtual", channel=channel) as net,
            AsyncNetwork(interface="virtual", channel=channel) as field,
        ):
            add_device(field, NODE, minimal_od())
            _watch(net.bus, trip, client=True)
            _watch(field.bus, trip, client=False)
            sdo = net.add_remote(NODE).sdo
            await sdo.upload(0x1000)  # warm
            out = []
            for _ in range(trips):
                trip.req_tx = trip.req_rx = trip.ans_tx = trip.ans_rx = 0
                start = clock()
                await sdo.upload(0x1000)
                end = clock()
                out.append(_hops((start, trip.req_tx, trip.req_rx, trip.ans_tx, trip.ans_rx, end)))
            return out

    return run(main())


def _hops(stamps: tuple[int, ...]) -> tuple[int, ...]:
    """The hops between ``stamps`` and the whole, in ns."""
    if 0 in stamps:  # (a stamp missed: a frame not seen where expected)
        raise RuntimeError(f"a trip crossed python-can without being stamped: {stamps}")
    return (*(b - a for a, b in itertools.pairwise(stamps)), stamps[-1] - stamps[0])


def _round(
    call: Callable[[], object], trip: _Trip, trips: int, *, server_here: bool = True
) -> list[tuple[int, ...]]:
    """``trips`` trips: per trip the hops and the total, in ns (hops 2-4 as one when the
    server is in another process)."""
    clock = time.perf_counter_ns
    call()  # warm
    out = []
    for _ in range(trips):
        trip.req_tx = trip.req_rx = trip.ans_tx = trip.ans_rx = 0
        start = clock()
        call()
        end = clock()
        stamps: tuple[int, ...]
        if server_here:
            stamps = (start, trip.req_tx, trip.req_rx, trip.ans_tx, trip.ans_rx, end)
        else:
            stamps = (start, trip.req_tx, trip.ans_rx, end)
        out.append(_hops(stamps))
    return out


def _medians(
    arrangements: dict[str, Arrangement], trips: int, rounds: int
) -> dict[str, list[float]]:
    """Interleaved rounds of every arrangement, then closes them; per arrangement the median
    µs of each hop and of the whole trip."""
    samples: dict[str, list[tuple[int, ...]]] = {name: [] for name in arrangements}
    try:
        for _ in range(rounds):
            for name, (round_, _close) in arrangements.items():
                samples[name] += round_(trips)
    finally:
        for _, close in arrangements.values():
            close()
    return {
        name: [statistics.median(column) / 1000 for column in zip(*rows, strict=True)]
        for name, rows in samples.items()
    }


def figures(trips: int = TRIPS, rounds: int = ROUNDS) -> dict[str, list[float]]:
    """One process: per arrangement, the median µs of each hop and of the whole trip."""
    return _medians(_arrangements(_Trip()), trips, rounds)


def _alone(opener: Opener, trip: _Trip) -> Arrangement:
    """An arrangement whose client is connected only for its own rounds: every client's
    connection hears every frame, and an idle one would wake for the measured trips."""

    def round_(trips: int) -> list[tuple[int, ...]]:
        call, close = opener()
        try:
            return _round(call, trip, trips, server_here=False)
        finally:
            close()

    return round_, lambda: None


def _remote_arrangements(trip: _Trip, interface: str, channel: str) -> dict[str, Arrangement]:
    """The clients here, each on its own connection while measured; the servers in the
    child process of ``bench_latency`` (cobus device 5, python-canopen 6, bare thread 7)."""

    def bare() -> tuple[Callable[[], object], Callable[[], object]]:
        ping = _RemotePing(interface, channel)
        _watch(ping.bus, trip, client=True, node=PONG_NODE)
        return ping.trip, ping.close

    def canopen_to(node: int) -> Opener:
        def open_() -> tuple[Callable[[], object], Callable[[], object]]:
            net = canopen.Network()
            net.connect(interface=interface, channel=channel)
            remote: Any = canopen.RemoteNode(node, canopen.ObjectDictionary())
            net.add_node(remote)
            _watch(net.bus, trip, client=True, node=node)
            return functools.partial(remote.sdo.upload, 0x1000, 0), net.disconnect

        return open_

    def cobus_to(node: int) -> Opener:
        def open_() -> tuple[Callable[[], object], Callable[[], object]]:
            net = Network(interface=interface, channel=channel)
            _watch(net.aio.bus, trip, client=True, node=node, sender=net.aio._tx)
            return functools.partial(net.add_remote(node).sdo.upload, 0x1000), net.close

        return open_

    return {
        "bare python-can ping-pong": _alone(bare, trip),
        "python-canopen at both ends": _alone(canopen_to(6), trip),
        "python-canopen client, cobus device": _alone(canopen_to(NODE), trip),
        "cobus at both ends": _alone(cobus_to(NODE), trip),
        "cobus client, python-canopen server": _alone(cobus_to(6), trip),
    }


def remote_figures(trips: int = TRIPS, rounds: int = ROUNDS) -> dict[str, list[float]] | None:
    """Two processes through python-can-remote: the client's side of each trip (hops 1, 2-4
    and 5), or None where the servers cannot start."""
    with remote_servers() as url:
        if url is None:
            return None
        return _medians(_remote_arrangements(_Trip(), "remote", url), trips, rounds)


def multicast_figures(trips: int = TRIPS, rounds: int = ROUNDS) -> dict[str, list[float]] | None:
    """Two processes through python-can's ``udp_multicast`` (no hub): the client's side,
    or None where it cannot run (no msgpack, no multicast)."""
    with multicast_servers() as group:
        if group is None:
            return None
        return _medians(_remote_arrangements(_Trip(), "udp_multicast", group), trips, rounds)


def _table(title: str, hops: tuple[str, ...], results: dict[str, list[float]]) -> None:
    print(f"\n{title} ({ROUNDS} interleaved rounds of {TRIPS} trips; medians, µs)")
    print(f"  {'':<42}" + "".join(f"{n.split('.')[0] + '.':>9}" for n in hops) + f"{'trip':>9}")
    for name, medians in results.items():
        cells = "".join(f"{value:>9.1f}" for value in medians[:-1])
        print(f"  {name:<42}{cells}{medians[-1]:>9.1f}")
    print("  (" + "; ".join(hops) + ")")


def main() -> None:
    _table("One expedited SDO read, hop by hop, one process, virtual bus", HOPS, figures())
    remote = remote_figures()
    if remote is not None:
        _table(
            "The same between two processes through python-can-remote, the client's side",
            REMOTE_HOPS,
            remote,
        )
    multicast = multicast_figures()
    if multicast is not None:
        _table(
            "The same through python-can's udp_multicast (no hub), the client's side",
            REMOTE_HOPS,
            multicast,
        )
    print("  (the hops' medians need not add up to the trip's; python-canopen's figures are")
    print("   the ones to beat: each stack's own work is in hops 1, 3 and 5)")


if __name__ == "__main__":
    main()
