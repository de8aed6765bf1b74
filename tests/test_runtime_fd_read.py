"""The loop reads python-can-remote's socket itself (issue 20): no reader thread, one wake-up.

python-can-remote's client reads a websocket frame with blocking socket calls. The loop peeks
at the socket first and reads only when a whole frame waits, so a frame split over TCP
segments, a ping between frames or a closed connection never stalls or spins the loop. The
peer here is a hand-driven websocket server on 127.0.0.1 that speaks python-can-remote's
protocol, so each byte the client sees is chosen by the test; the client is python-can's real
``remote`` interface.

Also here: python-can's ``udp_multicast`` (read on the loop too), and buses that hand a
network's own messages back, which it must not deliver twice.
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import hashlib
import json
import random
import socket
import struct
import sys
import threading
import time
from collections.abc import Awaitable, Callable

import can
import pytest

from cobus.proto import Frame
from cobus.runtime import AsyncNetwork, RealTimeLoop
from cobus.runtime.bus import (
    _PEEK_FIRST,
    Readiness,
    loop_source,
    websocket_readiness,
    websocket_waiting,
)
from cobus.runtime.events import ReceiveFailed
from tests.util import need, need_module, until

_GUID = b"258EAFA5-E914-47DA-95CA-C5AB0DC85B11"


def ws_frame(opcode: int, payload: bytes, *, mask: bool = False) -> bytes:
    """One unfragmented websocket frame (RFC 6455)."""
    head = bytearray([0x80 | opcode])
    flag = 0x80 if mask else 0
    if len(payload) < 126:
        head.append(flag | len(payload))
    elif len(payload) < 1 << 16:
        head.append(flag | 126)
        head += struct.pack(">H", len(payload))
    else:
        head.append(flag | 127)
        head += struct.pack(">Q", len(payload))
    if mask:
        key = b"\x01\x02\x03\x04"
        payload = bytes(b ^ key[i % 4] for i, b in enumerate(payload))
        head += key
    return bytes(head) + payload


def can_frame(cob_id: int, data: bytes) -> bytes:
    """python-can-remote's binary message of a CAN frame, in a websocket frame."""
    body = b"\x01" + struct.pack(">dIBB", 0.0, cob_id, len(data), 0) + data
    return ws_frame(0x2, body)


class Peer:
    """A python-can-remote server stand-in: accepts one client, answers its bus request,
    then sends exactly the bytes the test gives it."""

    def __init__(self) -> None:
        self._listener = socket.create_server(("127.0.0.1", 0))
        self.url = f"ws://127.0.0.1:{self._listener.getsockname()[1]}/"
        self.conn: socket.socket | None = None
        self._thread = threading.Thread(target=self._accept, daemon=True)
        self._thread.start()

    def _accept(self) -> None:
        conn, _ = self._listener.accept()
        request = b""
        while b"\r\n\r\n" not in request:
            request += conn.recv(4096)
        headers = dict(
            line.split(": ", 1) for line in request.decode().split("\r\n")[1:] if ": " in line
        )
        key = headers["Sec-WebSocket-Key"].encode()
        accept = base64.b64encode(hashlib.sha1(key + _GUID).digest()).decode()
        conn.sendall(
            (
                "HTTP/1.1 101 Switching Protocols\r\nUpgrade: websocket\r\n"
                f"Connection: Upgrade\r\nSec-WebSocket-Accept: {accept}\r\n"
                "Sec-WebSocket-Protocol: can.binary+json.v1\r\n\r\n"
            ).encode()
        )
        self._read_frame(conn)  # the bus request
        reply = {"type": "bus_response", "payload": {"channel_info": "virtual channel 0"}}
        conn.sendall(ws_frame(0x1, json.dumps(reply).encode()))
        self.conn = conn

    @staticmethod
    def _read_frame(conn: socket.socket) -> tuple[int, bytes]:
        def exactly(n: int) -> bytes:
            data = b""
            while len(data) < n:
                chunk = conn.recv(n - len(data))
                assert chunk, "client closed"
                data += chunk
            return data

        b1, b2 = exactly(2)
        length = b2 & 0x7F
        if length == 126:
            (length,) = struct.unpack(">H", exactly(2))
        elif length == 127:
            (length,) = struct.unpack(">Q", exactly(8))
        key = exactly(4) if b2 & 0x80 else b"\0\0\0\0"
        data = exactly(length)
        return b1 & 0x0F, bytes(b ^ key[i % 4] for i, b in enumerate(data))

    def read_frame(self) -> tuple[int, bytes]:
        assert self.conn is not None
        return self._read_frame(self.conn)

    def send(self, data: bytes) -> None:
        assert self.conn is not None
        self.conn.sendall(data)

    def answer_close(self) -> None:
        """Read on until the client's close frame, answer it and hang up (in a thread: the
        client's ``shutdown`` waits for that)."""
        conn = self.conn
        if conn is None or conn.fileno() < 0:
            return

        def run() -> None:
            with contextlib.suppress(AssertionError, OSError):
                while self._read_frame(conn)[0] != 0x8:
                    pass
                conn.sendall(ws_frame(0x8, b""))
            conn.close()

        threading.Thread(target=run, daemon=True).start()

    def close(self) -> None:
        if self.conn is not None:
            self.conn.close()
        self._listener.close()


@pytest.fixture
def peer():
    p = Peer()
    yield p
    p.close()


def open_remote(peer: Peer) -> can.BusABC:
    bus = can.Bus(interface="remote", channel=peer.url)
    deadline = time.monotonic() + 5
    while peer.conn is None and time.monotonic() < deadline:
        time.sleep(0.01)
    return bus


def close_remote(bus: can.BusABC, peer: Peer) -> None:
    peer.answer_close()
    try:
        bus.shutdown()
    except (ValueError, OSError):
        # python-can-remote's shutdown fails on a connection the server already closed (it
        # selects on its closed socket, or half-closes a dead one): nothing is left to close
        # but python-can's part
        can.BusABC.shutdown(bus)


# ---------------------------------------------------------------------------- the peek
@pytest.fixture
def pair():
    a, b = socket.socketpair()
    yield a, b
    a.close()
    b.close()


def test_readiness_of_an_empty_socket_is_nothing(pair):
    assert websocket_readiness(pair[0]) is Readiness.NOTHING


@pytest.mark.parametrize("cut", [1, 2, 10, -1])
def test_a_frame_cut_anywhere_is_partial_until_its_last_byte(pair, cut):
    a, b = pair
    frame = can_frame(0x181, b"\x01\x02\x03")
    b.sendall(frame[:cut])
    assert websocket_readiness(a) is Readiness.PART
    b.sendall(frame[cut:])
    assert websocket_readiness(a) is Readiness.WHOLE
    assert a.recv(100) == frame  # peeking took nothing


def test_control_frames_before_the_data_frame_need_the_data_frame_too(pair):
    a, b = pair
    b.sendall(ws_frame(0x9, b"ping") + ws_frame(0xA, b"") + can_frame(0x181, b"")[:5])
    assert websocket_readiness(a) is Readiness.PART
    b.sendall(can_frame(0x181, b"")[5:])
    assert websocket_readiness(a) is Readiness.WHOLE


def test_long_and_masked_frames_are_measured_whole(pair):
    a, b = pair
    long_text = ws_frame(0x1, b"x" * 70_000, mask=True)  # 64-bit length, beyond one peek
    b.sendall(long_text[:-1])
    assert websocket_readiness(a) is Readiness.PART
    b.sendall(long_text[-1:])
    assert websocket_readiness(a) is Readiness.WHOLE
    medium = ws_frame(0x2, b"y" * 600)  # 16-bit length
    assert websocket_readiness(a) is Readiness.WHOLE  # the first frame decides
    a.recv(len(long_text), socket.MSG_WAITALL)
    b.sendall(medium[:3])
    assert websocket_readiness(a) is Readiness.PART
    b.sendall(medium[3:])
    assert websocket_readiness(a) is Readiness.WHOLE


def test_a_close_frame_or_end_of_stream_reads_at_once(pair):
    a, b = pair
    b.sendall(ws_frame(0x8, b"\x03\xe8"))
    assert websocket_readiness(a) is Readiness.WHOLE
    a.recv(100)
    b.close()
    assert websocket_readiness(a) is Readiness.WHOLE  # recv() raises WebsocketClosed at once


def test_control_frames_alone_wait_for_a_data_frame_unless_the_stream_ended(pair):
    a, b = pair
    b.sendall(ws_frame(0x9, b"ping"))
    assert websocket_readiness(a) is Readiness.PART  # read() would wait for a data frame
    b.shutdown(socket.SHUT_WR)
    assert websocket_readiness(a) is Readiness.WHOLE  # it will not: recv() reads and raises


def test_a_frame_cut_by_the_end_of_stream_reads_at_once(pair):
    a, b = pair
    b.sendall(can_frame(0x181, b"\x01")[:5])
    assert websocket_readiness(a) is Readiness.PART
    b.shutdown(socket.SHUT_WR)
    assert websocket_readiness(a) is Readiness.WHOLE


def test_a_frame_longer_than_any_can_frame_is_left_to_a_thread(pair):
    a, b = pair
    b.sendall(b"\x81\x7f" + (16 << 20).to_bytes(8, "big") + b"x" * 100)  # 16 MiB announced
    assert websocket_readiness(a) is Readiness.HUGE  # more than the kernel's buffer may hold


def test_one_look_counts_every_whole_frame_waiting(pair):
    a, b = pair
    assert websocket_waiting(a) == (Readiness.NOTHING, 0)
    three = [can_frame(0x181, bytes([i])) for i in range(3)]
    ping = ws_frame(0x9, b"ping")
    b.sendall(three[0] + ping + three[1] + ws_frame(0xA, b"") + three[2] + three[0][:4])
    # control frames between are read along by recv(); the cut frame at the end is not
    assert websocket_waiting(a) == (Readiness.WHOLE, 3)
    a.recv(len(three[0] + ping + three[1]) + 2 + len(three[2]), socket.MSG_WAITALL)
    assert websocket_waiting(a) == (Readiness.PART, 0)
    b.sendall(three[0][4:] + ws_frame(0x8, b"\x03\xe8"))
    assert websocket_waiting(a) == (Readiness.WHOLE, 2)  # a close frame reads at once too
    a.recv(100)
    b.close()
    assert websocket_waiting(a) == (Readiness.WHOLE, 1)  # the end of the stream


def test_frames_beyond_the_first_look_are_not_counted(pair):
    a, b = pair
    frames = [can_frame(0x181, bytes(8)) for _ in range(400)]  # ~10 KiB, more than one look
    b.sendall(b"".join(frames))
    verdict, count = websocket_waiting(a)
    assert verdict is Readiness.WHOLE and 1 <= count < 400
    assert count == _PEEK_FIRST // len(frames[0])  # the whole ones among the bytes peeked at
    long_first = ws_frame(0x2, b"z" * (_PEEK_FIRST + 100))  # longer than the first look
    c, d = socket.socketpair()
    with c, d:
        d.sendall(long_first + frames[0] + long_first)  # the look grows to twice its size
        assert websocket_waiting(c) == (Readiness.WHOLE, 2)
    big, small = ws_frame(0x2, b"z" * _PEEK_FIRST), frames[0]
    e, f = socket.socketpair()
    with e, f:
        f.sendall(small + big)  # a small frame then one cut by the look's end
        assert websocket_waiting(e) == (Readiness.WHOLE, 1)


def test_which_buses_the_loop_reads(peer):
    bus = open_remote(peer)
    try:
        source = loop_source(bus)
        assert source is not None and source.fd == bus.fileno() and source.ready is not None
    finally:
        close_remote(bus, peer)
    virtual = can.Bus(interface="virtual", channel="fd-read-which")
    try:
        assert loop_source(virtual) is None  # a thread reads it
    finally:
        virtual.shutdown()


# ---------------------------------------------------------------------------- on the loop
def _on_real_time_loop(coro_fn):
    loop = RealTimeLoop()
    try:
        return loop.run_until_complete(coro_fn())
    finally:
        loop.close()


async def _until(predicate, seconds: float = 3.0) -> None:
    deadline = time.monotonic() + seconds
    while not predicate():
        assert time.monotonic() < deadline, "timed out"
        await asyncio.sleep(0.002)


def _count_reads(net: AsyncNetwork) -> list[int]:
    """Count the loop's looks at the descriptor: ``[n]``, updated as they happen."""
    calls = [0]
    read = net._read_ready

    def counted() -> None:
        calls[0] += 1
        read()

    net._read_ready = counted  # type: ignore[method-assign]
    fd = net._fd
    assert fd is not None
    net.loop.remove_reader(fd)
    net.loop.add_reader(fd, counted)
    return calls


def _failures(net: AsyncNetwork) -> list[ReceiveFailed]:
    """The ReceiveFailed events of ``net``, as they come."""
    failures: list[ReceiveFailed] = []
    net.add_listener(lambda e: failures.append(e) if isinstance(e, ReceiveFailed) else None)
    return failures


def _with_remote(peer: Peer, main: Callable[[can.BusABC], Awaitable[None]]) -> None:
    """Run ``main(bus)`` on a RealTimeLoop with a python-can-remote bus to ``peer``."""
    bus = open_remote(peer)
    try:
        _on_real_time_loop(lambda: main(bus))
    finally:
        close_remote(bus, peer)


@pytest.mark.parametrize("loop_kind", ["asyncio", "realtime"])
def test_frames_are_read_on_the_loop_without_a_thread(peer, loop_kind):
    async def main(bus: can.BusABC) -> None:
        async with AsyncNetwork(bus) as net:
            assert net._reader is None and net._fd == bus.fileno()
            got: list[Frame] = []
            net.subscribe(0x181, lambda f, now: got.append(f))
            peer.send(b"".join(can_frame(0x181, bytes([i & 0xFF])) for i in range(600)))
            await _until(lambda: len(got) == 600)
            assert [f.data[0] for f in got] == [i & 0xFF for i in range(600)]
            # what the network sends reaches the peer, as python-can-remote sends it
            net.send(Frame(0x601, b"\x40\x00\x10\x00\x00\x00\x00\x00"))
            opcode, body = await asyncio.to_thread(peer.read_frame)
            assert opcode == 0x2 and struct.unpack_from(">I", body, 9)[0] == 0x601

    if loop_kind == "realtime":
        _with_remote(peer, main)
        return
    bus = open_remote(peer)
    try:
        asyncio.run(main(bus))
    finally:
        close_remote(bus, peer)


def test_one_look_at_the_socket_for_each_batch_read(peer):
    async def main(bus: can.BusABC) -> None:
        async with AsyncNetwork(bus) as net:
            ready = net._fd_ready
            assert ready is not None
            looks: list[tuple[Readiness, int]] = []

            def counted() -> tuple[Readiness, int]:
                looks.append(ready())
                return looks[-1]

            net._fd_ready = counted
            got: list[Frame] = []
            net.subscribe(0x181, lambda f, now: got.append(f))
            peer.send(b"".join(can_frame(0x181, bytes([i])) for i in range(5)))
            await _until(lambda: len(got) == 5)
            await asyncio.sleep(0.02)
            # the five frames arrived at once: read after one look, and no look finds nothing
            assert looks == [(Readiness.WHOLE, 5)]
            assert [f.data for f in got] == [bytes([i]) for i in range(5)]
            peer.send(can_frame(0x181, b"\x07"))
            await _until(lambda: len(got) == 6)
            await asyncio.sleep(0.02)
            assert looks[1:] == [(Readiness.WHOLE, 1)]

    _with_remote(peer, main)


def test_a_frame_split_over_segments_does_not_stall_the_loop(peer):
    async def main(bus: can.BusABC) -> None:
        async with AsyncNetwork(bus) as net:
            got: list[Frame] = []
            net.subscribe(0x181, lambda f, now: got.append(f))
            frame = can_frame(0x181, b"\xaa\xbb")
            peer.send(frame[:7])
            for _ in range(3):  # the loop goes on running other work (stuck in the read, it
                await asyncio.sleep(0.005)  # would not come back: the suite's timeout says so)
            assert got == []
            peer.send(frame[7:] + ws_frame(0x9, b"are you there") + can_frame(0x181, b"\xcc"))
            await _until(lambda: len(got) == 2)
            assert [f.data for f in got] == [b"\xaa\xbb", b"\xcc"]
            # python-can-remote answered the ping from the loop, as its own reader would
            opcode, body = await asyncio.to_thread(peer.read_frame)
            assert (opcode, body) == (0xA, b"are you there")

    _with_remote(peer, main)


def test_a_partial_frame_does_not_spin_the_loop(peer):
    async def main(bus: can.BusABC) -> None:
        async with AsyncNetwork(bus) as net:
            calls = _count_reads(net)
            peer.send(can_frame(0x181, b"")[:3])
            await asyncio.sleep(0.2)
            # paused off the descriptor between looks: hundreds, not a spin of millions
            assert 1 <= calls[0] <= 0.2 / 0.0005 + 10

    _with_remote(peer, main)


def test_a_closed_connection_is_reported_with_back_off_then_read_by_a_thread(peer):
    async def main(bus: can.BusABC) -> None:
        async with AsyncNetwork(bus) as net:
            failures = _failures(net)
            got: list[Frame] = []
            net.subscribe(0x181, lambda f, now: got.append(f))
            peer.send(can_frame(0x181, b"\x01") + ws_frame(0x8, b"\x03\xe8"))
            await _until(lambda: got and failures)
            assert got[0].data == b"\x01"  # read before the close
            await asyncio.sleep(0.3)
            # python-can-remote closed its socket on the close frame: no descriptor to
            # watch any more; a thread reads on and reports with back-off, no spin
            assert net._fd is None and net._reader is not None
            assert 1 <= len(failures) <= 10

    _with_remote(peer, main)


def test_a_connection_dropped_without_a_close_frame_is_reported_with_back_off(peer):
    async def main(bus: can.BusABC) -> None:
        async with AsyncNetwork(bus) as net:
            failures = _failures(net)
            assert peer.conn is not None
            peer.conn.close()  # end of stream: the socket stays readable, with nothing in it
            await _until(lambda: failures)
            await asyncio.sleep(0.3)
            assert net._fd is not None  # still watched, between pauses: 50, 100, 200 ms...
            assert 1 <= len(failures) <= 5
            assert failures[0].reason  # python-can-remote's words for it

    _with_remote(peer, main)


def test_a_ping_that_no_frame_follows_does_not_spin_the_loop(peer):
    async def main(bus: can.BusABC) -> None:
        async with AsyncNetwork(bus) as net:
            calls = _count_reads(net)
            got: list[Frame] = []
            net.subscribe(0x181, lambda f, now: got.append(f))
            peer.send(ws_frame(0x9, b"hello?"))
            await asyncio.sleep(0.5)
            # pauses of 0.5 ms doubling to 50 ms between looks: about 17, not a spin
            assert 1 <= calls[0] <= 40 and got == []
            peer.send(can_frame(0x181, b"\x07"))
            await _until(lambda: got)
            assert got[0].data == b"\x07"
            opcode, body = await asyncio.to_thread(peer.read_frame)
            assert (opcode, body) == (0xA, b"hello?")  # answered once the frame came

    _with_remote(peer, main)


def test_a_frame_cut_by_a_dropped_connection_is_reported(peer):
    async def main(bus: can.BusABC) -> None:
        async with AsyncNetwork(bus) as net:
            failures = _failures(net)
            assert peer.conn is not None
            peer.send(can_frame(0x181, b"\x01\x02")[:6])
            await asyncio.sleep(0.05)
            peer.conn.shutdown(socket.SHUT_WR)
            await _until(lambda: failures)

    _with_remote(peer, main)


def test_disconnect_while_paused_leaves_the_descriptor_number_alone(peer):
    """While paused the loop does not watch the descriptor; by then its number may belong to
    another component (python-can-remote closes its socket on a close frame)."""

    async def main(bus: can.BusABC) -> None:
        net = AsyncNetwork(bus)
        await net.connect()
        fd = net._fd
        assert fd is not None
        peer.send(can_frame(0x181, b"")[:3])  # a partial frame: the watch pauses
        await _until(lambda: net._fd_resume is not None)
        loop = asyncio.get_running_loop()
        loop.add_reader(fd, lambda: None)  # someone else's reader now
        await net.disconnect()
        assert loop.remove_reader(fd)  # still registered: disconnect left it alone

    _with_remote(peer, main)


def test_no_read_and_no_lost_frame_after_disconnect_from_a_handler_in_a_burst(peer):
    errors: list[dict[str, object]] = []

    async def main(bus: can.BusABC) -> None:
        loop = asyncio.get_running_loop()
        loop.set_exception_handler(lambda _loop, context: errors.append(context))
        net = AsyncNetwork(bus)
        await net.connect()
        got: list[Frame] = []
        closing: list[asyncio.Task[None]] = []

        def handler(frame: Frame, now: float) -> None:
            got.append(frame)
            if len(got) == 10:
                closing.append(asyncio.ensure_future(net.disconnect()))

        net.subscribe(0x181, handler)
        recv, late = bus.recv, []

        def watched(timeout=None):
            if net._loop is None:
                late.append(1)  # a read after the disconnect
            return recv(timeout)

        bus.recv = watched  # type: ignore[method-assign]
        peer.send(b"".join(can_frame(0x181, bytes([i & 0xFF])) for i in range(600)))
        await _until(lambda: closing and closing[0].done())
        await asyncio.sleep(0.05)
        # the batch read before the disconnect is dispatched; nothing is read after it...
        assert 10 <= len(got) <= 256 and net._fd is None and net._fd_more is None
        assert late == []
        await net.connect()  # ...so that nothing is lost: the rest waits in the socket
        await _until(lambda: len(got) == 600)
        assert [f.data[0] for f in got] == [i & 0xFF for i in range(600)]
        await net.disconnect()

    _with_remote(peer, main)
    assert errors == []


def test_the_back_off_starts_again_after_each_good_frame(peer):
    error = ws_frame(0x1, json.dumps({"type": "error", "payload": "boom"}).encode())

    async def main(bus: can.BusABC) -> None:
        async with AsyncNetwork(bus) as net:
            failures = _failures(net)
            got: list[Frame] = []
            net.subscribe(0x181, lambda f, now: got.append(f))
            for round_ in range(1, 5):
                peer.send(can_frame(0x181, bytes([round_])) + error)
                await _until(lambda n=round_: len(failures) == n and len(got) == n)
                assert net._fd_backoff <= 0.1  # 50 ms, doubled once: never 1 s
                await _until(lambda: net._fd_resume is None)
            assert "boom" in failures[0].reason

    _with_remote(peer, main)


# ---------------------------------------------------------------------------- own messages
def test_a_bus_that_hands_our_messages_back_delivers_each_once():
    """python-can's virtual bus with receive_own_messages marks them (is_rx False): the
    network has echoed them locally already."""
    bus = can.Bus(interface="virtual", channel="fd-own", receive_own_messages=True)

    async def main():
        async with AsyncNetwork(bus) as net:
            got: list[Frame] = []
            net.subscribe(0x123, lambda f, now: got.append(f))
            net.send(Frame(0x123, b"\x01"))
            await asyncio.sleep(0.2)
            assert got == [Frame(0x123, b"\x01")]

    try:
        _on_real_time_loop(main)
    finally:
        bus.shutdown()


def _multicast_or_skip(group: str, port: int) -> None:
    """Skip where udp_multicast cannot work (fail instead with CI=true: tests.util.need)."""
    need_module("msgpack", "python-can's udp_multicast needs msgpack")
    try:
        a = can.Bus(interface="udp_multicast", channel=group, port=port)
    except (can.CanError, OSError) as exc:
        need(False, f"no multicast on this host: {exc}")
        return
    try:
        a.send(can.Message(arbitration_id=0x7F0, data=b"", is_extended_id=False))
        need(a.recv(1.0) is not None, "multicast loopback delivers nothing on this host")
    finally:
        a.shutdown()


@pytest.mark.parametrize("on_loop", [True, False])
@pytest.mark.parametrize("filtered", [True, False], ids=["echo-free", "tag-only"])
def test_udp_multicast_is_read_by_the_loop_or_a_thread_and_our_own_messages_come_once(
    on_loop, filtered, monkeypatch
):
    """Either way the bus is read, each network hears the other and its own frames once:
    on Linux its own datagrams never reach its socket (a sending socket of its own, filtered
    out by the kernel); where the filter cannot be attached, the tag drops them."""
    from can.interfaces.udp_multicast import UdpMulticastBus

    from cobus.device import add_device, minimal_od
    from cobus.runtime import Network, multicast

    if not filtered:
        monkeypatch.setattr(multicast, "_SO_ATTACH_FILTER", 0xDEAD)  # refused: no such option
    group = UdpMulticastBus.DEFAULT_GROUP_IPv6
    port = random.randrange(20000, 40000)  # (not the default port the benchmarks use)
    _multicast_or_skip(group, port)
    bus = can.Bus(interface="udp_multicast", channel=group, port=port)
    heard: list[can.Message] = []
    recv = bus.recv

    def recording(timeout: float | None = None) -> can.Message | None:
        msg = recv(timeout)
        if msg is not None:
            heard.append(msg)
        return msg

    bus.recv = recording  # type: ignore[method-assign]
    try:
        with (  # the blocking Network reads with its reading role unless read_on_loop=True
            Network(bus, read_on_loop=on_loop) as master,
            Network(
                interface="udp_multicast", channel=group, port=port, read_on_loop=on_loop
            ) as field,
        ):
            if on_loop:
                assert master.aio._reader is None and master.aio._fd is not None  # no thread
            else:
                assert master.aio._reading is not None and master.aio._fd is None
            linux = sys.platform.startswith("linux")
            assert (master.aio._tx is not None) is (filtered and linux)
            got: list[Frame] = []
            master.subscribe(0x123, lambda f, now: got.append(f))
            master.send(Frame(0x123, b"\x02"))
            add_device(field, 5, minimal_od())
            # the two networks of this process hear each other (different tags)...
            assert master.add_remote(5, sdo_timeout=2.0).sdo.upload(0x1000)
            master.send(Frame(0x123, b"\x7f"))  # a marker: a second copy would come before it
            tag = master.aio._echo_tag
            if master.aio._tx is None:  # tag only: the marker comes back (dropped by its tag)
                until(lambda: any(m.channel == tag and m.data == b"\x7f" for m in heard))
            until(lambda: got and got[-1].data == b"\x7f")
            assert got == [Frame(0x123, b"\x02"), Frame(0x123, b"\x7f")]  # ...each its own once
            own = [m for m in heard if m.channel == tag]
            assert heard and (not own if master.aio._tx is not None else len(own) == 3)
    finally:
        bus.shutdown()


def test_the_echo_free_sender_drops_only_its_own_datagrams_and_lets_go_when_closed(caplog):
    """python-can's udp_multicast bus with cobus's sending socket: what that socket sends
    reaches every other socket of the group but not the bus's own; what the bus sends
    through python-can, and what others send, still arrive. A sending socket that fails for
    good (the host's address changed) hands over to python-can's and takes the filter off;
    so does closing it."""
    from can.interfaces.udp_multicast import UdpMulticastBus
    from can.interfaces.udp_multicast.utils import pack_message

    from cobus.runtime.multicast import echo_free_sender

    if not sys.platform.startswith("linux"):
        pytest.skip("the kernel filter is Linux's")
    group = UdpMulticastBus.DEFAULT_GROUP_IPv6
    port = random.randrange(20000, 40000)
    _multicast_or_skip(group, port)

    def message(cob_id: int, data: bytes = b"", is_fd: bool = False) -> can.Message:
        return can.Message(arbitration_id=cob_id, is_extended_id=False, data=data, is_fd=is_fd)

    def heard(bus: can.BusABC) -> int | None:
        got = bus.recv(1.0)
        return None if got is None else got.arbitration_id

    virtual = can.Bus(interface="virtual", channel="fd-echo-free")
    ours = can.Bus(interface="udp_multicast", channel=group, port=port)
    other = can.Bus(interface="udp_multicast", channel=group, port=port, fd=False)
    sender = refuses_fd = None
    try:
        assert echo_free_sender(virtual) is None  # only udp_multicast hears itself
        sender = echo_free_sender(ours)
        assert sender is not None
        assert echo_free_sender(ours) is None  # one filter per socket: it has cobus's
        sender.send(message(0x101, data=b"\x01"))
        assert heard(other) == 0x101  # on the group...
        assert ours.recv(0.3) is None  # ...but never back on our own socket
        other.send(message(0x102))
        assert heard(ours) == 0x102
        ours.send(message(0x103))
        assert heard(ours) == 0x103  # python-can's own socket is not filtered (the tag's job)
        assert (heard(other), heard(other)) == (0x102, 0x103)  # (its own, looped back)
        refuses_fd = echo_free_sender(other)
        assert refuses_fd is not None
        with pytest.raises(can.CanOperationError, match="FD"):  # python-can decides FD
            refuses_fd.send(message(0x104, data=bytes(12), is_fd=True))
        address, source_port = sender.address
        sender._tx.close()  # as a send fails once the host's address has changed
        sender.send(message(0x105))  # through python-can's socket now
        assert not sender.active and "sending through python-can" in caplog.text
        assert heard(other) == 0x105 and heard(ours) == 0x105  # (the filter is off)
        sender.send(message(0x106))
        assert heard(other) == 0x106 and heard(ours) == 0x106
        # a socket that gets the old sender's address and port is heard too
        late = socket.socket(socket.AF_INET6, socket.SOCK_DGRAM)
        try:
            late.bind((address, source_port))
            late.sendto(pack_message(message(0x107)), (group, port))
            assert heard(ours) == 0x107
        finally:
            late.close()
        sender.close()  # again: nothing happens
        again = echo_free_sender(ours)  # the socket is free for a filter again
        assert again is not None and again.active
        again.close()
    finally:
        for made in (sender, refuses_fd):
            if made is not None:
                made.close()
        for bus in (virtual, ours, other):
            bus.shutdown()


def test_a_connect_that_fails_takes_the_filter_off_the_users_bus(monkeypatch):
    """Starting to receive fails after the sending socket was made: the connect raises, and
    the bus the user keeps is left without cobus's filter (free for the next network)."""
    from can.interfaces.udp_multicast import UdpMulticastBus

    from cobus.runtime import AsyncNetwork
    from cobus.runtime.multicast import echo_free_sender

    if not sys.platform.startswith("linux"):
        pytest.skip("the kernel filter is Linux's")
    group = UdpMulticastBus.DEFAULT_GROUP_IPv6
    port = random.randrange(20000, 40000)
    _multicast_or_skip(group, port)
    bus = can.Bus(interface="udp_multicast", channel=group, port=port)

    def refuse(*args: object) -> None:
        raise RuntimeError("no thread today")

    monkeypatch.setattr(AsyncNetwork, "_start_reader_thread", refuse)
    monkeypatch.setattr(AsyncNetwork, "_start_reading_role", refuse)

    async def main() -> None:
        net = AsyncNetwork(bus, read_on_loop=False)
        with pytest.raises(RuntimeError, match="no thread today"):
            await net.connect()
        assert net._tx is None

    try:
        _on_real_time_loop(main)
        again = echo_free_sender(bus)
        assert again is not None  # (None while a cobus filter is on the socket)
        again.close()
    finally:
        bus.shutdown()


def test_a_filter_program_drops_one_address_and_port_and_accepts_the_rest():
    """The BPF program, instruction by instruction: the UDP source port, then each 32-bit
    word of the source address; any mismatch jumps to "accept"."""
    from cobus.runtime.multicast import drop_from

    def decode(program: bytes) -> list[tuple[int, int, int, int]]:
        return [struct.unpack_from("HBBI", program, i) for i in range(0, len(program), 8)]

    four = decode(drop_from("192.0.2.7", 5000, socket.AF_INET))
    net = -0x100000 & 0xFFFFFFFF
    assert four == [
        (0x28, 0, 0, 0),  # ldh [0]: the UDP source port
        (0x15, 0, 3, 5000),  # jeq 5000, else accept
        (0x20, 0, 0, net + 12),  # ld [net + 12]: the IPv4 source address
        (0x15, 0, 1, 0xC0000207),  # jeq 192.0.2.7, else accept
        (0x06, 0, 0, 0),  # drop
        (0x06, 0, 0, 0xFFFFFFFF),  # accept
    ]
    six = decode(drop_from("fe80::1%eth0", 7, socket.AF_INET6))  # (the scope is not sent)
    assert len(six) == 12 and six[-2:] == four[-2:]
    loads = [k - net for code, _, _, k in six if code == 0x20]
    assert loads == [8, 12, 16, 20]  # the IPv6 source address, word by word
    jumps = [(pc, jf) for pc, (code, _, jf, _) in enumerate(six) if code == 0x15]
    assert all(pc + 1 + jf == 11 for pc, jf in jumps)  # each to "accept"
    assert [k for code, _, _, k in six if code == 0x15] == [7, 0xFE800000, 0, 0, 1]


def test_own_messages_are_recognised_through_a_fault_injecting_wrapper():
    from can.interfaces.udp_multicast import UdpMulticastBus

    from cobus.runtime.bus import own_echo
    from cobus.sim import FaultyBus

    group = UdpMulticastBus.DEFAULT_GROUP_IPv6
    port = random.randrange(20000, 40000)
    _multicast_or_skip(group, port)
    inner = can.Bus(interface="udp_multicast", channel=group, port=port)
    try:
        wrapped = FaultyBus(inner)
        assert own_echo(wrapped).tag is not None  # udp_multicast's, seen through the wrapper
        assert own_echo(wrapped).tag != own_echo(inner).tag  # (a fresh one each time)
        assert loop_source(wrapped) is None  # faults are injected in recv: a thread reads
    finally:
        inner.shutdown()


def test_only_the_virtual_bus_is_trusted_to_mark_our_own_messages():
    """SocketCAN marks every frame sent from the same host as not received (is_rx False),
    whichever program sent it (python-can issue 1274): those frames must be delivered."""
    from cobus.runtime.bus import own_echo

    own = can.Bus(interface="virtual", channel="fd-mark", receive_own_messages=True)
    plain = can.Bus(interface="virtual", channel="fd-mark")
    safe = can.ThreadSafeBus(interface="virtual", channel="fd-mark", receive_own_messages=True)
    try:
        assert own_echo(own).marked and not own_echo(plain).marked
        assert own_echo(safe).marked  # python-can's ThreadSafeBus is seen through
    finally:
        own.shutdown()
        plain.shutdown()
        safe.shutdown()


def test_a_thread_safe_udp_multicast_bus_hands_our_own_frames_back_once():
    """python-can's ThreadSafeBus is a proxy: the udp_multicast bus behind it is recognised,
    so the network's own frames are dropped (filtered out, or by their tag), not delivered a
    second time as received."""
    from can.interfaces.udp_multicast import UdpMulticastBus

    from cobus.runtime import Network

    group = UdpMulticastBus.DEFAULT_GROUP_IPv6
    port = random.randrange(20000, 40000)
    _multicast_or_skip(group, port)
    safe = can.ThreadSafeBus(interface="udp_multicast", channel=group, port=port)
    try:
        with Network(safe) as net:
            assert net.aio._echo_tag is not None
            assert (net.aio._tx is not None) is sys.platform.startswith("linux")
            got: list[Frame] = []
            net.subscribe(0x123, lambda f, now: got.append(f))
            net.send(Frame(0x123, b"\x03"))
            net.send(Frame(0x123, b"\x7f"))  # a marker: a second copy would come before it
            until(lambda: got and got[-1].data == b"\x7f")
            assert got == [Frame(0x123, b"\x03"), Frame(0x123, b"\x7f")]
    finally:
        safe.shutdown()


def test_a_huge_frame_hands_the_connection_to_a_thread_without_stalling_the_loop(peer):
    async def main(bus: can.BusABC) -> None:
        async with AsyncNetwork(bus) as net:
            got: list[Frame] = []
            net.subscribe(0x181, lambda f, now: got.append(f))
            size = 2 << 20  # 2 MiB, a binary message python-can-remote does not know
            huge = ws_frame(0x2, b"\x00" * size)
            peer.send(huge[:1000])
            # a thread reads now (the loop runs on: _until's sleeps come back)
            await _until(lambda: net._fd is None and net._reader is not None)
            await asyncio.to_thread(peer.send, huge[1000:] + can_frame(0x181, b"\x09"))
            await _until(lambda: got, 10.0)
            assert got[0].data == b"\x09"

    _with_remote(peer, main)
