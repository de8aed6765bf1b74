"""Requests per second through the CiA 309-3 gateway beside a direct SDO client: 1000h reads
of cobus devices on python-can's virtual bus, in real time.

Rows: cobus's own SDO client (``SdoChannel.upload``), the same reads as gateway requests over
a TCP socket on 127.0.0.1 (one client; then four clients on four nodes side by side), and
python-canopen's SDO client reading the same device (the column on the right, where it has
a counterpart). What the gateway costs is the text round trip on top of the SDO transfer.
cobus's rows run the devices, the gateway and its clients on one event loop; python-canopen's
client runs in its own thread beside the device's loop, as it must.
"""

from __future__ import annotations

import asyncio
import os
import threading
import time

import canopen

from benchmarks.common import header, row
from cobus.apps.gateway import GatewayCore, GatewayServer
from cobus.device import add_device, minimal_od
from cobus.runtime import AsyncNetwork, SdoChannel

READS = 400
NODES = (5, 6, 7, 8)


async def _measure(channel: str) -> tuple[float, float, float]:
    async with AsyncNetwork(interface="virtual", channel=channel) as net:
        for node in NODES:
            add_device(net, node, minimal_od())
        direct = SdoChannel(net, NODES[0], None)
        t0 = time.perf_counter()
        for _ in range(READS):
            await direct.upload(0x1000, 0)
        direct_rate = READS / (time.perf_counter() - t0)
        direct.close()
        server = GatewayServer(GatewayCore({1: net}))
        await server.start()
        try:

            async def client(node: int) -> None:
                reader, writer = await asyncio.open_connection("127.0.0.1", server.port)
                for k in range(READS):
                    writer.write(f"[{k}] {node} r 0x1000 0 u32\n".encode())
                    await writer.drain()
                    reply = await reader.readline()
                    assert not reply.startswith(f"[{k}] ERROR".encode()), reply
                writer.close()

            t0 = time.perf_counter()
            await client(NODES[0])
            one_rate = READS / (time.perf_counter() - t0)
            t0 = time.perf_counter()
            await asyncio.gather(*(client(node) for node in NODES))
            four_rate = len(NODES) * READS / (time.perf_counter() - t0)
        finally:
            await server.stop()
    return direct_rate, one_rate, four_rate


def _canopen_rate(channel: str) -> float:
    """python-canopen's SDO client reading 1000h of a cobus device (its own thread)."""
    ready = threading.Event()
    done = threading.Event()

    def serve() -> None:
        async def device() -> None:
            async with AsyncNetwork(interface="virtual", channel=channel) as net:
                add_device(net, NODES[0], minimal_od())
                ready.set()
                while not done.is_set():
                    await asyncio.sleep(0.05)

        asyncio.run(device())

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    ready.wait(10)
    cnet = canopen.Network()
    cnet.connect(interface="virtual", channel=channel)
    try:
        node = cnet.add_node(NODES[0], canopen.ObjectDictionary())
        t0 = time.perf_counter()
        for _ in range(READS):
            node.sdo.upload(0x1000, 0)
        return READS / (time.perf_counter() - t0)
    finally:
        cnet.disconnect()
        done.set()
        thread.join(10)


def main() -> None:
    channel = f"bench-gateway-{os.getpid()}"
    direct, one, four = asyncio.run(_measure(channel))
    other = _canopen_rate(channel + "-canopen")
    print(header("CiA 309-3 gateway: 1000h reads per second, real time (higher is better)"))
    print(row("direct SDO client (canopen: its SDO client)", direct, other, "req/s", True))
    print(row("through the gateway, one TCP client", one, other, "req/s", True))
    print(row("through the gateway, 4 clients on 4 nodes", four, None, "req/s", True))
