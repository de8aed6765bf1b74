"""The runtime under failure: bus refusing frames, cancelled and orphaned transfers,
reconnects, re-entrant calls. Each test pins a failure found in review."""

import asyncio
import threading
import time

import can
import pytest

from cobus.proto import Frame
from cobus.proto.heartbeat import HeartbeatProducer
from cobus.proto.sdo import DictBackend, SdoServer, SdoTimeoutError
from cobus.runtime import (
    AsyncNetwork,
    BusOpenError,
    HandlerFailed,
    Network,
    NetworkClosedError,
    ReentrantCallError,
    TxBufferOverflow,
)
from cobus.runtime import bus as bus_module
from cobus.runtime.remote import SdoChannel
from tests.test_runtime_network import RefusingBus, error_frame
from tests.util import simulate


def heartbeat_producer(node_id: int, period_ms: int) -> HeartbeatProducer:
    producer = HeartbeatProducer(node_id)
    producer.set_period(period_ms, 0.0)
    return producer


def test_a_producer_keeps_running_after_the_backlog_overflowed():
    bus = RefusingBus()

    async def main():
        async with AsyncNetwork(bus, tx_backlog=2) as net:
            events = []
            net.add_listener(events.append)
            net.attach(heartbeat_producer(5, 100))
            bus.refuse = True
            await net.sleep(1.0)  # ten heartbeats, eight of them beyond the backlog
            bus.refuse = False
            await net.sleep(0.05)
            before = len(bus.sent)
            await net.sleep(1.0)
            return events, len(bus.sent) - before

    events, sent_later = simulate(main())
    assert sent_later == 10  # still one heartbeat every 100 ms
    assert any(isinstance(e, HandlerFailed) and "backlog full" in e.error for e in events)


def test_sdo_channel_is_free_again_after_a_transfer_could_not_be_sent():
    bus = RefusingBus()

    async def main():
        async with AsyncNetwork(bus, tx_backlog=0) as net:
            net.attach(
                SdoServer(0x605, 0x585, DictBackend({(0x1000, 0): b"\x91\x01\0\0"})), [0x605]
            )
            sdo = net.add_remote(5, sdo_timeout=0.5).sdo
            bus.refuse = True
            with pytest.raises(SdoTimeoutError):
                await sdo.upload(0x1000)
            bus.refuse = False
            return await sdo.upload(0x1000)

    assert simulate(main()) == b"\x91\x01\0\0"


def test_a_cancelled_transfer_aborts_and_frees_the_channel():
    async def main():
        async with AsyncNetwork() as net:
            seen = []
            net.subscribe(0x609, lambda f, now: seen.append(f))
            sdo = net.add_remote(9, sdo_timeout=1.0).sdo
            with pytest.raises(TimeoutError):
                await asyncio.wait_for(sdo.upload(0x1000), 0.2)
            with pytest.raises(SdoTimeoutError):  # not SdoBusyError
                await sdo.upload(0x1000)
            return seen

    seen = simulate(main())
    assert seen[1] == Frame(0x609, bytes([0x80, 0x00, 0x10, 0x00, 0x00, 0x00, 0x00, 0x08]))


def test_disconnect_fails_a_pending_transfer():
    async def main():
        net = await AsyncNetwork().connect()
        sdo = net.add_remote(9, sdo_timeout=10.0).sdo
        task = asyncio.ensure_future(sdo.upload(0x1000))
        await net.sleep(0.1)
        await net.disconnect()
        with pytest.raises(NetworkClosedError, match="disconnected during an SDO transfer"):
            await asyncio.wait_for(task, 1.0)

    simulate(main())


def test_closing_a_real_time_network_releases_a_blocked_caller():
    net = Network(interface="virtual", channel="robust-close")
    node = net.add_remote(9, sdo_timeout=30.0)
    errors = []

    def worker():
        try:
            node.sdo.upload(0x1000)
        except Exception as exc:
            errors.append(exc)

    thread = threading.Thread(target=worker)
    thread.start()
    time.sleep(0.2)
    net.close()
    thread.join(5.0)
    assert not thread.is_alive()
    assert errors and not isinstance(errors[0], SdoTimeoutError)
    net.close()  # a second close does nothing


def test_a_failed_connect_can_be_retried(monkeypatch):
    real_open = bus_module.open_bus
    attempts = []

    def flaky_open(**kwargs):
        attempts.append(kwargs)
        if len(attempts) == 1:
            raise BusOpenError("adapter not plugged in")
        return real_open(**kwargs)

    monkeypatch.setattr(bus_module, "open_bus", flaky_open)

    async def main():
        net = AsyncNetwork(interface="virtual", channel="robust-retry")
        with pytest.raises(BusOpenError):
            await net.connect()
        assert not net.connected
        await net.connect()
        assert net.bus is not None
        await net.disconnect()

    simulate(main())
    assert len(attempts) == 2


def test_reconnect_resumes_machines_and_the_backlog():
    bus = RefusingBus()

    async def main():
        net = await AsyncNetwork(bus).connect()
        net.attach(heartbeat_producer(5, 100))
        bus.refuse = True
        await net.sleep(0.25)
        assert net.tx_backlog == 2
        await net.disconnect()
        with pytest.raises(NetworkClosedError):
            net.send(Frame(0x1))  # nothing goes on the wire while disconnected
        bus.refuse = False
        await net.connect()
        await net.sleep(0.5)
        await net.disconnect()
        return len(bus.sent)

    assert simulate(main()) >= 2 + 4  # the backlog, then heartbeats again


def test_sdo_on_29_bit_identifiers():
    async def main():
        async with AsyncNetwork() as net:
            store = DictBackend({(0x1000, 0): b"\x2a\0\0\0"})
            net.attach(SdoServer(0x10000605, 0x10000585, store), [0x10000605], extended=True)
            channel = SdoChannel(net, 5, None, rx_cob_id=0x10000605, tx_cob_id=0x10000585)
            return await channel.upload(0x1000)

    assert simulate(main()) == b"\x2a\0\0\0"


def test_run_timeout_holds_on_the_simulated_clock():
    with Network(simulated=True) as net:
        node = net.add_remote(9, sdo_timeout=30.0)
        with pytest.raises(TimeoutError):
            net.run(node.sdo.aio.upload(0x1000), timeout=1.0)
        assert net.time() == pytest.approx(1.0)


def test_blocking_call_inside_a_simulated_callback_is_a_clear_error():
    with Network(simulated=True) as net:
        events = []
        net.add_listener(events.append)
        net.subscribe(0x10, lambda f, now: net.sleep(1))
        net.send(Frame(0x10))
        net.sleep(0.01)
    failures = [e for e in events if isinstance(e, HandlerFailed)]
    assert failures and "ReentrantCallError" in failures[0].error
    assert issubclass(ReentrantCallError, RuntimeError)


def test_coroutine_listeners_run_in_both_modes():
    for simulated in (True, False):
        ran = threading.Event()

        async def listener(event, ran=ran):
            ran.set()

        kwargs = {"simulated": True} if simulated else {"interface": "virtual", "channel": "co"}
        with Network(**kwargs) as net:
            net.add_listener(listener)
            net.run(_emit(net.aio))
            net.sleep(0.1)
        assert ran.wait(2.0), simulated


async def _emit(aio):
    aio.emit(TxBufferOverflow())


def test_close_from_a_callback_in_real_time():
    done = threading.Event()
    net = Network(interface="virtual", channel="robust-cb-close")

    def handler(frame, now):
        net.close()
        done.set()

    net.subscribe(0x10, handler)
    net.send(Frame(0x10))
    assert done.wait(3.0)
    net.close()


def test_transmit_overflow_is_not_reported_as_receive_overflow():
    bus = RefusingBus()

    async def main():
        async with AsyncNetwork(bus) as net:
            events = []
            net.add_listener(events.append)
            bus.rx.append(error_frame(0x004, bytes([0, 0x02, 0, 0, 0, 0, 0, 0])))
            await net.sleep(0.01)
            return [type(e).__name__ for e in events]

    names = simulate(main())
    assert "TxBufferOverflow" in names and "RxOverflow" not in names


def test_attach_arms_a_deadline_the_machine_already_has():
    async def main():
        async with AsyncNetwork() as net:
            got = []
            net.subscribe(0x705, lambda f, now: got.append(now))
            net.attach(heartbeat_producer(5, 100))  # period set before attaching
            await net.sleep(0.35)
            return got

    assert simulate(main()) == pytest.approx([0.1, 0.2, 0.3])


def test_local_ping_pong_does_not_starve_timers():
    # Real time: on the simulated clock an endless exchange at one instant is a livelock by
    # definition (time moves only when the loop is idle).
    async def main():
        async with AsyncNetwork(interface="virtual", channel="robust-pingpong") as net:
            net.subscribe(0x100, lambda f, now: net.send(Frame(0x100)))  # answers itself forever
            net.send(Frame(0x100))
            await asyncio.wait_for(asyncio.sleep(0.01), 2.0)  # returns despite the ping-pong
            return net.frames_sent

    assert asyncio.run(main()) > 100


def test_interface_without_state_keeps_polling(monkeypatch):
    class Odd(can.BusABC):
        def __init__(self):
            super().__init__(channel="odd")

        @property  # type: ignore[misc]
        def state(self):
            raise KeyError("driver bug")

        def send(self, msg, timeout=None):
            pass

        def _recv_internal(self, timeout):
            return None, False

    assert bus_module.read_state(Odd()) is None
