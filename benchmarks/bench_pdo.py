"""TPDOs decoded into named values by a remote node, frames per second.

Both stacks know the simulated CiA 402 servo's mapping (from its EDS) and receive its TPDO 2
(statusword + position actual value, 6 bytes): cobus ``node.tpdo[2]`` with a callback,
python-canopen ``node.tpdo[2]`` with a callback. The messages are already read from the
interface; each goes through each stack's receive path, is decoded, and reaches the callback
with the values by name.
"""

from __future__ import annotations

import can
import canopen

from benchmarks.common import best_of, cobus_receive_rate, header, row
from cobus.device import export_eds
from cobus.runtime import AsyncNetwork, PdoReceived, SimulatedEventLoop
from cobus.sim import SimulatedDrive402

N = 20_000
NODE = 10


def _eds(tmp: str) -> str:
    async def export() -> str:
        async with AsyncNetwork() as net:
            return export_eds(SimulatedDrive402(net, NODE).od)

    loop = SimulatedEventLoop()
    text = loop.run_until_complete(export())
    loop.close()
    path = f"{tmp}/servo.eds"
    with open(path, "w") as f:
        f.write(text)
    return path


def _messages() -> list[can.Message]:
    return [
        can.Message(
            arbitration_id=0x280 + NODE,
            data=(0x0237).to_bytes(2, "little") + i.to_bytes(4, "little", signed=True),
            is_extended_id=False,
        )
        for i in range(N)
    ]


def cobus_rate(eds: str, msgs: list[can.Message]) -> float:
    seen = [0]

    def callback(event: PdoReceived) -> None:
        seen[0] += event.values["Position actual value"] >= 0

    def setup(net: AsyncNetwork) -> None:
        node = net.add_remote(NODE, eds)
        node.tpdo.load_from_od()
        node.tpdo[2].add_callback(callback)

    return cobus_receive_rate(setup, msgs)


def canopen_rate(eds: str, msgs: list[can.Message]) -> float:
    network = canopen.Network()
    node = network.add_node(NODE, eds)
    node.tpdo.read(from_od=True)
    seen = [0]

    def callback(pdo: canopen.pdo.PdoBase) -> None:
        seen[0] += pdo["Position actual value"].raw >= 0

    node.tpdo[2].add_callback(callback)
    listener = network.listeners[0]

    def run() -> None:
        for msg in msgs:
            listener.on_message_received(msg)

    return N / best_of(run)


def main() -> None:
    import tempfile

    msgs = _messages()
    with tempfile.TemporaryDirectory() as tmp:
        eds = _eds(tmp)
        print(header(f"TPDO reception by a remote node ({N:,} frames, 2 named values)"))
        print(
            row(
                "decoded, callback with values by name",
                cobus_rate(eds, msgs),
                canopen_rate(eds, msgs),
                "frames/s",
                True,
            )
        )


if __name__ == "__main__":
    main()
