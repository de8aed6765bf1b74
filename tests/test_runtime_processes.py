"""The runtime across processes and on descriptor-driven interfaces.

- Two processes share one bus through python-can-remote on 127.0.0.1: a cobus SDO server in a
  child process, the cobus client here.
- The SocketCAN read path (the loop watches the socket's descriptor) with a stand-in bus
  whose class has SocketCAN's name: this machine's kernel has no SocketCAN.
"""

import asyncio
import socket
import subprocess
import sys
import textwrap
from collections import deque

import can
import pytest

from cobus.proto import Frame
from cobus.runtime import AsyncNetwork, Network
from cobus.runtime.events import ReceiveFailed

pytestmark = pytest.mark.interop

DATA = bytes(range(256)) * 4

SERVER = textwrap.dedent(
    """
    import sys, time
    from cobus.proto.sdo import DictBackend, SdoServer
    from cobus.runtime import Network

    async def serve(net):
        store = DictBackend({(0x1000, 0): b"\\x91\\x01\\x00\\x00", (0x2000, 0): DATA})
        net.aio.attach(SdoServer(0x605, 0x585, store), [0x605])

    DATA = bytes(range(256)) * 4
    with Network(interface="remote", channel=sys.argv[1]) as net:
        net.run(serve(net))
        print("ready", flush=True)
        sys.stdin.read()  # until the test closes our stdin
    """
)


@pytest.mark.parametrize("on_loop", [False, True])
def test_sdo_between_two_processes_over_python_can_remote(remote_bus_url, on_loop):
    child = subprocess.Popen(
        [sys.executable, "-c", SERVER, remote_bus_url],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert child.stdout is not None and child.stdout.readline().strip() == "ready"
        with Network(interface="remote", channel=remote_bus_url, read_on_loop=on_loop) as net:
            if on_loop:  # the loop reads the websocket itself (tests/test_runtime_fd_read)
                assert net.aio._fd is not None and net.aio._reader is None
            else:  # the blocking Network's way: a reader thread
                assert net.aio._fd is None and net.aio._reader is not None
            node = net.add_remote(5, sdo_timeout=2.0)
            assert node.sdo.upload(0x1000) == b"\x91\x01\x00\x00"
            assert node.sdo.upload(0x2000) == DATA
            assert node.sdo.upload(0x2000, block=True) == DATA
            node.sdo.download(0x2000, 0, DATA[::-1], block=True)
            assert node.sdo.upload(0x2000) == DATA[::-1]
    finally:
        if child.stdin is not None:
            child.stdin.close()
        child.wait(15)
    assert child.returncode == 0


class SocketcanBus(can.BusABC):
    """Stand-in with SocketCAN's class name: a socketpair makes its descriptor readable
    exactly when a frame is waiting, as a CAN_RAW socket is."""

    def __init__(self):
        self._r, self._w = socket.socketpair()
        self._r.setblocking(False)
        self._frames: deque[can.Message] = deque()
        self.sent: list[can.Message] = []
        super().__init__(channel="stand-in")

    def inject(self, msg: can.Message) -> None:
        if not self._frames:
            self._w.send(b"x")  # readable while frames wait, like a CAN_RAW socket
        self._frames.append(msg)

    def fileno(self):
        return self._r.fileno()

    down = False  # the interface is down: reads fail (ENETDOWN), the socket stays readable

    def _recv_internal(self, timeout):
        if self.down:
            raise can.CanOperationError("Network is down [Error Code 100]")
        if not self._frames:
            return None, False
        msg = self._frames.popleft()
        if not self._frames:
            self._r.recv(1)
        return msg, False

    def send(self, msg, timeout=None):
        self.sent.append(msg)

    def shutdown(self):
        self._r.close()
        self._w.close()
        super().shutdown()


def test_socketcan_descriptor_is_watched_by_the_loop_without_a_thread():
    bus = SocketcanBus()

    async def main():
        async with AsyncNetwork(bus) as net:
            assert net._reader is None and net._fd == bus.fileno()
            got = []
            net.subscribe(0x181, lambda f, now: got.append(f))
            for i in range(600):  # more than one read batch
                bus.inject(can.Message(arbitration_id=0x181, data=[i & 0xFF], is_extended_id=False))
            for _ in range(100):
                if len(got) == 600:
                    break
                await asyncio.sleep(0.01)
            return got

    got = asyncio.run(main())
    bus.shutdown()
    assert [f.data[0] for f in got] == [i & 0xFF for i in range(600)]
    assert got[0] == Frame(0x181, b"\x00")


def test_a_failing_socketcan_read_is_reported_with_back_off_and_reading_resumes():
    """An interface taken down (ENETDOWN) keeps its socket readable: the loop must not spin
    on it; once the interface is back, frames flow again."""

    bus = SocketcanBus()

    async def main():
        async with AsyncNetwork(bus) as net:
            failures: list[ReceiveFailed] = []
            net.add_listener(lambda e: failures.append(e) if isinstance(e, ReceiveFailed) else None)
            got = []
            net.subscribe(0x181, lambda f, now: got.append(f))
            bus.down = True
            bus.inject(can.Message(arbitration_id=0x181, data=b"\x01", is_extended_id=False))
            await asyncio.sleep(0.4)
            assert 2 <= len(failures) <= 6  # 50, 100, 200 ms apart: no spin
            assert "Network is down" in failures[0].reason
            bus.down = False
            for _ in range(200):
                if got:
                    break
                await asyncio.sleep(0.01)
            assert [f.data for f in got] == [b"\x01"]  # the waiting frame, once it is back up
            assert net._fd == bus.fileno() and net._reader is None

    asyncio.run(main())
    bus.shutdown()


def test_socketcan_frames_of_other_programs_on_the_host_are_delivered():
    """python-can marks a SocketCAN frame sent by any program of the same host is_rx False
    (the kernel's MSG_DONTROUTE; python-can issue 1274): it is not this network's own."""
    bus = SocketcanBus()

    async def main():
        async with AsyncNetwork(bus) as net:
            got = []
            net.subscribe(0x181, lambda f, now: got.append(f))
            local = can.Message(arbitration_id=0x181, data=b"\x05", is_extended_id=False)
            local.is_rx = False  # as python-can reads another local program's frame
            bus.inject(local)
            for _ in range(100):
                if got:
                    break
                await asyncio.sleep(0.01)
            assert [f.data for f in got] == [b"\x05"]

    asyncio.run(main())
    bus.shutdown()
