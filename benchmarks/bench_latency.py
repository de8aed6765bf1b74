"""Round-trip latency of one expedited SDO upload, and how many times a thread sleeps and is
woken for it, in every arrangement of client and server (issue 20: the real-time path).

All peers run in this process on python-can's ``virtual`` bus in real time. Each arrangement
is timed over the same number of trips in interleaved rounds (so a noisy moment hits all of
them alike); the figures are medians of the rounds, the ratios paired per round against
python-canopen at both ends. "Wake-ups" are the process's voluntary context switches per trip
(``getrusage``): each is a thread that blocked and was woken — the hand-overs between the
user's thread, the loop, the bus's reader threads and back.

- bare python-can: a thread answers each frame at once — the floor any stack stands on;
- python-canopen at both ends: its client (``RemoteNode``) against its server (``LocalNode``);
- cobus blocking client against a cobus device, each on its own ``Network``;
- cobus asyncio client against a cobus device, both ``AsyncNetwork`` on one loop;
- the two mixed pairs;
- the blocking facade alone: a call from the user's thread run on the loop and back, no bus.

Then the same over python-can-remote on 127.0.0.1 between two processes (a cobus device on
node 5, a python-canopen ``LocalNode`` on node 6 and a bare python-can thread answering
node 7 in a child process; the clients here, each on its own connection opened for its
measurement, so that no other client of this process wakes for its frames).
Last, 4 KiB uploads by blocking clients in one process: segmented at both ends, and block
transfer against a cobus device (python-canopen's server has none).
"""

from __future__ import annotations

import asyncio
import contextlib
import importlib.util
import os
import resource
import socket
import statistics
import subprocess
import sys
import textwrap
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import can
import canopen
from canopen.sdo.client import BlockUploadStream

from benchmarks.common import canopen_device_type_od
from cobus.device import DictionaryBuilder, add_device, minimal_od
from cobus.od import DataType, ObjectDictionary
from cobus.runtime import AsyncNetwork, Network, run

NODE = 5
TRIPS = 400
ROUNDS = 7
REQUEST = can.Message(arbitration_id=0x600 + NODE, data=bytes([0x40, 0, 0x10, 0, 0, 0, 0, 0]))


#: Per trip: microseconds, voluntary context switches of this process (its threads' sleeps),
#: and microseconds of CPU this process used (all its threads; in one process, the server's
#: too).
Measured = tuple[float, float, float]


def _switches() -> int:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_nvcsw


def _measure(trip: Callable[[], object], trips: int = TRIPS) -> Measured:
    """Microseconds, voluntary context switches and CPU microseconds per trip, over
    ``trips`` trips."""
    trip()  # warm
    s0, c0, t0 = _switches(), time.process_time(), time.perf_counter()
    for _ in range(trips):
        trip()
    elapsed = time.perf_counter() - t0
    cpu = time.process_time() - c0
    return elapsed / trips * 1e6, (_switches() - s0) / trips, cpu / trips * 1e6


class _PingPong:
    """Bare python-can: a thread answers every request frame at once."""

    def __init__(self, channel: str) -> None:
        self.client = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
        self.server = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()
        self._reply = can.Message(arbitration_id=0x580 + NODE, data=bytes(8))

    def _serve(self) -> None:
        while not self._stop.is_set():
            if self.server.recv(0.1) is not None:
                self.server.send(self._reply)

    def trip(self) -> None:
        self.client.send(REQUEST)
        assert self.client.recv(1.0) is not None

    def close(self) -> None:
        self._stop.set()
        self._thread.join()
        self.client.shutdown()
        self.server.shutdown()


def _canopen_server(channel: str) -> canopen.Network:
    net = canopen.Network()
    net.connect(interface="virtual", channel=channel)
    net.add_node(canopen.LocalNode(NODE, canopen_device_type_od()))
    return net


def _canopen_client(channel: str) -> tuple[canopen.Network, Any]:
    net = canopen.Network()
    net.connect(interface="virtual", channel=channel)
    node: Any = canopen.RemoteNode(NODE, canopen.ObjectDictionary())
    net.add_node(node)
    return net, node


def _asyncio_round(
    interface: str, channel: str, *, device_here: bool, cobus_loop: bool
) -> Measured:
    """cobus asyncio client against a cobus device (on a second network of the same loop when
    ``device_here``), set up outside the timing; on asyncio's own loop (``asyncio.run``), or
    on cobus's ``RealTimeLoop`` (``cobus.runtime.run``) with its reader threads dispatching."""

    async def main() -> Measured:
        async with contextlib.AsyncExitStack() as stack:
            net = await stack.enter_async_context(
                AsyncNetwork(interface=interface, channel=channel)
            )
            if device_here:
                field = await stack.enter_async_context(
                    AsyncNetwork(interface=interface, channel=channel)
                )
                add_device(field, NODE, minimal_od())
            sdo = net.add_remote(NODE).sdo
            await sdo.upload(0x1000)
            s0, c0, t0 = _switches(), time.process_time(), time.perf_counter()
            for _ in range(TRIPS):
                await sdo.upload(0x1000)
            elapsed = time.perf_counter() - t0
            cpu = time.process_time() - c0
            return elapsed / TRIPS * 1e6, (_switches() - s0) / TRIPS, cpu / TRIPS * 1e6

    return run(main()) if cobus_loop else asyncio.run(main())


ASYNCIO_ROUNDS = {
    "cobus asyncio client, cobus device (asyncio.run)": False,
    "the same on cobus.runtime.run (RealTimeLoop)": True,
}


def _interleave(
    trips: dict[str, Callable[[], object]], asyncio_round: Callable[[bool], Measured]
) -> dict[str, list[Measured]]:
    """ROUNDS rounds, each timing every blocking arrangement, then the asyncio ones."""
    out: dict[str, list[Measured]] = {name: [] for name in trips}
    out.update({name: [] for name in ASYNCIO_ROUNDS})
    for _ in range(ROUNDS):
        for name, trip in trips.items():
            out[name].append(_measure(trip))
        for name, cobus_loop in ASYNCIO_ROUNDS.items():
            out[name].append(asyncio_round(cobus_loop))
    return out


def _cobus_pair(channel: str, od: ObjectDictionary) -> tuple[Network, Network, Any]:
    """A blocking client and a cobus device on node NODE, each on its own network; the
    client's SDO channel to it."""
    client = Network(interface="virtual", channel=channel)
    server = Network(interface="virtual", channel=channel)
    add_device(server, NODE, od)
    return client, server, client.add_remote(NODE).sdo


def figures() -> dict[str, list[Measured]]:
    """Per arrangement, the (µs, wake-ups) of each round."""
    pid = os.getpid()
    ping = _PingPong(f"lat-ping-{pid}")
    co_server = _canopen_server(f"lat-co-{pid}")
    co_net, co_node = _canopen_client(f"lat-co-{pid}")
    cob_client, cob_server, cob_sdo = _cobus_pair(f"lat-cob-{pid}", minimal_od())
    mixed_co_server = _canopen_server(f"lat-m1-{pid}")
    mixed_cob_client = Network(interface="virtual", channel=f"lat-m1-{pid}")
    mixed_sdo = mixed_cob_client.add_remote(NODE).sdo
    mixed_cob_server = Network(interface="virtual", channel=f"lat-m2-{pid}")
    add_device(mixed_cob_server, NODE, minimal_od())
    mixed_co_net, mixed_co_node = _canopen_client(f"lat-m2-{pid}")

    async def nothing() -> None:
        return None

    runner = cob_client._runner  # what every blocking property and plain method goes through

    trips: dict[str, Callable[[], object]] = {
        "bare python-can ping-pong": ping.trip,
        "python-canopen at both ends": lambda: co_node.sdo.upload(0x1000, 0),
        "cobus blocking client, cobus device": lambda: cob_sdo.upload(0x1000),
        "cobus blocking client, canopen server": lambda: mixed_sdo.upload(0x1000),
        "canopen client, cobus device": lambda: mixed_co_node.sdo.upload(0x1000, 0),
        "facade: coroutine on the loop and back": lambda: cob_client.run(nothing()),
        "facade: plain call on the loop and back": lambda: runner.call(int),
    }
    try:
        return _interleave(
            trips,
            lambda cobus_loop: _asyncio_round(
                "virtual", f"lat-aio-{pid}", device_here=True, cobus_loop=cobus_loop
            ),
        )
    finally:
        ping.close()
        for net in (co_net, co_server, mixed_co_server, mixed_co_net):
            net.disconnect()
        for cob in (cob_client, cob_server, mixed_cob_client, mixed_cob_server):
            cob.close()


BLOB = bytes(range(256)) * 16  # 4 KiB
BLOB_TRIPS = 10


def _blob_od() -> ObjectDictionary:
    b = DictionaryBuilder(device_name="bench")
    b.variable(0x2000, "Blob", DataType.DOMAIN, default=BLOB)
    return b.build()


def _canopen_blob_server(channel: str) -> canopen.Network:
    od = canopen.ObjectDictionary()
    var = canopen.objectdictionary.ODVariable("Blob", 0x2000, 0)
    var.data_type = canopen.objectdictionary.datatypes.DOMAIN
    var.access_type = "rw"
    od.add_object(var)
    net = canopen.Network()
    net.connect(interface="virtual", channel=channel)
    node = canopen.LocalNode(NODE, od)
    net.add_node(node)
    node.sdo.download(0x2000, 0, BLOB)
    return net


def blob_figures() -> dict[str, list[Measured]]:
    """4 KiB uploads, blocking clients: segmented at both ends, and block against a cobus
    device (python-canopen's server has no block transfer)."""
    pid = os.getpid()
    co_server = _canopen_blob_server(f"blob-co-{pid}")
    co_net, co_node = _canopen_client(f"blob-co-{pid}")
    cob_client, cob_server, cob_sdo = _cobus_pair(f"blob-cob-{pid}", _blob_od())
    block_server = Network(interface="virtual", channel=f"blob-blk-{pid}")
    add_device(block_server, NODE, _blob_od())
    block_net, block_node = _canopen_client(f"blob-blk-{pid}")

    def canopen_block() -> bytes:
        with BlockUploadStream(block_node.sdo, 0x2000, 0) as stream:
            return bytes(stream.read())

    trips: dict[str, Callable[[], object]] = {
        "python-canopen at both ends": lambda: co_node.sdo.upload(0x2000, 0),
        "cobus at both ends, segmented": lambda: cob_sdo.upload(0x2000),
        "python-canopen client, cobus device, block": canopen_block,
        "cobus at both ends, block": lambda: cob_sdo.upload(0x2000, block=True),
    }
    assert all(trip() == BLOB for trip in trips.values())
    out: dict[str, list[Measured]] = {name: [] for name in trips}
    try:
        for _ in range(ROUNDS):
            for name, trip in trips.items():
                out[name].append(_measure(trip, BLOB_TRIPS))
        return out
    finally:
        for net in (co_net, co_server, block_net):
            net.disconnect()
        for cob in (cob_client, cob_server, block_server):
            cob.close()


_SERVERS = textwrap.dedent(
    """
    import sys, threading
    import can
    import canopen
    from cobus.device import add_device, minimal_od
    from cobus.runtime import Network
    from benchmarks.bench_latency import PONG_NODE
    from benchmarks.common import canopen_device_type_od

    stop = threading.Event()

    def pong(bus):  # bare python-can: answer node PONG_NODE's requests at once
        reply = can.Message(arbitration_id=0x580 + PONG_NODE, data=bytes(8))
        while not stop.is_set():
            msg = bus.recv(0.1)
            if msg is not None and msg.arbitration_id == 0x600 + PONG_NODE:
                bus.send(reply)

    interface, channel = sys.argv[1], sys.argv[2]
    with Network(interface=interface, channel=channel) as net:
        add_device(net, 5, minimal_od())
        co = canopen.Network()
        co.connect(interface=interface, channel=channel)
        co.add_node(canopen.LocalNode(6, canopen_device_type_od()))
        bare = can.Bus(interface=interface, channel=channel)
        ponger = threading.Thread(target=pong, args=(bare,))
        ponger.start()
        print("ready", flush=True)
        sys.stdin.read()
        stop.set()
        ponger.join()
        bare.shutdown()
        co.disconnect()
    """
)
PONG_NODE = 7


class _RemotePing:
    """Bare python-can between processes: the child process's thread answers."""

    def __init__(self, interface: str, channel: str) -> None:
        self.bus = can.Bus(interface=interface, channel=channel)
        self._request = can.Message(arbitration_id=0x600 + PONG_NODE, data=bytes(8))

    def trip(self) -> None:
        self.bus.send(self._request)
        while True:
            msg = self.bus.recv(1.0)
            assert msg is not None, "no pong"
            if msg.arbitration_id == 0x580 + PONG_NODE:
                return

    def close(self) -> None:
        self.bus.shutdown()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def remote_figures() -> dict[str, list[Measured]] | None:
    """The clients here, the servers in a child process, over python-can-remote."""
    with remote_servers() as url:
        if url is None:
            return None
        return _interleave_connected(_remote_arrangements("remote", url), "remote", url)


@contextlib.contextmanager
def remote_servers() -> Iterator[str | None]:
    """A python-can-remote hub on 127.0.0.1 and the servers' child process (_SERVERS) on it:
    the hub's URL, or None when the servers could not start."""
    port = _free_port()
    where = ["-H", "127.0.0.1", "-p", str(port)]
    hub = subprocess.Popen(
        [sys.executable, "-m", "can_remote", "-i", "virtual", "-c", f"lat{port}", *where],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    url = f"ws://127.0.0.1:{port}/"
    servers = None
    try:
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", port), 0.2):
                break
            time.sleep(0.05)
        servers = _start_servers("remote", url)
        yield None if servers is None else url
    finally:
        if servers is not None:
            _stop_servers(servers)
        hub.terminate()
        hub.wait(15)


def _start_servers(interface: str, channel: str) -> subprocess.Popen[str] | None:
    """The servers' child process (_SERVERS) on ``channel``, once it says it is ready."""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    servers = subprocess.Popen(
        [sys.executable, "-c", _SERVERS, interface, channel],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
        cwd=root,
    )
    assert servers.stdout is not None
    if servers.stdout.readline().strip() != "ready":
        _stop_servers(servers)
        return None
    return servers


def _stop_servers(servers: subprocess.Popen[str]) -> None:
    if servers.stdin is not None:
        servers.stdin.close()  # the child's cue to stop
    servers.wait(15)


def multicast_figures() -> dict[str, list[Measured]] | None:
    """The clients here, the servers in a child process, over python-can's udp_multicast
    (no hub: each process's socket hears the others; cobus reads it on the loop)."""
    with multicast_servers() as group:
        if group is None:
            return None
        arrangements = _remote_arrangements("udp_multicast", group)
        return _interleave_connected(arrangements, "udp_multicast", group)


@contextlib.contextmanager
def multicast_servers() -> Iterator[str | None]:
    """The servers' child process (_SERVERS) on python-can's udp_multicast: the group, or
    None where it cannot run (no msgpack, no multicast)."""
    if importlib.util.find_spec("msgpack") is None:  # python-can's udp_multicast packs with it
        yield None
        return
    from can.interfaces.udp_multicast import UdpMulticastBus

    group = UdpMulticastBus.DEFAULT_GROUP_IPv6
    servers = _start_servers("udp_multicast", group)
    if servers is None:
        yield None
        return
    try:
        yield group
    finally:
        _stop_servers(servers)


Arrangement = Callable[[], tuple[Callable[[], object], Callable[[], object]]]


def _remote_arrangements(interface: str, url: str) -> dict[str, Arrangement]:
    """Each arrangement opens its own connection to the hub for its measurement and closes
    it after, so that no other client of this process hears (and wakes for) its frames."""

    def bare() -> tuple[Callable[[], object], Callable[[], object]]:
        ping = _RemotePing(interface, url)
        return ping.trip, ping.close

    def canopen_to(node_id: int) -> Arrangement:
        def open_() -> tuple[Callable[[], object], Callable[[], object]]:
            net = canopen.Network()
            net.connect(interface=interface, channel=url)
            node: Any = canopen.RemoteNode(node_id, canopen.ObjectDictionary())
            net.add_node(node)
            return (lambda: node.sdo.upload(0x1000, 0)), net.disconnect

        return open_

    def cobus_to(node_id: int) -> Arrangement:
        def open_() -> tuple[Callable[[], object], Callable[[], object]]:
            net = Network(interface=interface, channel=url)
            sdo = net.add_remote(node_id).sdo
            return (lambda: sdo.upload(0x1000)), net.close

        return open_

    return {
        "bare python-can ping-pong": bare,
        "python-canopen at both ends": canopen_to(6),
        "cobus blocking client, cobus device": cobus_to(NODE),
        "cobus blocking client, canopen server": cobus_to(6),
        "canopen client, cobus device": canopen_to(NODE),
    }


def _interleave_connected(
    arrangements: dict[str, Arrangement], interface: str, url: str
) -> dict[str, list[Measured]]:
    out: dict[str, list[Measured]] = {name: [] for name in arrangements}
    out.update({name: [] for name in ASYNCIO_ROUNDS})
    for _ in range(ROUNDS):
        for name, open_ in arrangements.items():
            trip, close = open_()
            try:
                out[name].append(_measure(trip))
            finally:
                close()
        for name, cobus_loop in ASYNCIO_ROUNDS.items():
            out[name].append(
                _asyncio_round(interface, url, device_here=False, cobus_loop=cobus_loop)
            )
    return out


def _table(title: str, results: dict[str, list[Measured]], trips: int = TRIPS) -> None:
    base = results["python-canopen at both ends"]
    print(f"\n{title} ({ROUNDS} interleaved rounds of {trips} trips; medians)")
    print(f"  {'':<50} {'µs/trip':>9} {'wake-ups':>9} {'CPU µs':>7} {'vs python-canopen':>18}")
    for name, rounds in results.items():
        us = statistics.median(r[0] for r in rounds)
        wakes = statistics.median(r[1] for r in rounds)
        cpu = statistics.median(r[2] for r in rounds)
        if name.startswith("facade"):
            ratio = ""
        else:
            paired = [b[0] / r[0] for r, b in zip(rounds, base, strict=True)]
            ratio = f"x{statistics.median(paired):.2f}"
        print(f"  {name:<50} {us:>9.1f} {wakes:>9.1f} {cpu:>7.0f} {ratio:>18}")


def main() -> None:
    _table("SDO expedited round trip, one process, virtual bus, real time", figures())
    remote = remote_figures()
    if remote is not None:
        _table("The same between two processes through python-can-remote (127.0.0.1)", remote)
    multicast = multicast_figures()
    if multicast is not None:
        _table("The same through python-can's udp_multicast (no hub; msgpack)", multicast)
    blobs = blob_figures()
    _table("4 KiB upload, blocking clients, one process (per upload)", blobs, BLOB_TRIPS)
    theirs, ours = (
        blobs["python-canopen client, cobus device, block"],
        blobs["cobus at both ends, block"],
    )
    paired = statistics.median(t[0] / o[0] for t, o in zip(theirs, ours, strict=True))
    print(f"  (block: cobus at both ends x{paired:.2f} of python-canopen's client, same device)")
    print("  (x > 1: faster than python-canopen at both ends, paired per round; the targets:")
    print("   x1.0 for every cobus arrangement, x1.15 for the asyncio client where the bus has a")
    print("   file descriptor, x1.5 for block upload)")
    print("  (wake-ups: voluntary context switches of this process per trip; over")
    print("   python-can-remote each client here is alone in this process while measured;")
    print("   CPU µs: what all threads of this process used per trip, servers included in")
    print("   the one-process tables)")


if __name__ == "__main__":
    main()
