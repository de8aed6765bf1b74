"""CPU instructions a device spends on one expedited SDO request, a master on one received
TPDO, and a blocking client on its own part of an expedited read, beside python-canopen's.

Wall-clock figures on a shared 2-core machine vary by ±30 % from run to run; instruction
counts under ``valgrind --tool=callgrind`` repeat exactly (with ``PYTHONHASHSEED`` fixed), so
a change of a few percent in the device's path shows here when no timing can show it.

Each figure is the difference between a run serving 3,000 requests and one serving 1,000,
divided by 2,000: start-up, imports and the dictionary's set-up cancel out. A request is a
python-can message already read, through each stack's receive path to its SDO server (cobus
``Device`` on a ``RealTimeLoop``, under the protocol lock as a reader thread dispatches;
python-canopen ``LocalNode`` through its ``MessageListener``) and the answer handed to the
interface (python-can's virtual bus, nobody else on it). A TPDO is a frame of two mapped
16-bit values, decoded by a master's remote node (cobus ``tpdo[1]`` of a remote node with its
heartbeat watched, as ``bench_load`` sets up 64 of them; python-canopen ``RemoteNode.tpdo[1]``
subscribed), with nobody waiting for it. A client's read is what ``bench_dispatch`` times
as "a blocking client's own work": ``sdo.upload`` of each stack's blocking API with the
answer fed through its receive path from the interface's send, in the same thread.

Needs valgrind (``apt install valgrind``); without it the table says so and nothing runs.
Run alone: ``python -m benchmarks.bench_instructions``.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from benchmarks.common import header, row

if TYPE_CHECKING:
    import canopen

    from cobus.runtime import AsyncNetwork

NODE = 5
_REQUESTS = {
    # upload 1000h:00 (device type)
    "read": bytes([0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0]),
    # expedited download of 4 bytes to 2000h:00 (an UNSIGNED32 the application owns)
    "write": bytes([0x23, 0x00, 0x20, 0x00, 1, 2, 3, 4]),
}
_WARM_UP = 200
_ROOT = Path(__file__).resolve().parent.parent


def _feed_cobus(
    setup: Callable[[AsyncNetwork], object], cob_id: int, data: bytes, count: int
) -> None:
    """A network on a ``RealTimeLoop`` set up by ``setup``, fed ``count`` frames (after the
    warm-up) as its reader thread dispatches them: one at a time, under the protocol lock."""
    import can

    from cobus.runtime import AsyncNetwork, RealTimeLoop

    loop = RealTimeLoop()

    async def connect() -> AsyncNetwork:
        net = await AsyncNetwork(interface="virtual", channel="bench-instr-cobus").connect()
        setup(net)
        return net

    net = loop.run_until_complete(connect())
    batch = [can.Message(arbitration_id=cob_id, data=data, is_extended_id=False)]
    lock, dispatch = loop.protocol_lock, net._on_messages
    for _ in range(_WARM_UP + count):
        with lock:
            dispatch(batch)


def _feed_canopen(network: canopen.Network, cob_id: int, data: bytes, count: int) -> None:
    """``count`` frames (after the warm-up) through python-canopen's listener."""
    import can

    listener = network.listeners[0]
    msg = can.Message(arbitration_id=cob_id, data=data, is_extended_id=False)
    for _ in range(_WARM_UP + count):
        listener.on_message_received(msg)


def _serve_cobus(data: bytes, count: int) -> None:
    from cobus.device import Device, minimal_od
    from cobus.od import DataType, Variable

    od = minimal_od()
    od.add(Variable(0x2000, 0, "Setpoint", DataType.UNSIGNED32, default=0))
    _feed_cobus(lambda net: Device(net, NODE, od).start(), 0x600 + NODE, data, count)


def _serve_canopen(data: bytes, count: int) -> None:
    import canopen

    from benchmarks.common import canopen_device_type_od

    od = canopen_device_type_od()
    var = canopen.objectdictionary.ODVariable("Setpoint", 0x2000, 0)
    var.data_type = canopen.objectdictionary.datatypes.UNSIGNED32
    var.access_type = "rw"
    var.default = 0
    od.add_object(var)
    network = canopen.Network()
    network.connect(interface="virtual", channel="bench-instr-canopen")
    network.add_node(canopen.LocalNode(NODE, od))
    _feed_canopen(network, 0x600 + NODE, data, count)


_TPDO = bytes([5, 0, 0, 1])


def _receive_cobus(count: int) -> None:
    from benchmarks.bench_load import cobus_master_node

    _feed_cobus(lambda net: cobus_master_node(net, NODE), 0x180 + NODE, _TPDO, count)


def _receive_canopen(count: int) -> None:
    import canopen

    from benchmarks.bench_load import canopen_master_node

    network = canopen.Network()
    network.connect(interface="virtual", channel="bench-instr-tpdo-canopen")
    canopen_master_node(network, NODE)
    _feed_canopen(network, 0x180 + NODE, _TPDO, count)


def _client_cobus(count: int) -> None:
    from benchmarks.bench_dispatch import cobus_client

    _, read = cobus_client("bench-instr-client")
    for _ in range(_WARM_UP + count):
        read()


def _client_canopen(count: int) -> None:
    from benchmarks.bench_dispatch import canopen_client

    _, read = canopen_client("bench-instr-client-canopen")
    for _ in range(_WARM_UP + count):
        read()


def _count(stack: str, request: str, count: int) -> int:
    """Instructions of one whole run under callgrind."""
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, PYTHONHASHSEED="0")
        result = subprocess.run(
            [
                "valgrind",
                "--tool=callgrind",
                f"--callgrind-out-file={tmp}/out",
                sys.executable,
                "-m",
                "benchmarks.bench_instructions",
                "--serve",
                stack,
                request,
                str(count),
            ],
            cwd=_ROOT,
            env=env,
            capture_output=True,
            text=True,
            timeout=600,
            check=True,
        )
    found = re.search(r"Collected : (\d+)", result.stderr)
    if found is None:
        raise RuntimeError(f"callgrind printed no count:\n{result.stderr[-2000:]}")
    return int(found.group(1))


def per_request(stack: str, request: str) -> float:
    return (_count(stack, request, 3000) - _count(stack, request, 1000)) / 2000


def main() -> None:
    print(header("Instructions per request or frame (callgrind)"))
    if shutil.which("valgrind") is None:
        print("  valgrind is not installed: nothing counted")
        return
    for request in _REQUESTS:
        ours, theirs = per_request("cobus", request), per_request("canopen", request)
        print(row(f"a device: expedited {request}", ours, theirs, "instr", False))
    ours, theirs = per_request("cobus", "tpdo"), per_request("canopen", "tpdo")
    print(row("a master: a TPDO received", ours, theirs, "instr", False))
    ours, theirs = per_request("cobus", "client"), per_request("canopen", "client")
    print(row("a blocking client: its own work per read", ours, theirs, "instr", False))


if __name__ == "__main__":
    if len(sys.argv) == 5 and sys.argv[1] == "--serve":
        _, _, stack, request, count = sys.argv
        if request == "tpdo":
            (_receive_cobus if stack == "cobus" else _receive_canopen)(int(count))
        elif request == "client":
            (_client_cobus if stack == "cobus" else _client_canopen)(int(count))
        else:
            serve = _serve_cobus if stack == "cobus" else _serve_canopen
            serve(_REQUESTS[request], int(count))
        sys.stdout.flush()
        os._exit(0)  # no shutdown work in the count
    main()
