"""Master boot-up: wall time to boot 127 simulated devices to operational.

The same network twice: on the simulated clock (virtual time jumps over every wait, so the
figure is pure processing) and on the real-time clock (python-can virtual bus, master and
devices in one process). Each device gets the full CiA 302-2 sequence: reset, boot-up,
1000h/1018h checks, PDO mapping, heartbeat, start. python-canopen has no NMT master boot-up
to compare with.
"""

from __future__ import annotations

import asyncio
import os
import tempfile
import time
from pathlib import Path

from benchmarks.common import header, row
from cobus.device import DictionaryBuilder, add_device, export_eds
from cobus.master import Master, NetworkConfig, NodeState, loads_network
from cobus.od import DataType, ObjectDictionary
from cobus.proto.nmt import NmtState
from cobus.runtime import AsyncNetwork, new_event_loop

NODES = 127
NODE = """  n{node_id}:
    node_id: {node_id}
    eds: io.eds
    mandatory: true
    device_type: 0x191
    vendor_id: 0xC0B
    heartbeat_time: 200
    tpdo1: {{mapping: [counter, status], transmission_type: 255}}
    rpdo1: {{mapping: [setpoint], transmission_type: 255}}
"""


def _od() -> ObjectDictionary:
    b = DictionaryBuilder(device_name="bench io", vendor_id=0xC0B)
    b.variable(0x2000, "Counter", DataType.UNSIGNED16, access="ro", mappable=True)
    b.variable(0x2001, "Status", DataType.UNSIGNED8, access="ro", mappable=True)
    b.variable(0x2002, "Setpoint", DataType.INTEGER16, access="rww", mappable=True)
    return b.build()


def _config(folder: Path) -> NetworkConfig:
    (folder / "io.eds").write_text(export_eds(_od()), encoding="utf-8")
    text = "master: {reset: broadcast, start: broadcast, sync_period: 20}\nnodes:\n"
    text += "".join(NODE.format(node_id=n) for n in range(1, NODES + 1))
    return loads_network(text, base_dir=folder)


async def _boot(net: AsyncNetwork, config: NetworkConfig) -> tuple[float, float, int]:
    devices = [add_device(net, n, _od()) for n in range(1, NODES + 1)]
    master = Master(net, config)
    wall = time.perf_counter()
    start = net.time()
    await master.boot(timeout=60)
    elapsed = time.perf_counter() - wall
    network_time = net.time() - start
    assert all(n.state is NodeState.OPERATIONAL for n in master.nodes.values())
    await asyncio.sleep(0.05)
    assert all(d.state is NmtState.OPERATIONAL for d in devices)
    frames = net.frames_sent
    await master.stop()
    for device in devices:
        device.close()
    return elapsed, network_time, frames


def simulated(config: NetworkConfig) -> tuple[float, float, int]:
    async def main() -> tuple[float, float, int]:
        async with AsyncNetwork() as net:
            return await _boot(net, config)

    loop = new_event_loop(simulated=True)
    try:
        return loop.run_until_complete(main())
    finally:
        loop.close()


def real_time(config: NetworkConfig) -> tuple[float, float, int]:
    async def main() -> tuple[float, float, int]:
        channel = f"bench-master-{os.getpid()}"
        async with AsyncNetwork(interface="virtual", channel=channel) as net:
            return await _boot(net, config)

    loop = new_event_loop()
    try:
        return loop.run_until_complete(main())
    finally:
        loop.close()


def main() -> None:
    with tempfile.TemporaryDirectory() as folder:
        config = _config(Path(folder))
        sim_wall, sim_virtual, sim_frames = simulated(config)
        rt_wall, _rt_network, rt_frames = real_time(config)
    print(header(f"Master: boot {NODES} devices to operational (CiA 302-2)"))
    print(row("simulated clock: wall time", sim_wall * 1000, None, "ms", False))
    print(row("simulated clock: network time", sim_virtual * 1000, None, "ms", False))
    print(row("simulated clock: frames", sim_frames, None, "frames", True))
    print(row("simulated clock: frames per wall second", sim_frames / sim_wall, None, "fr/s", True))
    print(row("real-time clock (virtual bus): wall time", rt_wall * 1000, None, "ms", False))
    print(row("real-time clock: frames", rt_frames, None, "frames", True))


if __name__ == "__main__":
    main()
