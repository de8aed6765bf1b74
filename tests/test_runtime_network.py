import asyncio
from dataclasses import dataclass

import can
import pytest

from cobus.proto import NOTHING, Event, Frame, Out
from cobus.runtime.bus import BusOpenError, decode_error_frame, open_bus
from cobus.runtime.events import (
    BusErrorFrame,
    BusState,
    BusStateChanged,
    HandlerFailed,
    RxOverflow,
    TxQueueFull,
    TxResumed,
)
from cobus.runtime.network import AsyncNetwork, NetworkClosedError, TxOverflowError
from tests.util import simulate


def test_local_echo_delivers_own_frames_to_own_handlers():
    async def main():
        async with AsyncNetwork() as net:
            got = []
            net.subscribe(0x181, lambda f, now: got.append((f, now)))
            net.send(Frame(0x181, b"\x01\x02"))
            net.send(Frame(0x182, b"\x03"))
            await net.sleep(0.01)
            return got, net.frames_sent

    got, sent = simulate(main())
    assert got == [(Frame(0x181, b"\x01\x02"), 0.0)]
    assert sent == 2


def test_a_frame_nobody_here_listens_to_is_not_echoed_and_the_order_holds():
    async def main():
        async with AsyncNetwork() as net:
            got = []
            net.subscribe(0x181, lambda f, now: got.append(f.data))
            net.send(Frame(0x181, b"\x01"))
            net.send(Frame(0x700, b"\x05"))  # no handler, no monitor: no echo scheduled
            net.send(Frame(0x181, b"\x02"))
            assert list(net._inbound) == [Frame(0x181, b"\x01"), Frame(0x181, b"\x02")]
            await net.sleep(0.01)
            alone = []
            async with AsyncNetwork() as quiet:
                quiet.send(Frame(0x700, b"\x05"))
                alone.append((len(quiet._inbound), quiet._drain_pending))
                seen = []
                quiet.subscribe_all(lambda f, now: seen.append(f.cob_id))
                quiet.send(Frame(0x700, b"\x05"))  # a monitor hears everything: echoed
                await quiet.sleep(0.01)
            return got, alone, seen

    got, alone, seen = simulate(main())
    assert got == [b"\x01", b"\x02"]
    assert alone == [(0, False)]
    assert seen == [0x700]


def test_two_networks_on_one_virtual_channel_in_simulated_time():
    async def main():
        a = await AsyncNetwork(interface="virtual", channel="t-two").connect()
        b = await AsyncNetwork(interface="virtual", channel="t-two").connect()
        got_a, got_b = [], []
        a.subscribe(0x585, lambda f, now: got_a.append(f))
        b.subscribe(0x605, lambda f, now: (got_b.append(f), b.send(Frame(0x585, b"\x60"))))
        await asyncio.sleep(1.0)
        a.send(Frame(0x605, b"\x40"))
        await asyncio.sleep(0.001)
        await a.disconnect()
        await b.disconnect()
        return got_a, got_b, a.frames_received, b.frames_received

    got_a, got_b, rx_a, rx_b = simulate(main())
    assert got_b == [Frame(0x605, b"\x40")]
    assert got_a == [Frame(0x585, b"\x60")]
    assert (rx_a, rx_b) == (1, 1)


def test_real_time_network_with_reader_thread():
    async def main():
        a = await AsyncNetwork(interface="virtual", channel="t-real").connect()
        b = await AsyncNetwork(interface="virtual", channel="t-real").connect()
        got = asyncio.get_running_loop().create_future()
        b.subscribe(0x77, lambda f, now: got.done() or got.set_result(f))
        a.send(Frame(0x77, b"\xaa", extended=False))
        frame = await asyncio.wait_for(got, 2.0)
        await a.disconnect()
        await b.disconnect()
        return frame

    assert asyncio.run(main()) == Frame(0x77, b"\xaa")


def test_extended_and_standard_identifiers_are_dispatched_apart():
    async def main():
        async with AsyncNetwork() as net:
            std, ext = [], []
            net.subscribe(0x100, lambda f, now: std.append(f))
            net.subscribe(0x100, lambda f, now: ext.append(f), extended=True)
            net.send(Frame(0x100, b"\x01", extended=True))
            net.send(Frame(0x100, b"\x02"))
            await net.sleep(0)
            await net.sleep(0)
            return std, ext

    std, ext = simulate(main())
    assert [f.data for f in std] == [b"\x02"]
    assert [f.data for f in ext] == [b"\x01"]


def test_a_failing_handler_is_reported_and_the_network_goes_on():
    async def main():
        async with AsyncNetwork() as net:
            events, got = [], []
            net.add_listener(events.append)

            def bad(frame, now):
                raise ZeroDivisionError("boom")

            net.subscribe(0x10, bad)
            net.subscribe(0x10, lambda f, now: got.append(f))
            net.send(Frame(0x10))
            await net.sleep(0.01)
            return events, got

    events, got = simulate(main())
    assert got == [Frame(0x10)]
    assert any(isinstance(e, HandlerFailed) and "boom" in e.error for e in events)


def test_subscription_cancel_and_monitor():
    async def main():
        async with AsyncNetwork() as net:
            seen, all_frames = [], []
            sub = net.subscribe(0x20, lambda f, now: seen.append(f))
            mon = net.subscribe_all(lambda f, now: all_frames.append(f))
            net.send(Frame(0x20))
            await net.sleep(0.01)
            sub.cancel()
            net.send(Frame(0x20))
            await net.sleep(0.01)
            mon.cancel()
            net.send(Frame(0x21))
            await net.sleep(0.01)
            return seen, all_frames

    seen, all_frames = simulate(main())
    assert len(seen) == 1
    assert len(all_frames) == 2


class RefusingBus(can.BusABC):
    """A python-can bus whose controller can be switched to refuse frames (bus-off)."""

    def __init__(self, channel="refusing", **kwargs):
        self.refuse = False
        self.sent: list[can.Message] = []
        self.rx: list[can.Message] = []
        super().__init__(channel=channel, **kwargs)

    def send(self, msg, timeout=None):
        if self.refuse:
            raise can.CanOperationError("Transmit buffer full")
        self.sent.append(msg)

    def _recv_internal(self, timeout):
        if self.rx:
            return self.rx.pop(0), False
        return None, False


def test_refused_frames_wait_in_the_backlog_and_nothing_is_lost():
    bus = RefusingBus()

    async def main():
        async with AsyncNetwork(bus) as net:
            events = []
            net.add_listener(events.append)
            bus.refuse = True
            for i in range(5):
                net.send(Frame(0x200, bytes([i])))
            await net.sleep(0.05)
            assert net.tx_backlog == 5
            bus.refuse = False
            await net.sleep(0.01)
            return events, net.tx_backlog

    events, backlog = simulate(main())
    assert [m.data[0] for m in bus.sent] == [0, 1, 2, 3, 4]
    assert backlog == 0
    kinds = [type(e) for e in events]
    assert kinds.count(TxQueueFull) == 1 and kinds.count(TxResumed) == 1
    assert kinds.index(TxQueueFull) < kinds.index(TxResumed)


def test_backlog_overflow_raises_instead_of_dropping():
    bus = RefusingBus()

    async def main():
        async with AsyncNetwork(bus, tx_backlog=3) as net:
            bus.refuse = True
            for i in range(3):
                net.send(Frame(0x200, bytes([i])))
            with pytest.raises(TxOverflowError, match="backlog full"):
                net.send(Frame(0x200, b"\x09"))

    simulate(main())


def error_frame(ident, data=b"\x00" * 8):
    return can.Message(arbitration_id=ident, data=data, is_error_frame=True, is_extended_id=True)


def test_error_frames_become_bus_state_events():
    bus = RefusingBus()

    async def main():
        async with AsyncNetwork(bus) as net:
            events = []
            net.add_listener(events.append)
            bus.rx.append(error_frame(0x004, bytes([0, 0x20, 0, 0, 0, 0, 0, 0])))
            await net.sleep(0.01)
            bus.rx.append(error_frame(0x040))
            await net.sleep(0.01)
            bus.rx.append(error_frame(0x100))
            await net.sleep(0.01)
            return events, net.bus_state

    events, state = simulate(main())
    changes = [(e.old, e.new) for e in events if isinstance(e, BusStateChanged)]
    assert changes == [
        (BusState.ACTIVE, BusState.PASSIVE),
        (BusState.PASSIVE, BusState.BUS_OFF),
        (BusState.BUS_OFF, BusState.ACTIVE),
    ]
    assert state is BusState.ACTIVE
    assert sum(isinstance(e, BusErrorFrame) for e in events) == 3


def test_decode_error_frame_overflow_and_counters():
    events, state, tx, rx = decode_error_frame(
        error_frame(0x204, bytes([0, 0x01 | 0x08, 0, 0, 0, 0, 97, 12]))
    )
    assert state is BusState.WARNING
    assert (tx, rx) == (97, 12)
    assert any(isinstance(e, RxOverflow) for e in events)
    first = events[0]
    assert isinstance(first, BusErrorFrame) and first.classes == ("controller",)


@dataclass(frozen=True, slots=True)
class Tick(Event):
    at: float


class Ticker:
    """A minimal machine: sends a frame every period, counts frames it receives."""

    def __init__(self, period: float) -> None:
        self.period = period
        self.next: float | None = period
        self.received = 0

    @property
    def deadline(self) -> float | None:
        return self.next

    def on_frame(self, frame: Frame, now: float) -> Out:
        self.received += 1
        if frame.data == b"stop":
            self.next = None
        return NOTHING

    def on_timer(self, now: float) -> Out:
        assert self.next is not None and now >= self.next
        self.next = now + self.period
        return Out((Frame(0x80),), (Tick(now),))


def test_machine_host_arms_timers_on_the_virtual_clock():
    async def main():
        async with AsyncNetwork() as net:
            ticks = []
            machine = Ticker(0.5)
            host = net.attach(machine, [0x99], on_event=ticks.append)
            host.apply(NOTHING)  # arm the first timer
            await net.sleep(2.2)
            net.send(Frame(0x99, b"stop"))
            await net.sleep(5)
            host.close()
            return ticks, machine.received

    ticks, received = simulate(main())
    assert [t.at for t in ticks] == pytest.approx([0.5, 1.0, 1.5, 2.0])
    assert received == 1


def test_using_a_closed_network_is_a_clear_error():
    net = AsyncNetwork()
    with pytest.raises(NetworkClosedError, match="not connected"):
        net.send(Frame(1))
    with pytest.raises(NetworkClosedError):
        net.time()


def test_a_bus_that_fails_to_shut_down_is_reported_and_the_network_closes(monkeypatch):
    """A driver raising from ``shutdown`` (a SocketCAN task the kernel will not delete, a
    USB adapter unplugged) does not escape ``disconnect``: it is reported, the bus is let go
    and the network connects again on a new one."""

    from can.interfaces.virtual import VirtualBus

    class FailingShutdown(VirtualBus):
        def shutdown(self) -> None:
            super().shutdown()
            raise can.CanOperationError("the adapter is gone")

    opened: list[can.BusABC] = []

    def open_failing(**kwargs: object) -> can.BusABC:
        opened.append(FailingShutdown(channel="failing-shutdown"))
        return opened[-1]

    monkeypatch.setattr("cobus.runtime.network._bus.open_bus", open_failing)

    async def main() -> None:
        net = AsyncNetwork(interface="virtual", channel="failing-shutdown")
        await net.connect()
        failures: list[HandlerFailed] = []
        net.add_listener(lambda e: failures.append(e) if isinstance(e, HandlerFailed) else None)
        await net.disconnect()
        assert [f.where for f in failures] == ["shutting the bus down"]
        assert "the adapter is gone" in failures[0].error
        await net.connect()  # a new bus, not the one shut down
        assert net.bus is opened[1]
        await net.disconnect()

    simulate(main())


def test_open_bus_without_interface_says_what_to_do(monkeypatch):
    monkeypatch.delenv("CAN_INTERFACE", raising=False)
    monkeypatch.setenv("HOME", "/nonexistent")
    monkeypatch.chdir("/")
    with pytest.raises(BusOpenError, match="interface"):
        open_bus(channel="x")


def test_interface_and_channel_come_from_the_environment(monkeypatch):
    monkeypatch.setenv("CAN_INTERFACE", "virtual")
    monkeypatch.setenv("CAN_CHANNEL", "from-env")
    monkeypatch.setenv("CAN_BITRATE", "250000")

    async def main():
        peer = can.Bus(interface="virtual", channel="from-env")
        async with AsyncNetwork() as net:
            assert net.bus.channel_info.startswith("Virtual bus channel from-env")
            got = asyncio.get_running_loop().create_future()
            net.subscribe(0x123, lambda f, now: got.done() or got.set_result(f))
            peer.send(can.Message(arbitration_id=0x123, data=b"\x01", is_extended_id=False))
            frame = await asyncio.wait_for(got, 2.0)
        peer.shutdown()
        return frame

    assert asyncio.run(main()) == Frame(0x123, b"\x01")


def test_machine_timers_stop_with_the_network():
    errors = []

    async def main():
        asyncio.get_running_loop().set_exception_handler(lambda loop, ctx: errors.append(ctx))
        net = await AsyncNetwork().connect()
        machine = Ticker(0.5)
        host = net.attach(machine)
        host.apply(NOTHING)
        await net.sleep(0.6)
        await net.disconnect()
        await asyncio.sleep(5)  # no timer may fire on the closed network
        return machine.next

    assert simulate(main()) == pytest.approx(1.0)
    assert errors == []


def test_error_frames_of_others_on_a_virtual_bus_do_not_flip_our_state():
    """python-can's virtual bus is a hub: an error frame there was sent by another
    participant. It is seen (BusErrorFrame) but our controller stays error-active; on an
    interface that reports its own controller (RefusingBus here) the same frame counts."""
    import os
    import time

    from cobus.runtime import Network
    from cobus.runtime.bus import error_frames_are_local

    channel = f"errors-{os.getpid()}"
    passive = error_frame(0x004, bytes([0, 0x20, 0, 0, 0, 0, 0, 0]))
    with Network(interface="virtual", channel=channel) as net:
        events: list[object] = []
        net.add_listener(events.append)
        other = can.Bus(interface="virtual", channel=channel)
        try:
            for _ in range(50):
                other.send(passive)
                other.send(error_frame(0x040))  # bus-off, of the other participant
            deadline = time.monotonic() + 5
            while sum(isinstance(e, BusErrorFrame) for e in events) < 100:
                assert time.monotonic() < deadline
                net.sleep(0.01)
        finally:
            other.shutdown()
        assert net.bus_state is BusState.ACTIVE
        assert not [e for e in events if isinstance(e, BusStateChanged)]
    hub = can.Bus(interface="virtual", channel=channel)
    try:
        assert not error_frames_are_local(hub)
    finally:
        hub.shutdown()
    assert error_frames_are_local(RefusingBus())


def test_others_error_frames_on_the_simulated_clock_and_through_a_faulty_bus():
    """The same on the simulated clock, and through cobus.sim.FaultyBus wrapping a virtual
    bus (its own bus-off still counts); python-can's ThreadSafeBus is seen through."""
    import os

    from cobus.runtime.bus import error_frames_are_local
    from cobus.sim import FaultyBus

    channel = f"errors-sim-{os.getpid()}"
    other = can.Bus(interface="virtual", channel=channel)

    async def main():
        states = []
        for bus in (
            can.Bus(interface="virtual", channel=channel),
            FaultyBus(can.Bus(interface="virtual", channel=channel)),
        ):
            async with AsyncNetwork(bus) as net:
                other.send(error_frame(0x040))
                await net.sleep(0.05)
                states.append(net.bus_state)
                if isinstance(bus, FaultyBus):
                    bus.bus_off()  # the wrapper's own controller: this one counts
                    await net.sleep(0.05)
                    states.append(net.bus_state)
            bus.shutdown()
        return states

    try:
        assert simulate(main()) == [BusState.ACTIVE, BusState.ACTIVE, BusState.BUS_OFF]
        safe = can.ThreadSafeBus(interface="virtual", channel=channel)
        try:
            assert not error_frames_are_local(safe)
        finally:
            safe.shutdown()
    finally:
        other.shutdown()


def test_a_frame_becomes_the_message_python_cans_constructor_makes():
    from cobus.runtime import bus

    frames = [
        Frame(0x585, bytes(range(8))),
        Frame(0x1FFFFFFF, b"\x01", extended=True),
        Frame(0x705, rtr=True, dlc=1),
        Frame(0x80),
    ]
    made = [bus.frame_to_message]
    if set(can.Message.__slots__) - {"__weakref__"} == bus._MESSAGE_FIELDS:
        made.append(bus._message_by_fields)  # this python-can: the direct way, checked too
    for make in made:
        for frame in frames:
            fast, slow = make(frame), bus._message_by_init(frame)
            for field in bus._MESSAGE_FIELDS:
                assert getattr(fast, field) == getattr(slow, field), (frame, field)
                assert type(getattr(fast, field)) is type(getattr(slow, field)), (frame, field)
            assert bus.message_to_frame(fast) == frame


def test_a_python_can_message_with_other_fields_is_made_by_its_constructor():
    from cobus.runtime import bus

    later = type("Message", (), {"__slots__": (*sorted(bus._MESSAGE_FIELDS), "new_field")})
    assert bus._message_maker(later) is bus._message_by_init
    if set(can.Message.__slots__) - {"__weakref__"} == bus._MESSAGE_FIELDS:
        assert bus._message_maker(can.Message) is bus._message_by_fields
