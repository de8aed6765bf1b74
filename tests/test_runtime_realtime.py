"""The real-time path (issue 20): the loop's protocol lock, and reader threads that dispatch
frames directly under it instead of handing every frame over to the loop."""

import asyncio
import os
import signal
import threading
import time

import can
import pytest

from cobus.device import DictionaryBuilder, add_device
from cobus.od import DataType, ObjectDictionary
from cobus.proto import Frame
from cobus.proto.sdo import SdoTimeoutError
from cobus.runtime import AsyncNetwork, Network, run
from cobus.runtime.errors import NetworkClosedError, ReentrantCallError
from cobus.runtime.loop import RealTimeLoop, new_event_loop
from cobus.runtime.network import MachineHost
from tests.util import second_ctrl_c_on_abort


def test_the_real_time_loop_of_the_blocking_facade_is_a_real_time_loop():
    loop = new_event_loop()
    try:
        assert isinstance(loop, RealTimeLoop)
    finally:
        loop.close()


def test_the_protocol_lock_is_reentrant_and_the_loop_knows_who_holds_it():
    loop = RealTimeLoop()
    try:
        assert not loop.lock_held()
        with loop.protocol_lock:
            with loop.protocol_lock:
                assert loop.lock_held()
            assert loop.lock_held()
            other: list[bool] = []
            t = threading.Thread(
                target=lambda: other.extend(
                    [loop.lock_held(), loop.protocol_lock.acquire(True, 0.01)]
                )
            )
            t.start()
            t.join()
            assert other == [False, False]  # another thread neither holds it nor gets it
        assert not loop.lock_held()
    finally:
        loop.close()


class _LoopThread:
    def __init__(self) -> None:
        self.loop = RealTimeLoop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()
        self.wait_asleep()

    def wait_asleep(self, until: float = float("inf")) -> None:
        """Until the loop sleeps, at most until ``until`` on its clock."""
        deadline = time.monotonic() + 2
        while self.loop._sleeping_until is None or self.loop._sleeping_until > until:
            assert time.monotonic() < deadline, "the loop never went to sleep"
            time.sleep(0.001)

    def close(self) -> None:
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(2)
        self.loop.close()


@pytest.fixture
def looping():
    lt = _LoopThread()
    yield lt
    lt.close()


def test_the_loop_holds_the_lock_except_while_it_sleeps(looping):
    loop = looping.loop
    seen: list[bool] = []
    loop.call_soon_threadsafe(lambda: seen.append(loop.lock_held()))
    deadline = time.monotonic() + 2
    while not seen and time.monotonic() < deadline:
        time.sleep(0.001)
    assert seen == [True]
    looping.wait_asleep()
    assert loop.protocol_lock.acquire(True, 1.0)  # free while it sleeps
    loop.protocol_lock.release()


def test_call_soon_under_the_lock_wakes_the_sleeping_loop_once_the_lock_is_let_go(looping):
    loop = looping.loop
    ran = threading.Event()
    with loop.protocol_lock:
        loop.call_soon(ran.set)
        assert loop.wake_pending
        assert not ran.wait(0.05)  # the loop cannot run it while this thread holds the lock
    assert not ran.wait(0.05)  # asleep without a timer until woken:
    loop.wake_if_pending()
    assert ran.wait(2.0)  # then it runs at once
    assert not loop.wake_pending


def test_a_thread_woken_from_under_the_lock_wakes_once_the_holder_lets_go(looping):
    loop = looping.loop
    woken = threading.Event()
    loop.wake_after_release(woken.set)  # this thread does not hold the lock: at once
    assert woken.is_set()
    woken.clear()
    with loop.protocol_lock:
        loop.wake_after_release(woken.set)
        assert not woken.is_set()  # woken now, it would only wait for the GIL or the lock
    assert not woken.wait(0.05)  # (the holder's own wake_if_pending wakes it)
    loop.wake_if_pending()
    assert woken.is_set()


def test_each_holder_of_the_lock_runs_only_the_wakes_it_owes(looping):
    """Ctrl-C lands in the main thread only: a wake-up owed by another thread is never in
    the main thread's hands, where an interrupt could drop it."""
    loop = looping.loop
    mine, theirs = threading.Event(), threading.Event()
    let_go, go = threading.Event(), threading.Event()

    def other() -> None:
        with loop.protocol_lock:
            loop.wake_after_release(theirs.set)
        let_go.set()
        go.wait(2.0)
        loop.wake_if_pending()

    t = threading.Thread(target=other)
    t.start()
    assert let_go.wait(2.0)
    with loop.protocol_lock:
        loop.wake_after_release(mine.set)
    loop.wake_if_pending()
    assert mine.is_set() and not theirs.is_set()  # the other thread's is left to it
    go.set()
    t.join(2.0)
    assert theirs.is_set()


def test_the_loop_wakes_waiting_threads_before_it_sleeps_or_runs_more(looping):
    loop = looping.loop
    order: list[str] = []
    woken = threading.Event()

    def wake() -> None:
        order.append("woken")
        woken.set()

    def job() -> None:  # protocol code on the loop, as a received answer's dispatch
        loop.wake_after_release(wake)
        loop.call_soon(lambda: order.append("the next turn's work"))
        order.append("job done")

    loop.call_soon_threadsafe(job)
    assert woken.wait(2.0)
    looping.wait_asleep()
    # not in the middle of the job; before work left for the next turn
    assert order == ["job done", "woken", "the next turn's work"]
    woken.clear()
    loop.call_soon_threadsafe(lambda: loop.wake_after_release(woken.set))
    assert woken.wait(2.0)  # a turn with nothing after it: woken as the loop goes to sleep


def test_a_stopping_loop_wakes_the_threads_it_owes_a_wake_up():
    lt = _LoopThread()
    woken = threading.Event()

    def job() -> None:
        lt.loop.wake_after_release(woken.set)
        lt.loop.stop()

    lt.loop.call_soon_threadsafe(job)
    lt.thread.join(2)
    assert woken.is_set()
    lt.loop.close()


def test_a_timer_set_under_the_lock_wakes_the_loop_only_when_due_before_it_would_wake(looping):
    loop = looping.loop
    fired = threading.Event()
    with loop.protocol_lock:
        loop.call_at(loop.time() + 0.01, fired.set)
        assert loop.wake_pending  # it slept without a timer: woken
    loop.wake_if_pending()
    assert fired.wait(2.0)
    looping.wait_asleep()
    with loop.protocol_lock:
        loop.call_at(loop.time() + 30, lambda: None)
    loop.wake_if_pending()
    looping.wait_asleep(until=loop.time() + 31)
    with loop.protocol_lock:
        loop.call_at(loop.time() + 60, lambda: None)  # later than it will wake anyway
        assert not loop.wake_pending


def test_a_reader_thread_dispatches_frames_itself_under_the_lock():
    with Network(interface="virtual", channel="rt-direct") as net:
        raw = can.Bus(interface="virtual", channel="rt-direct")
        seen: list[tuple[str, bool]] = []
        done = threading.Event()
        loop = net.aio.loop
        assert isinstance(loop, RealTimeLoop)

        def handler(frame: Frame, now: float) -> None:
            seen.append((threading.current_thread().name, loop.lock_held()))
            done.set()

        net._runner.call(net.aio.subscribe, 0x123, handler)
        raw.send(can.Message(arbitration_id=0x123, data=b"\x01", is_extended_id=False))
        assert done.wait(2.0)
        raw.shutdown()
    assert seen == [("cobus-rx", True)]


def test_a_reader_thread_drops_our_own_messages_without_the_lock():
    bus = can.Bus(interface="virtual", channel="rt-own", receive_own_messages=True)
    with Network(bus) as net:
        got: list[Frame] = []
        net.subscribe(0x123, lambda f, now: got.append(f))
        loop = net.aio.loop
        assert isinstance(loop, RealTimeLoop) and net.aio._reader is not None
        with loop.protocol_lock:  # as a blocking caller sends: under the lock
            net.aio.send(Frame(0x123, b"\x01"))
            deadline = time.monotonic() + 5  # the reader takes it back meanwhile...
            while not bus.queue.empty():  # type: ignore[attr-defined]
                assert time.monotonic() < deadline, "the reader never took the message"
                time.sleep(0.001)
            time.sleep(0.01)
            # ...and drops it: it neither waits for the lock nor hands it to the loop
            assert not net.aio._rx_pending and not net.aio._rx_posted
        loop.wake_if_pending()
        deadline = time.monotonic() + 5
        while not got and time.monotonic() < deadline:
            time.sleep(0.001)
        time.sleep(0.05)
        assert got == [Frame(0x123, b"\x01")]  # the local echo, once
    bus.shutdown()


def test_the_blocking_network_reads_a_descriptor_bus_with_a_thread(request, monkeypatch):
    """Where AsyncNetwork's loop reads the descriptor itself, the blocking Network uses a
    reader thread, or its waiting callers (read_on_loop=False: cobus.runtime.reading);
    read_on_loop=True gives it the loop's way."""
    from cobus.runtime import bus as bus_module

    bus = can.Bus(interface="virtual", channel="rt-fd")
    r, w = os.pipe()  # a descriptor that never becomes readable
    request.addfinalizer(lambda: (os.close(r), os.close(w)))
    # a virtual bus standing for one the loop could watch: what loop_source decides on
    monkeypatch.setattr(bus_module, "loop_source", lambda b: bus_module.LoopSource(r, None))
    with Network(bus) as net:
        assert net.aio._reading is not None and net.aio._fd is None
    with Network(bus, read_on_loop=True) as net:
        assert net.aio._reader is None and net.aio._fd == r
    bus.shutdown()


def test_frames_keep_their_order_when_a_busy_loop_makes_the_reader_hand_them_over():
    with Network(interface="virtual", channel="rt-busy") as net:
        raw = can.Bus(interface="virtual", channel="rt-busy")
        got: list[int] = []
        threads: set[str] = set()
        loop = net.aio.loop

        def handler(frame: Frame, now: float) -> None:
            got.append(frame.data[0] | frame.data[1] << 8)
            threads.add(threading.current_thread().name)

        def busy() -> None:  # the loop holds the lock 10 ms at a time, for the first half
            time.sleep(0.01)
            if len(got) < 1000:
                loop.call_soon(busy)

        net._runner.call(net.aio.subscribe, 0x124, handler)
        loop.call_soon_threadsafe(busy)
        for n in range(2000):
            raw.send(
                can.Message(
                    arbitration_id=0x124, data=n.to_bytes(2, "little"), is_extended_id=False
                )
            )
            if n % 100 == 99:
                time.sleep(0.02)
        deadline = time.monotonic() + 10
        while len(got) < 2000 and time.monotonic() < deadline:
            time.sleep(0.01)
        raw.shutdown()
    assert got == list(range(2000))
    assert threads == {"cobus-rx", "cobus-loop"}  # both ways were taken, in one order


def test_blocking_calls_from_a_dispatching_reader_thread_do_not_deadlock():
    with Network(interface="virtual", channel="rt-reentrant") as net:
        raw = can.Bus(interface="virtual", channel="rt-reentrant")
        outcome: list[object] = []
        done = threading.Event()

        async def nothing() -> None:
            return None

        def handler(frame: Frame, now: float) -> None:
            outcome.append(net._runner.call(lambda: threading.current_thread().name))
            try:
                net._runner.run(nothing())
            except ReentrantCallError as exc:
                outcome.append(type(exc))
            done.set()

        net._runner.call(net.aio.subscribe, 0x125, handler)
        raw.send(can.Message(arbitration_id=0x125, data=b"", is_extended_id=False))
        assert done.wait(2.0)
        raw.shutdown()
    assert outcome == ["cobus-rx", ReentrantCallError]


# -- blocking SDO transfers begun in the caller's thread


def _device_od() -> ObjectDictionary:
    b = DictionaryBuilder(device_name="rt")
    b.variable(0x2000, "Blob", DataType.DOMAIN)
    for n in range(8):
        b.variable(0x2100 + n, f"Value {n}", DataType.UNSIGNED32, default=n * 1000)
    return b.build()


@pytest.fixture
def pair():
    """A blocking client and a cobus device on node 5, in real time on a virtual bus."""
    channel = f"rt-sdo-{threading.get_ident()}-{time.monotonic_ns()}"
    client = Network(interface="virtual", channel=channel)
    field = Network(interface="virtual", channel=channel)
    add_device(field, 5, _device_od())
    yield client, client.add_remote(5, _device_od())
    client.close()
    field.close()


def test_a_blocking_transfer_sends_from_the_callers_thread(pair):
    client, node = pair
    senders: list[str] = []
    bus = client.aio._bus
    send = bus.send

    def recording_send(msg: can.Message, timeout: float | None = None) -> None:
        senders.append(threading.current_thread().name)
        send(msg, timeout)

    bus.send = recording_send
    try:
        assert node.sdo.upload(0x2101) == (1000).to_bytes(4, "little")
        assert node.sdo["Value 2"].raw == 2000
        node.sdo.write("Value 3", 7)
        assert node.sdo.read(0x2103) == 7
        assert node.sdo[0x1018][1].raw == 0  # a record's sub-object: vendor-ID
    finally:
        bus.send = send
    assert set(senders) == {threading.current_thread().name}  # no hop through the loop


def test_segmented_and_block_transfers_take_the_direct_path_too(pair):
    _, node = pair
    blob = bytes(range(256)) * 16
    node.sdo.download(0x2000, 0, blob)
    assert node.sdo.upload(0x2000) == blob
    node.sdo["Blob"].download(blob[::-1], block=True)
    assert node.sdo["Blob"].upload(block=True) == blob[::-1]


def test_threads_sharing_a_channel_each_get_their_own_answers(pair):
    _, node = pair
    errors: list[BaseException] = []

    def reader(n: int) -> None:
        try:
            for _ in range(60):
                assert node.sdo.read(0x2100 + n) == n * 1000
        except BaseException as exc:
            errors.append(exc)

    threads = [threading.Thread(target=reader, args=(n,)) for n in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    assert errors == []


def test_a_silent_node_times_out_and_leaves_the_channel_free():
    with Network(interface="virtual", channel="rt-silent") as net:
        node = net.add_remote(9, sdo_timeout=0.05)
        for _ in range(2):
            with pytest.raises(SdoTimeoutError) as err:
                node.sdo.upload(0x1000)
            assert err.value.timeout == 0.05  # (its own timeout ended it, not another wait)


def test_closing_the_network_ends_a_waiting_transfer():
    net = Network(interface="virtual", channel="rt-close")
    node = net.add_remote(9, sdo_timeout=30)
    timer = threading.Timer(0.1, net.close)
    timer.start()
    try:
        with pytest.raises(NetworkClosedError):
            node.sdo.upload(0x1000)
    finally:
        timer.join()
        net.close()


def test_ctrl_c_while_waiting_aborts_the_transfer_and_frees_the_channel():
    with Network(interface="virtual", channel="rt-ctrl-c") as net:
        raw = can.Bus(interface="virtual", channel="rt-ctrl-c")
        node = net.add_remote(9, sdo_timeout=30)
        timer = threading.Timer(0.1, os.kill, (os.getpid(), signal.SIGINT))
        timer.start()
        with pytest.raises(KeyboardInterrupt):
            node.sdo.upload(0x1000)
        timer.join()
        frames = []
        while (msg := raw.recv(0.5)) is not None:
            frames.append((msg.arbitration_id, msg.data[0]))
        raw.shutdown()
        assert frames == [(0x609, 0x40), (0x609, 0x80)]  # the request, then its abort
        node.sdo.timeout = 0.05
        with pytest.raises(SdoTimeoutError):  # free: the next transfer runs (and times out)
            node.sdo.upload(0x1000)


def test_a_second_ctrl_c_while_the_transfer_is_cancelled_still_frees_the_channel():
    """The user presses Ctrl-C twice: the second SIGINT lands while the first one's cleanup
    sends the abort (here, exactly then). It is raised once the channel is free, not in the
    middle of the cancellation, which would leave the channel busy for good."""
    with Network(interface="virtual", channel="rt-ctrl-c-twice") as net:
        raw = can.Bus(interface="virtual", channel="rt-ctrl-c-twice")
        node = net.add_remote(9, sdo_timeout=30)
        second_ctrl_c_on_abort(net.aio.bus)
        timer = threading.Timer(0.1, os.kill, (os.getpid(), signal.SIGINT))
        timer.start()
        with pytest.raises(KeyboardInterrupt) as second:
            node.sdo.upload(0x1000)
        timer.join()
        assert isinstance(second.value.__context__, KeyboardInterrupt)  # raised after the first
        frames = []
        while (msg := raw.recv(0.5)) is not None:
            frames.append((msg.arbitration_id, msg.data[0]))
        raw.shutdown()
        assert frames == [(0x609, 0x40), (0x609, 0x80)]
        node.sdo.timeout = 0.05
        outcome: list[BaseException] = []

        def next_transfer() -> None:  # free: it runs (and times out)
            try:
                node.sdo.upload(0x1000)
            except BaseException as exc:
                outcome.append(exc)

        caller = threading.Thread(target=next_transfer, daemon=True)
        caller.start()
        caller.join(5.0)
        assert outcome, "the channel stayed busy: the next transfer never started"
        assert isinstance(outcome[0], SdoTimeoutError)


# -- the asyncio API on a RealTimeLoop (cobus.runtime.run)


def test_async_programs_get_the_direct_path_with_cobus_run():
    async def main() -> tuple[list[tuple[str, bool]], bytes, str]:
        loop = asyncio.get_running_loop()
        assert isinstance(loop, RealTimeLoop)
        async with (
            AsyncNetwork(interface="virtual", channel="rt-run") as net,
            AsyncNetwork(interface="virtual", channel="rt-run") as field,
        ):
            add_device(field, 5, _device_od())
            seen: list[tuple[str, bool]] = []
            tasks: list[asyncio.Task[None]] = []
            task_ran = loop.create_future()

            async def later() -> None:
                task_ran.set_result(threading.current_thread().name)

            def handler(frame: Frame, now: float) -> None:
                seen.append((threading.current_thread().name, asyncio.get_running_loop() is loop))
                tasks.append(asyncio.create_task(later()))  # as on the loop

            net.subscribe(0x585, handler)
            data = await net.add_remote(5).sdo.upload(0x2101)
            where = await asyncio.wait_for(task_ran, 2.0)
            return seen, data, where

    seen, data, where = run(main())
    assert seen == [("cobus-rx", True)]
    assert data == (1000).to_bytes(4, "little")
    assert where == threading.current_thread().name  # the task ran on the loop


# -- found in review: Ctrl-C at any moment, close() from a reader, a reader outliving its loop


def test_ctrl_c_at_any_moment_of_blocking_transfers_leaves_the_network_alive():
    """SIGINT lands anywhere in a tight loop of transfers (also inside the lock's acquire or
    release, which is why the protocol lock is one C call per operation)."""
    for trial in range(12):
        channel = f"rt-sigint-{trial}"
        with (
            Network(interface="virtual", channel=channel) as client,
            Network(interface="virtual", channel=channel) as field,
        ):
            add_device(field, 5, _device_od())
            node = client.add_remote(5, _device_od())
            timer = threading.Timer(0.01 + trial * 0.005, os.kill, (os.getpid(), signal.SIGINT))
            timer.start()
            with pytest.raises(KeyboardInterrupt):
                while True:
                    node.sdo.upload(0x2101)
            timer.join()
            alive = threading.Event()
            threading.Thread(
                target=lambda ev=alive: (client._runner.call(int), ev.set()), daemon=True
            ).start()
            assert alive.wait(2.0), "the loop no longer runs"
            assert node.sdo.read(0x2101) == 1000


def test_close_from_a_handler_on_a_reader_thread_returns_at_once():
    net = Network(interface="virtual", channel="rt-close-rx")
    raw = can.Bus(interface="virtual", channel="rt-close-rx")
    took: list[tuple[str, float]] = []

    def handler(frame: Frame, now: float) -> None:
        t0 = time.monotonic()
        net.close()
        took.append((threading.current_thread().name, time.monotonic() - t0))

    net._runner.call(net.aio.subscribe, 0x123, handler)
    raw.send(can.Message(arbitration_id=0x123, data=b"", is_extended_id=False))
    deadline = time.monotonic() + 5
    while not net._runner.loop.is_closed() and time.monotonic() < deadline:
        time.sleep(0.01)
    raw.shutdown()
    assert [name for name, _ in took] == ["cobus-rx"]
    assert net._runner.loop.is_closed()  # (within the 5 s above: it did not wait for itself)


def test_a_reader_thread_ends_with_its_closed_loop():
    channel = "rt-orphan"

    async def main() -> None:  # leaves its network connected
        field = AsyncNetwork(interface="virtual", channel=channel)
        await field.connect()
        add_device(field, 5, _device_od())

    before = set(threading.enumerate())
    run(main())
    readers = [t for t in set(threading.enumerate()) - before if t.name == "cobus-rx"]
    assert len(readers) == 1
    raw = can.Bus(interface="virtual", channel=channel)
    answers = 0
    request = bytes([0x40, 1, 0x21, 0, 0, 0, 0, 0])
    for _ in range(3):
        raw.send(can.Message(arbitration_id=0x605, data=request, is_extended_id=False))
        while (msg := raw.recv(0.1)) is not None:
            answers += msg.arbitration_id == 0x585
    raw.shutdown()
    assert answers == 0  # no protocol code runs without its loop
    readers[0].join(2.0)
    assert not readers[0].is_alive(), "the reader thread outlived its loop"


def test_file_descriptors_wake_the_loop_during_its_sub_millisecond_waits():
    """Waits under 2 ms use select() (epoll rounds up to whole milliseconds): readers added
    to the loop are watched there too, and removed from both."""
    import socket

    async def main() -> list[bytes]:
        loop = asyncio.get_running_loop()
        a, b = socket.socketpair()
        a.setblocking(False)
        got: list[bytes] = []
        done = loop.create_future()

        def readable() -> None:
            got.append(a.recv(16))
            if len(got) == 3 and not done.done():
                done.set_result(None)

        def tick() -> None:  # keeps the loop in waits of about 1 ms
            if not done.done():
                loop.call_later(0.001, tick)

        loop.add_reader(a.fileno(), readable)
        tick()
        for n in range(3):
            await asyncio.sleep(0.0015)
            threading.Thread(target=b.send, args=(bytes([n]),)).start()
            await asyncio.sleep(0.0015)
        await asyncio.wait_for(done, 2.0)
        assert loop.remove_reader(a.fileno())
        a.close()
        b.close()
        return got

    assert run(main()) == [b"\x00", b"\x01", b"\x02"]


def test_supervision_keeps_working_when_real_time_timers_only_move_later():
    """In real time a deadline that moves later (each heartbeat) keeps the armed timer, which
    re-arms when it fires: no false loss while heartbeats come, a loss once they stop."""
    with Network(interface="virtual", channel="rt-lazy") as net:
        raw = can.Bus(interface="virtual", channel="rt-lazy")
        node = net.add_remote(9)
        node.nmt.watch_heartbeat(0.15)
        beat = can.Message(arbitration_id=0x709, data=b"\x05", is_extended_id=False)
        for _ in range(25):  # 0.5 s of heartbeats, 20 ms apart
            raw.send(beat)
            time.sleep(0.02)
            assert not node.nmt.lost
        deadline = time.monotonic() + 3
        while not node.nmt.lost:
            assert time.monotonic() < deadline, "the loss was never reported"
            time.sleep(0.01)
        raw.send(beat)  # heard again
        deadline = time.monotonic() + 3
        while node.nmt.lost:
            assert time.monotonic() < deadline
            time.sleep(0.01)
        raw.shutdown()


def _armed(host: MachineHost) -> float | None:
    return host._armed  # (a call, read afresh: mypy would narrow the attribute)


def test_a_finished_transfer_leaves_its_timeout_armed_so_the_next_does_not_wake_the_loop():
    """In real time a transfer that ends keeps its machine's armed timer: the next transfer's
    later timeout needs no wake-up of the sleeping loop. The stale timer fires and does
    nothing; a real timeout still comes on time."""
    with Network(interface="virtual", channel="rt-lazy-sdo") as client:
        server = Network(interface="virtual", channel="rt-lazy-sdo")
        add_device(server, 5, _device_od())
        sdo = client.add_remote(5, sdo_timeout=0.5).sdo
        host = sdo.aio.transport._host
        assert sdo.upload(0x1000)
        assert host.machine.deadline is None and _armed(host) is not None  # kept
        loop = client.aio.loop
        assert isinstance(loop, RealTimeLoop)
        wake = loop._write_to_self  # type: ignore[attr-defined]
        wakes = 0

        def counted() -> None:
            nonlocal wakes
            wakes += 1
            wake()

        loop._write_to_self = counted  # type: ignore[attr-defined]
        for _ in range(20):
            assert sdo.upload(0x1000)
        assert wakes <= 3  # (was one per trip; a reader that misses the lock wakes it too)
        time.sleep(0.8)  # the kept timers fire: nothing happens
        assert _armed(host) is None and host._handle is None
        assert sdo.upload(0x1000)
        server.close()
        start = time.monotonic()
        with pytest.raises(SdoTimeoutError):
            sdo.upload(0x1000)
        assert time.monotonic() - start > 0.45  # (the timeout's own timer ended it)


def test_ctrl_c_while_a_blocking_call_waits_cancels_it_on_the_loop():
    with Network(interface="virtual", channel="rt-ctrl-c-run") as net:
        node = net.add_remote(9)
        tasks_before = net._runner.call(lambda: len(asyncio.all_tasks(net.aio.loop)))
        timer = threading.Timer(0.1, os.kill, (os.getpid(), signal.SIGINT))
        timer.start()
        with pytest.raises(KeyboardInterrupt):
            node.nmt.wait_for_bootup(timeout=30)
        timer.join()
        deadline = time.monotonic() + 2
        while net._runner.call(lambda: len(asyncio.all_tasks(net.aio.loop))) > tasks_before:
            assert time.monotonic() < deadline, "the wait still runs on the loop"
            time.sleep(0.01)


def test_a_refused_selector_change_leaves_both_selectors_in_step():
    """A descriptor closed while watched: the refused modify unregisters it from the
    select() copy too, so that its number can be watched again once reused."""
    import socket

    loop = RealTimeLoop()
    try:
        a, b = socket.socketpair()
        fd = a.fileno()
        loop.add_reader(fd, lambda: None)
        a.detach()
        os.close(fd)
        with pytest.raises(OSError):
            loop.add_writer(fd, lambda: None)  # a modify of the closed descriptor
        c, d = socket.socketpair()  # may reuse the number
        loop.add_reader(c.fileno(), lambda: None)
        assert loop.remove_reader(c.fileno())
        for s in (b, c, d):
            s.close()
    finally:
        loop.close()
