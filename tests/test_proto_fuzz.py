"""Random bus traffic must never make a protocol machine raise."""

from hypothesis import given, settings
from hypothesis import strategies as st

from cobus.proto import Event, Frame, Machine, Out
from cobus.proto.emcy import EmcyConsumer, EmcyProducer
from cobus.proto.guarding import GuardingMaster, GuardingResponder
from cobus.proto.heartbeat import HeartbeatConsumer, HeartbeatMonitor, encode_consumer_entry
from cobus.proto.nmt import NmtSlave, NmtState
from cobus.proto.pdo import RpdoWatchdog
from cobus.proto.sync import SyncConsumer
from cobus.proto.timestamp import TimeConsumer


@st.composite
def frames(draw: st.DrawFn) -> Frame:
    extended = draw(st.booleans())
    if extended:
        cob_id = draw(st.integers(0, 0x1FFFFFFF))
    else:
        # favour the identifiers the machines listen to
        cob_id = draw(
            st.one_of(
                st.sampled_from([0x000, 0x080, 0x081, 0x085, 0x100, 0x201, 0x705, 0x71B]),
                st.integers(0, 0x7FF),
            )
        )
    if draw(st.booleans()):
        return Frame(cob_id, rtr=True, extended=extended, dlc=draw(st.integers(0, 8)))
    return Frame(cob_id, draw(st.binary(max_size=8)), extended=extended)


traffic = st.lists(
    st.tuples(frames(), st.floats(0.0, 0.2, allow_nan=False)), min_size=1, max_size=60
)


def machines() -> list[Machine]:
    slave = NmtSlave(27)
    slave.boot(0.0)
    consumer = HeartbeatConsumer(3)
    consumer.set_entry(1, encode_consumer_entry(5, 50), 0.0)
    consumer.set_entry(2, encode_consumer_entry(27, 100), 0.0)
    guard = GuardingMaster(27, 50, 2)
    guard.start(0.0)
    guard5 = GuardingMaster(5, 20, 3)
    guard5.start(0.0)
    responder = GuardingResponder(27, lambda: slave.state)
    responder.set_guard_time(30, 0.0)
    responder.set_life_time_factor(2, 0.0)
    sync = SyncConsumer(overflow=0)
    sync.set_period(10_000, 0.0)
    return [
        slave,
        consumer,
        HeartbeatMonitor(),
        guard,
        guard5,
        responder,
        GuardingResponder(5, lambda: NmtState.STOPPED),
        EmcyConsumer(),
        EmcyProducer(5),
        sync,
        SyncConsumer(),
        TimeConsumer(),
        RpdoWatchdog(0x201, 30, length=4),
    ]


def check(out: Out) -> None:
    assert isinstance(out, Out)
    assert all(isinstance(f, Frame) for f in out.frames)
    assert all(isinstance(ev, Event) for ev in out.events)


def drive(machine: Machine, steps: list[tuple[Frame, float]]) -> None:
    now = 0.0
    for frame, gap in steps:
        now += gap
        due = machine.deadline
        while due is not None and due <= now:
            check(machine.on_timer(due))
            nxt = machine.deadline
            assert nxt is None or nxt > due, f"{machine!r} asks again for {due} after on_timer"
            due = nxt
        check(machine.on_frame(frame, now))


@settings(max_examples=150, deadline=None)
@given(traffic)
def test_no_exception_escapes_on_random_frames(steps):
    for machine in machines():
        drive(machine, steps)


@settings(max_examples=50, deadline=None)
@given(traffic)
def test_nmt_slave_state_stays_valid(steps):
    slave = NmtSlave(27)
    slave.boot(0.0)
    for frame, _ in steps:
        check(slave.on_frame(frame, 1.0))
        if slave.state is NmtState.INITIALISING:
            check(slave.boot(1.0))
        assert slave.state in (NmtState.PRE_OPERATIONAL, NmtState.OPERATIONAL, NmtState.STOPPED)


def test_timers_far_in_the_future_are_harmless():
    for machine in machines():
        check(machine.on_timer(1e9))
