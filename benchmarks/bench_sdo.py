"""SDO throughput: expedited round trips per second, segmented and block kB/s.

cobus is measured three ways:
- in-process: client and server on one network (local echo), in real time — how a rig or a
  test bench runs master and simulated devices in one process;
- two networks on a python-can virtual channel in real time, each with its reader thread,
  with the asyncio client on ``cobus.runtime.run`` (readers dispatch directly; the blocking
  clients are measured in bench_latency.py);
- two networks on a python-can virtual channel on one simulated-clock loop (polled, no threads).
python-canopen runs its client against its own server (LocalNode) on the virtual bus, its only
way to run both peers in one process; its server has no block transfer, so its block figure is
its client against a cobus server.
"""

from __future__ import annotations

import os
import time
from typing import Any

import canopen

from benchmarks.common import header, row
from cobus.proto.sdo import DictBackend, SdoServer
from cobus.runtime import AsyncNetwork, Network, SimulatedEventLoop, run

NODE = 5
EXPEDITED = 2000
BLOB = bytes(range(256)) * 256  # 64 KiB
SEGMENTED_ROUNDS = 3


def _backend() -> DictBackend:
    return DictBackend({(0x1000, 0): b"\x91\x01\x00\x00", (0x2000, 0): BLOB})


async def _cobus_figures(net_a: AsyncNetwork, net_b: AsyncNetwork) -> dict[str, float]:
    net_b.attach(SdoServer(0x600 + NODE, 0x580 + NODE, _backend()), [0x600 + NODE])
    sdo = net_a.add_remote(NODE, sdo_timeout=5.0).sdo
    perf = time.perf_counter
    t0 = perf()
    for _ in range(EXPEDITED):
        await sdo.upload(0x1000)
    expedited = EXPEDITED / (perf() - t0)
    t0 = perf()
    for _ in range(SEGMENTED_ROUNDS):
        assert await sdo.upload(0x2000) == BLOB
    segmented = SEGMENTED_ROUNDS * len(BLOB) / 1024 / (perf() - t0)
    t0 = perf()
    for _ in range(SEGMENTED_ROUNDS):
        assert await sdo.upload(0x2000, block=True) == BLOB
    block = SEGMENTED_ROUNDS * len(BLOB) / 1024 / (perf() - t0)
    return {"expedited": expedited, "segmented": segmented, "block": block}


def cobus_simulated() -> dict[str, float]:
    async def main() -> dict[str, float]:
        channel = f"bs-sim-{os.getpid()}"
        async with (
            AsyncNetwork(interface="virtual", channel=channel) as a,
            AsyncNetwork(interface="virtual", channel=channel) as b,
        ):
            return await _cobus_figures(a, b)

    loop = SimulatedEventLoop()
    try:
        return loop.run_until_complete(main())
    finally:
        loop.close()


def cobus_real_time() -> dict[str, float]:
    async def main() -> dict[str, float]:
        channel = f"bs-rt-{os.getpid()}"
        async with (
            AsyncNetwork(interface="virtual", channel=channel) as a,
            AsyncNetwork(interface="virtual", channel=channel) as b,
        ):
            return await _cobus_figures(a, b)

    return run(main())


def cobus_in_process() -> dict[str, float]:
    async def main() -> dict[str, float]:
        async with AsyncNetwork(interface="virtual", channel=f"bs-one-{os.getpid()}") as net:
            return await _cobus_figures(net, net)

    return run(main())


def _canopen_od() -> canopen.ObjectDictionary:
    od = canopen.ObjectDictionary()
    types = canopen.objectdictionary.datatypes
    for index, data_type, default in (
        (0x1000, types.UNSIGNED32, 0x191),
        (0x2000, types.DOMAIN, BLOB),
    ):
        var = canopen.objectdictionary.ODVariable(f"v{index:X}", index, 0)
        var.data_type = data_type
        var.access_type = "rw"
        var.default = default  # type: ignore[assignment]
        od.add_object(var)
    return od


def canopen_figures() -> dict[str, float]:
    channel = f"bs-co-{os.getpid()}"
    server_net = canopen.Network()
    server_net.connect(interface="virtual", channel=channel)
    server_net.add_node(canopen.LocalNode(NODE, _canopen_od()))
    client_net = canopen.Network()
    client_net.connect(interface="virtual", channel=channel)
    node: Any = canopen.RemoteNode(NODE, canopen.ObjectDictionary())
    client_net.add_node(node)
    perf = time.perf_counter
    try:
        t0 = perf()
        for _ in range(EXPEDITED):
            node.sdo.upload(0x1000, 0)
        expedited = EXPEDITED / (perf() - t0)
        t0 = perf()
        for _ in range(SEGMENTED_ROUNDS):
            assert node.sdo.upload(0x2000, 0) == BLOB
        segmented = SEGMENTED_ROUNDS * len(BLOB) / 1024 / (perf() - t0)
    finally:
        client_net.disconnect()
        server_net.disconnect()
    return {"expedited": expedited, "segmented": segmented, "block": canopen_block()}


def canopen_block() -> float:
    """python-canopen's block upload client against a cobus server (its own has no block)."""
    channel = f"bs-cb-{os.getpid()}"
    with Network(interface="virtual", channel=channel) as server:
        server.run(_serve(server.aio))
        client_net = canopen.Network()
        client_net.connect(interface="virtual", channel=channel)
        node: Any = canopen.RemoteNode(NODE, canopen.ObjectDictionary())
        client_net.add_node(node)
        try:
            t0 = time.perf_counter()
            for _ in range(SEGMENTED_ROUNDS):
                with node.sdo.open(0x2000, 0, "rb", block_transfer=True) as f:
                    assert f.read() == BLOB
            return SEGMENTED_ROUNDS * len(BLOB) / 1024 / (time.perf_counter() - t0)
        finally:
            client_net.disconnect()


async def _serve(net: AsyncNetwork) -> None:
    net.attach(SdoServer(0x600 + NODE, 0x580 + NODE, _backend()), [0x600 + NODE])


def main() -> None:
    one = cobus_in_process()
    sim = cobus_simulated()
    real = cobus_real_time()
    other = canopen_figures()
    print(header(f"SDO throughput (virtual bus; {len(BLOB) // 1024} KiB object)"))
    for key, unit in (("expedited", "trips/s"), ("segmented", "kB/s"), ("block", "kB/s")):
        print(row(f"{key}, in-process (one network)", one[key], other[key], unit, True))
    for key, unit in (("expedited", "trips/s"), ("segmented", "kB/s"), ("block", "kB/s")):
        print(row(f"{key}, real time (reader threads)", real[key], other[key], unit, True))
    for key, unit in (("expedited", "trips/s"), ("segmented", "kB/s"), ("block", "kB/s")):
        print(row(f"{key}, simulated clock (one loop)", sim[key], other[key], unit, True))
    print("  (python-canopen block: its client against a cobus server; its server has none)")
    print("  (two networks in real time: the asyncio client on cobus.runtime.run; its reader")
    print("   threads dispatch directly, and the answer wakes the loop for the client's task)")
    print("  (the 1 Mbit/s wire carries at most ~62 kB/s of SDO payload)")


if __name__ == "__main__":
    main()
