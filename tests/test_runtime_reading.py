"""A blocking caller reads the bus itself while it waits for its answer (leader/follower,
``cobus.runtime.reading``), on SocketCAN through the stand-in of ``tests/socketcan_standin.py``.

The test plays the peer on the bus's raw socket: it sees each request the network sends and
answers when it chooses, so that who holds the role at each moment is known. Where a wait
could hang, the call runs in a thread joined with a generous bound: it checks that it ends,
not how fast.
"""

from __future__ import annotations

import asyncio
import os
import random
import resource
import signal
import struct
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import can
import pytest

from cobus.device import add_device, minimal_od
from cobus.proto import Frame
from cobus.proto.sdo.errors import SdoTimeoutError
from cobus.runtime import Network, ReceiveFailed
from cobus.runtime import reading as _reading
from cobus.runtime.loop import RealTimeLoop
from tests.socketcan_standin import KernelStandIn
from tests.util import second_ctrl_c_on_abort

NODE = 5


@pytest.fixture
def kernel(monkeypatch: pytest.MonkeyPatch) -> Iterator[KernelStandIn]:
    standin = KernelStandIn().install(monkeypatch)
    yield standin
    standin.close()


def _answer(index: int, subindex: int, value: int) -> can.Message:
    data = struct.pack("<BHBI", 0x43, index, subindex, value)
    return can.Message(arbitration_id=0x580 + NODE, data=data, is_extended_id=False)


class _Peer:
    """Answers each expedited upload request of the latest bus with ``index * 0x100 + subindex``,
    unless muted; may put other frames before each answer."""

    def __init__(self, kernel: KernelStandIn) -> None:
        self.kernel = kernel
        self.muted = False
        self.requests = 0
        self.before_answer: Callable[[], None] = lambda: None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        while not self._stop.is_set():
            if not self.kernel.raw:  # (the network's bus is not open yet)
                time.sleep(0.01)
                continue
            bus = len(self.kernel.raw) - 1  # the network's latest bus (a reconnect opens one)
            try:
                sent = self.kernel.sent(bus, timeout=0.05)
            except (OSError, struct.error):  # the network closed that bus
                time.sleep(0.01)
                continue
            for msg in sent:
                if msg.arbitration_id != 0x600 + NODE or msg.data[0] != 0x40:
                    continue
                self.requests += 1
                if self.muted:
                    continue
                index, subindex = struct.unpack_from("<HB", msg.data, 1)
                self.before_answer()
                self.kernel.inject(_answer(index, subindex, index * 0x100 + subindex), bus)

    def close(self) -> None:
        self._stop.set()
        self._thread.join()


@pytest.fixture
def peer(kernel: KernelStandIn) -> Iterator[_Peer]:
    p = _Peer(kernel)
    yield p
    p.close()


def _ends(call: Callable[[], Any], bound: float = 20.0) -> Any:
    """Run ``call`` in a thread; it must end within ``bound`` seconds (a hang otherwise)."""
    out: dict[str, Any] = {}

    def run() -> None:
        try:
            out["value"] = call()
        except BaseException as exc:
            out["error"] = exc

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    thread.join(bound)
    assert not thread.is_alive(), "the call never ended"
    if "error" in out:
        raise out["error"]
    return out.get("value")


def _eventually(done: Callable[[], bool], seconds: float) -> None:
    """Wait until ``done()`` (a frame or event another thread delivers), at most ``seconds``;
    the assertion after it says what was missing."""
    deadline = time.monotonic() + seconds
    while not done() and time.monotonic() < deadline:
        time.sleep(0.002)


def _value(index: int, subindex: int = 0) -> bytes:
    return (index * 0x100 + subindex).to_bytes(4, "little")


def test_back_to_back_calls_read_their_answers_themselves(kernel, peer, monkeypatch):
    """The first call finds the reader thread reading and waits; the reader lets go once it
    has dispatched that answer, and every next call reads its own."""
    monkeypatch.setattr(_reading, "GRACE", 30.0)  # the reader never takes it back here
    with Network(interface="socketcan", channel="can0") as net:
        role = net.aio._reading
        assert role is not None and net.aio._reader is None
        sdo = net.add_remote(NODE).sdo
        for i in range(50):
            assert sdo.upload(0x2000 + i) == _value(0x2000 + i)
        assert role._takes == 49  # all but the first
        assert role.read_by_callers == 49
        assert net.aio.frames_received == 50


def test_a_reading_caller_is_woken_when_the_loop_settles_its_outcome(kernel, peer, monkeypatch):
    """Outcomes that come from the loop, not from a frame the caller reads: a device of the
    same network (it answers through the loop's local echo), and an SDO timeout. The caller
    is poked awake; it would otherwise sleep in ``select`` for a minute here."""
    monkeypatch.setattr(_reading, "GRACE", 60.0)
    monkeypatch.setattr(_reading, "_CALLER_WAIT", 60.0)
    with Network(interface="socketcan", channel="can0") as net:
        od = minimal_od()
        add_device(net, 9, od)
        device_type = int(od[0x1000].default).to_bytes(4, "little")  # type: ignore[union-attr]
        local = net.add_remote(9).sdo
        assert _ends(lambda: local.upload(0x1000)) == device_type
        remote = net.add_remote(NODE, sdo_timeout=0.3).sdo
        assert remote.upload(0x2001) == _value(0x2001)  # (the role passes to callers)
        role = net.aio._reading
        assert role is not None
        before = role._takes
        for _ in range(5):
            assert _ends(lambda: local.upload(0x1000)) == device_type
        assert role._takes == before + 5  # each read the bus, and was poked
        peer.muted = True
        with pytest.raises(SdoTimeoutError):
            _ends(lambda: remote.upload(0x2002))
        assert role._takes == before + 6
        peer.muted = False
        assert remote.upload(0x2003) == _value(0x2003)


@pytest.mark.parametrize("presses", [1, 2])
def test_ctrl_c_in_a_reading_caller_gives_the_role_back(kernel, peer, monkeypatch, presses):
    """SIGINT while the main thread reads for an answer that does not come: the call raises
    KeyboardInterrupt, the transfer is cancelled, the role is given back, and the next
    calls work — also when a second SIGINT lands while the abort is sent."""
    monkeypatch.setattr(_reading, "GRACE", 60.0)
    with Network(interface="socketcan", channel="can0") as net:
        sdo = net.add_remote(NODE, sdo_timeout=30.0).sdo
        assert sdo.upload(0x2000) == _value(0x2000)  # the reader thread lets go of the role
        role = net.aio._reading
        assert role is not None
        seen = peer.requests
        peer.muted = True
        main = threading.main_thread().ident
        assert main is not None
        if presses == 2:
            second_ctrl_c_on_abort(net.aio.bus)

        def interrupt() -> None:
            while peer.requests == seen:
                time.sleep(0.01)
            while _reading._ROLE not in role._claim:
                time.sleep(0.01)
            signal.pthread_kill(main, signal.SIGINT)

        threading.Thread(target=interrupt, daemon=True).start()
        with pytest.raises(KeyboardInterrupt):
            sdo.upload(0x2001)
        assert role._takes == 1
        assert role._claim.get(_reading._ROLE) != main  # (the reader thread's now)
        peer.muted = False
        assert _ends(lambda: sdo.upload(0x2002)) == _value(0x2002)  # (the channel is free)
        assert sdo.upload(0x2003) == _value(0x2003)
        assert sdo.upload(0x2004) == _value(0x2004)
        assert role._takes >= 2  # (the first of them may find the reader still reading)


def test_frames_keep_their_order_whoever_reads_them(kernel, peer, monkeypatch):
    """A stream of PDOs arrives while calls go on: the reader thread and the calling threads
    read in turns, and the subscriber sees every frame once, in order. (While several
    callers wait at once, the reader thread keeps the role.)"""
    monkeypatch.setattr(_reading, "GRACE", 0.05)
    count = 0

    def stream() -> None:
        nonlocal count
        for _ in range(20):
            kernel.inject(
                can.Message(
                    arbitration_id=0x181, data=count.to_bytes(4, "little"), is_extended_id=False
                )
            )
            count += 1

    peer.before_answer = stream
    with Network(interface="socketcan", channel="can0") as net:
        got: list[int] = []
        net.subscribe(0x181, lambda f, now: got.append(int.from_bytes(f.data, "little")))
        sdo = net.add_remote(NODE).sdo

        def calls(first: int) -> None:
            for i in range(40):
                assert sdo.upload(first + i) == _value(first + i)
                if i % 10 == 9:
                    time.sleep(0.1)  # past GRACE: the reader thread takes the role back

        calls(0x2000)  # alone: the caller reads, and the reader thread after each pause
        role = net.aio._reading
        assert role is not None
        assert 0 < role.read_by_callers < net.aio.frames_received
        workers = [threading.Thread(target=calls, args=(0x2100 + 0x100 * n,)) for n in range(2)]
        for worker in workers:
            worker.start()
        calls(0x2300)
        for worker in workers:
            worker.join(20.0)
        _eventually(lambda: len(got) >= count, 5.0)
        assert got == list(range(count)) and count == 160 * 20


def test_a_failing_read_backs_off_and_the_call_still_ends(kernel, peer, monkeypatch):
    """The socket fails while a caller reads: it gives the role back and waits; the reader
    thread reports each failure and backs off (no busy loop); the transfer times out."""
    monkeypatch.setattr(_reading, "GRACE", 60.0)
    with Network(interface="socketcan", channel="can0") as net:
        events: list[ReceiveFailed] = []
        net.add_listener(lambda e: events.append(e) if isinstance(e, ReceiveFailed) else None)
        sdo = net.add_remote(NODE, sdo_timeout=0.6).sdo
        assert sdo.upload(0x2000) == _value(0x2000)
        bus: Any = net.aio.bus
        reads = 0

        def failing(timeout: float | None = None) -> can.Message | None:
            nonlocal reads
            reads += 1
            raise can.CanOperationError("the interface went away")

        bus.recv = failing
        peer.muted = True
        kernel.inject(can.Message(arbitration_id=0x181, is_extended_id=False))  # readable
        with pytest.raises(SdoTimeoutError):
            _ends(lambda: sdo.upload(0x2001))
        role = net.aio._reading
        assert role is not None and role._takes == 1
        assert 2 <= reads <= 10  # the caller's, then the reader's: 50, 100, 200, 400 ms apart
        _eventually(lambda: bool(events), 2.0)
        assert events and "went away" in events[0].reason


def test_the_parked_reader_looks_less_often_during_a_long_wait(kernel, peer, monkeypatch):
    """While one caller holds the role for a second, the reader thread looks at it a few
    times (2, 4, 8 ... 50 ms apart), not every 2 ms; the caller wakes it when it lets go."""
    with Network(interface="socketcan", channel="can0") as net:
        sdo = net.add_remote(NODE, sdo_timeout=1.0).sdo
        assert sdo.upload(0x2000) == _value(0x2000)
        role = net.aio._reading
        assert role is not None
        looks = 0
        park = role._park_for

        def counted(seconds: float) -> None:
            nonlocal looks
            looks += 1
            park(seconds)

        role._park_for = counted  # type: ignore[method-assign]
        peer.muted = True
        with pytest.raises(SdoTimeoutError):
            sdo.upload(0x2001)
        assert role._takes == 1
        assert looks < 40  # every 2 ms: ~500


def test_a_reconnected_network_reads_with_a_new_role(kernel, peer):
    """disconnect stops the role's thread and closes its sockets; connect starts a new one."""
    with Network(interface="socketcan", channel="can0") as net:
        sdo = net.add_remote(NODE).sdo
        assert sdo.upload(0x2000) == _value(0x2000)
        first = net.aio._reading
        assert first is not None
        net.run(net.aio.disconnect())
        assert net.aio._reading is None and first._poke_w.fileno() == -1
        assert first._thread is None
        net.run(net.aio.connect())
        second: Any = net.aio._reading  # (mypy: not the None it saw above)
        assert second is not None and second is not first
        for i in range(3):
            assert sdo.upload(0x2001 + i) == _value(0x2001 + i)


def test_a_bus_without_a_whole_frame_descriptor_keeps_its_reader_thread():
    """python-can's virtual bus has no descriptor: the reader thread reads, callers wait."""
    with Network(interface="virtual", channel=f"reading-{os.getpid()}") as net:
        assert net.aio._reading is None and net.aio._reader is not None
        net.send(Frame(0x181, b"\x01"))


def test_a_coroutine_run_from_blocking_code_has_the_reader_thread_read_at_once(
    kernel, peer, monkeypatch
):
    """After a call that read its own answer the role is free; a coroutine run on the loop
    (``net.run``) waits for frames it does not read, so the reader thread takes the role at
    once instead of after GRACE (a minute here)."""
    monkeypatch.setattr(_reading, "GRACE", 60.0)
    with Network(interface="socketcan", channel="can0") as net:
        sdo = net.add_remote(NODE).sdo
        assert sdo.upload(0x2000) == _value(0x2000)
        assert sdo.upload(0x2001) == _value(0x2001)  # read by the caller
        role = net.aio._reading
        assert role is not None and role._takes == 1
        assert _ends(lambda: net.run(sdo.aio.upload(0x2002))) == _value(0x2002)
        assert role._takes == 1


def test_frame_handlers_have_the_loop_as_their_running_loop_whoever_reads(
    kernel, peer, monkeypatch
):
    """A handler on the network (``net.aio``) may call ``asyncio.get_running_loop()``: the
    reader thread and a reading caller both run it with the network's loop."""
    monkeypatch.setattr(_reading, "GRACE", 60.0)
    pdo = can.Message(arbitration_id=0x181, data=b"\x01", is_extended_id=False)
    with Network(interface="socketcan", channel="can0") as net:
        seen: list[tuple[str, bool]] = []

        def handler(frame: Frame, now: float) -> None:
            same = asyncio.get_running_loop() is net._runner.loop
            seen.append((threading.current_thread().name, same))

        net._runner.call(net.aio.subscribe, 0x181, handler)
        kernel.inject(pdo)  # the reader thread reads it
        _eventually(lambda: bool(seen), 5.0)
        sdo = net.add_remote(NODE).sdo
        assert sdo.upload(0x2000) == _value(0x2000)
        peer.before_answer = lambda: kernel.inject(pdo)
        assert sdo.upload(0x2001) == _value(0x2001)  # the caller reads the PDO and its answer
        assert seen == [("cobus-rx", True), (threading.current_thread().name, True)]
        with pytest.raises(RuntimeError):
            asyncio.get_running_loop()  # (the caller's own is put back)


def test_descriptors_above_select_s_limit_are_read(kernel, peer):
    """With a thousand descriptors open, the role's socket pair lands above 1023, where
    ``select`` refuses descriptors: it waits with ``poll``. (The bus's own stays below:
    python-can's SocketCAN ``recv`` uses ``select``.)"""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if hard != resource.RLIM_INFINITY and hard < 2048:
        pytest.skip("cannot open 1,100 descriptors here")
    resource.setrlimit(resource.RLIMIT_NOFILE, (2048, hard))
    fillers: list[int] = []
    try:
        while not fillers or fillers[-1] < 1018:
            fillers.append(os.open(os.devnull, os.O_RDONLY))
        with Network(interface="socketcan", channel="can0") as net:
            role = net.aio._reading
            assert role is not None
            if not role._fd < 1024 <= role._poke_r.fileno():
                pytest.skip(f"descriptors {role._fd} and {role._poke_r.fileno()} here")
            failures: list[ReceiveFailed] = []
            net.add_listener(lambda e: failures.append(e) if isinstance(e, ReceiveFailed) else None)
            sdo = net.add_remote(NODE).sdo
            for i in range(20):
                assert sdo.upload(0x2000 + i) == _value(0x2000 + i)
            assert role.read_by_callers > 0 and not failures
    finally:
        for fd in fillers:
            os.close(fd)
        resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))


def test_sigint_while_the_main_thread_reads_never_strands_another_thread(kernel):
    """Real SIGINTs at random moments while the main thread and a worker thread call devices
    of another network: the main thread dispatches the worker's answers with SIGINT's
    handler put aside, so every interrupt ends the main thread's call alone. The worker
    never times out and the protocol lock is never left taken."""
    kernel.start_vcan()
    rng = random.Random(20)
    main = threading.main_thread().ident
    assert main is not None
    with (
        Network(interface="socketcan", channel="vcan0") as field,
        Network(interface="socketcan", channel="vcan0") as client,
    ):
        for node in (5, 6):
            add_device(field, node, minimal_od())
        worker_sdo = client.add_remote(5, sdo_timeout=0.5).sdo
        main_sdo = client.add_remote(6, sdo_timeout=0.5).sdo
        stop = threading.Event()
        calls, failures = [0], []

        def worker() -> None:
            while not stop.is_set():
                try:
                    worker_sdo.upload(0x1000)
                except Exception as exc:
                    failures.append(exc)
                calls[0] += 1

        thread = threading.Thread(target=worker, daemon=True)
        thread.start()
        loop = client._runner.loop
        assert isinstance(loop, RealTimeLoop)
        lock = loop.protocol_lock
        role = client.aio._reading
        assert role is not None
        interrupts = 0
        try:
            for _ in range(400):
                timer = threading.Timer(
                    rng.uniform(0.001, 0.01), signal.pthread_kill, (main, signal.SIGINT)
                )
                try:  # (the signal may come before start() returns: the GIL is busy)
                    timer.start()
                    while True:
                        main_sdo.upload(0x1000)
                except KeyboardInterrupt:
                    interrupts += 1
                timer.join()
                assert not lock._is_owned()  # type: ignore[attr-defined]
                before = calls[0]

                def moved(seen: int = before) -> bool:
                    return calls[0] > seen

                _eventually(moved, 3.0)
                assert calls[0] > before, "the worker stopped"
        finally:
            stop.set()
            thread.join(5.0)
        assert interrupts == 400 and not failures
        assert role._takes > 0
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
        assert not role._sigint.hit


def test_the_main_thread_leaves_the_bus_to_the_reader_while_another_signal_has_a_handler(
    kernel, peer, monkeypatch
):
    """A Python handler of another signal (SIGALRM timeouts, SIGTERM, SIGUSR1) may raise at
    any bytecode of the main thread: it then waits as before, and reads again once the
    handler is gone. Another thread still reads."""
    monkeypatch.setattr(_reading, "GRACE", 60.0)
    with Network(interface="socketcan", channel="can0") as net:
        sdo = net.add_remote(NODE).sdo
        role = net.aio._reading
        assert role is not None
        assert sdo.upload(0x2000) == _value(0x2000)
        previous = signal.signal(signal.SIGUSR1, lambda signum, frame: None)
        try:
            for i in range(5):
                assert sdo.upload(0x2001 + i) == _value(0x2001 + i)
            assert role._takes == 0
            assert _ends(lambda: sdo.upload(0x2006)) == _value(0x2006)  # not the main thread
            assert role._takes == 1
        finally:
            signal.signal(signal.SIGUSR1, previous)
        assert sdo.upload(0x2007) == _value(0x2007)
        assert role._takes == 2


def test_a_sigint_handler_that_does_not_raise_lets_the_call_go_on(kernel, peer, monkeypatch):
    """The user's own SIGINT handler runs once per signal when the reading caller gives the
    role back, and the call still gets its answer; the handler is put back after."""
    monkeypatch.setattr(_reading, "GRACE", 60.0)
    main = threading.main_thread().ident
    assert main is not None
    seen: list[int] = []

    def counting(signum: int, frame: object) -> None:
        seen.append(signum)

    previous = signal.signal(signal.SIGINT, counting)
    try:
        with Network(interface="socketcan", channel="can0") as net:
            sdo = net.add_remote(NODE).sdo
            role = net.aio._reading
            assert role is not None
            assert sdo.upload(0x2000) == _value(0x2000)
            sent = peer.requests

            def interrupt_then_answer() -> None:
                while _reading._ROLE not in role._claim or peer.requests == sent:
                    time.sleep(0.005)
                signal.pthread_kill(main, signal.SIGINT)
                time.sleep(0.05)
                peer.muted = False
                kernel.inject(_answer(0x2001, 0, 0x2001 * 0x100))

            peer.muted = True
            threading.Thread(target=interrupt_then_answer, daemon=True).start()
            assert sdo.upload(0x2001) == _value(0x2001)
            assert seen == [signal.SIGINT] and role._takes == 1
            assert signal.getsignal(signal.SIGINT) is counting
    finally:
        signal.signal(signal.SIGINT, previous)
