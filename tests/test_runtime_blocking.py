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
