import threading
import time

import pytest

from cobus.proto import Frame
from cobus.runtime import Network


def test_simulated_network_runs_inline_and_time_only_moves_while_waiting():
    with Network(simulated=True) as net:
        got = []
        net.subscribe(0x181, lambda f, now: got.append((f.data, now)))
        assert net.time() == 0.0
        net.send(Frame(0x181, b"\x01"))
        net.sleep(10)
        assert net.time() == pytest.approx(10)
        net.send(Frame(0x181, b"\x02"))
        net.sleep(0.5)
    assert got == [(b"\x01", 0.0), (b"\x02", pytest.approx(10.0))]


def test_real_time_network_runs_callbacks_off_the_loop_thread():
    threads = []
    done = threading.Event()
    with (
        Network(interface="virtual", channel="t-blocking") as a,
        Network(interface="virtual", channel="t-blocking") as b,
    ):

        def handler(frame, now):
            threads.append(threading.current_thread().name)
            time.sleep(0.05)  # a slow callback must not stall the network
            done.set()

        b.subscribe(0x222, handler)
        a.send(Frame(0x222, b"\x05"))
        assert done.wait(2.0)
        assert b.frames_received == 1
    assert threads == ["cobus-callbacks"]


def test_listener_sees_runtime_events_simulated():
    import can

    from cobus.runtime import TxQueueFull

    class Off(can.BusABC):
        def __init__(self):
            super().__init__(channel="off")

        def send(self, msg, timeout=None):
            raise can.CanOperationError("bus-off")

        def _recv_internal(self, timeout):
            return None, False

    with Network(Off(), simulated=True) as net:
        events = []
        net.add_listener(events.append)
        net.send(Frame(0x1))
        net.sleep(0.01)
        assert any(isinstance(e, TxQueueFull) and "bus-off" in e.reason for e in events)


def test_the_blocking_facade_hands_results_errors_and_timeouts_back():
    import asyncio
    import concurrent.futures

    from cobus.runtime import NetworkClosedError, ReentrantCallError

    with Network(interface="virtual", channel="t-handoff") as net:
        runner = net._runner

        async def answer(value):
            await asyncio.sleep(0)
            return value

        async def fails():
            raise ValueError("refused on the loop")

        cancelled = threading.Event()

        async def slow():
            try:
                await asyncio.sleep(10)
            except asyncio.CancelledError:
                cancelled.set()
                raise

        async def gives_up():
            me = asyncio.current_task()
            assert me is not None
            me.cancel()
            await asyncio.sleep(1)

        assert net.run(answer(42)) == 42
        with pytest.raises(ValueError, match="refused on the loop"):
            net.run(fails())
        with pytest.raises(TimeoutError):
            net.run(slow(), timeout=0.05)
        assert cancelled.wait(2.0)  # the caller gave up: the coroutine is cancelled
        finished = []

        async def short():
            await asyncio.sleep(0.1)
            finished.append(True)

        for at_once in (0, -0.5):  # no time to wait: only a result already there counts
            with pytest.raises(TimeoutError):
                net.run(short(), timeout=at_once)
        time.sleep(0.3)
        assert finished == []  # given up at once: cancelled, never ran to its end
        with pytest.raises(TypeError, match="takes a coroutine"):
            net.run(slow)  # type: ignore[arg-type]  # the function, not a call: refused
        with pytest.raises(concurrent.futures.CancelledError):
            net.run(gives_up())
        loop_thread = runner.call(threading.current_thread)
        assert loop_thread.name == "cobus-loop"
        with pytest.raises(ZeroDivisionError):
            runner.call(lambda: 1 / 0)

        def from_the_loop():
            coro = answer(1)
            try:
                runner.run(coro)
            except ReentrantCallError as exc:
                return str(exc)
            return "ran"

        assert "would deadlock" in runner.call(from_the_loop)
        assert net.run(answer("still serving")) == "still serving"
    assert loop_thread.ident is not None and not loop_thread.is_alive()
    assert runner._loop_ident is None  # (a new thread may get the dead one's ident)
    with pytest.raises(NetworkClosedError):
        runner.call(int)
    with pytest.raises(NetworkClosedError):
        net.run(answer(1))
