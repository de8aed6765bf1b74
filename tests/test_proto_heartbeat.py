import pytest

from cobus.proto import NOTHING, Frame, Machine
from cobus.proto.heartbeat import (
    BootupReceived,
    ConsumerEntry,
    HeartbeatConfigError,
    HeartbeatConsumer,
    HeartbeatMonitor,
    HeartbeatProducer,
    HeartbeatResumed,
    HeartbeatTimeout,
    MalformedHeartbeat,
    RemoteStateChanged,
    decode_consumer_entry,
    encode_consumer_entry,
    heartbeat_frame,
)
from cobus.proto.nmt import NmtState

PRE, OP, STOP, INIT = (
    NmtState.PRE_OPERATIONAL,
    NmtState.OPERATIONAL,
    NmtState.STOPPED,
    NmtState.INITIALISING,
)


def deadline(machine: Machine) -> float | None:
    """Read the deadline without letting mypy narrow it for the rest of a test."""
    return machine.deadline


def hb(node: int, state: int) -> Frame:
    return Frame(0x700 + node, bytes((state,)))


# --- helpers ----------------------------------------------------------------------------------


def test_consumer_entry_codec():
    assert encode_consumer_entry(5, 150) == 0x00050096
    assert decode_consumer_entry(0x00050096) == ConsumerEntry(5, 150)
    assert encode_consumer_entry(0, 0) == 0
    with pytest.raises(HeartbeatConfigError, match="reserved bits 24-31"):
        decode_consumer_entry(0x01050096)
    with pytest.raises(HeartbeatConfigError, match="UNSIGNED32"):
        decode_consumer_entry(-1)
    with pytest.raises(HeartbeatConfigError, match=r"1\.\.127"):
        encode_consumer_entry(128, 10)
    with pytest.raises(HeartbeatConfigError, match="65535"):
        encode_consumer_entry(1, 70000)


def test_heartbeat_frame():
    assert heartbeat_frame(27, OP) == Frame.parse("71B [1] 05")
    assert heartbeat_frame(1, 0x7F) == Frame.parse("701 [1] 7F")
    with pytest.raises(HeartbeatConfigError, match="not an NMT state"):
        heartbeat_frame(1, 0x33)


# --- producer ---------------------------------------------------------------------------------


def test_producer_sends_each_period():
    p = HeartbeatProducer(27)
    assert deadline(p) is None and p.on_timer(10.0) is NOTHING
    p.set_period(250, 1.0)
    assert deadline(p) == 1.25
    assert p.on_timer(1.125) is NOTHING
    assert p.on_timer(1.25).frames == (Frame.parse("71B [1] 7F"),)
    assert deadline(p) == 1.5
    p.state = OP
    assert p.on_timer(1.5).frames == (Frame.parse("71B [1] 05"),)
    assert p.on_frame(hb(27, 5), 1.6) is NOTHING


def test_producer_drives_by_its_own_deadline_without_drift():
    p = HeartbeatProducer(27)
    p.set_period(100, 0.0)
    sent = 0
    for _ in range(1000):
        due = deadline(p)
        assert due is not None
        sent += len(p.on_timer(due).frames)
    assert sent == 1000 and deadline(p) == pytest.approx(100.1)


def test_producer_skips_missed_beats_after_a_stall():
    p = HeartbeatProducer(1)
    p.set_period(100, 0.0)
    assert len(p.on_timer(5.0).frames) == 1
    assert deadline(p) == pytest.approx(5.1)


def test_producer_state_from_a_callable_and_stop():
    state = [STOP]
    p = HeartbeatProducer(2, state_getter=lambda: state[0])
    p.set_period(50, 0.0)
    assert p.on_timer(0.05).frames == (Frame.parse("702 [1] 04"),)
    state[0] = OP
    assert p.on_timer(0.1).frames == (Frame.parse("702 [1] 05"),)
    p.set_period(0, 0.12)
    assert deadline(p) is None and p.on_timer(1.0) is NOTHING
    p.restart(2.0)
    assert deadline(p) is None
    p.set_period(10, 3.0)
    p.restart(4.0)
    assert deadline(p) == pytest.approx(4.01)


def test_producer_validation():
    with pytest.raises(HeartbeatConfigError, match="65535"):
        HeartbeatProducer(1).set_period(65536, 0.0)
    with pytest.raises(HeartbeatConfigError, match=r"1\.\.127"):
        HeartbeatProducer(0)
    p = HeartbeatProducer(1, state_getter=lambda: 3)  # type: ignore[arg-type,return-value]
    p.set_period(1, 0.0)
    with pytest.raises(HeartbeatConfigError, match="not an NmtState"):
        p.on_timer(1.0)


# --- consumer (1016h) -------------------------------------------------------------------------


def consumer(*entries: int) -> HeartbeatConsumer:
    c = HeartbeatConsumer(4)
    for sub, value in enumerate(entries, start=1):
        c.set_entry(sub, value, 0.0)
    return c


def test_timer_arms_on_the_first_heartbeat_then_times_out_once():
    c = consumer(encode_consumer_entry(5, 150))
    assert deadline(c) is None  # nothing heard yet: nothing to supervise
    out = c.on_frame(hb(5, 0x7F), 1.0)
    assert out.events == (RemoteStateChanged(5, None, PRE),)
    assert deadline(c) == pytest.approx(1.15)
    assert c.on_frame(hb(5, 0x7F), 1.1) is NOTHING
    assert c.on_timer(1.2) is NOTHING  # early wake-up: the expiry moved to 1.25
    assert deadline(c) == pytest.approx(1.25)
    assert c.on_timer(1.25).events == (HeartbeatTimeout(5),)
    assert c.is_lost(5) and deadline(c) is None
    assert c.on_timer(9.0) is NOTHING  # once per loss


def test_resume_after_timeout_and_state_change():
    c = consumer(encode_consumer_entry(5, 100))
    c.on_frame(hb(5, 0x7F), 0.0)
    c.on_timer(0.1)
    out = c.on_frame(hb(5, 0x05), 0.5)
    assert out.events == (HeartbeatResumed(5, OP), RemoteStateChanged(5, PRE, OP))
    assert not c.is_lost(5) and c.state(5) is OP
    assert deadline(c) == pytest.approx(0.6)
    assert c.on_frame(hb(5, 0x04), 0.55).events == (RemoteStateChanged(5, OP, STOP),)
    # a resume without state change
    c.on_timer(0.65)
    assert c.on_frame(hb(5, 0x04), 0.7).events == (HeartbeatResumed(5, STOP),)


def test_bootup_stops_supervision_until_the_next_heartbeat():
    c = consumer(encode_consumer_entry(5, 100))
    c.on_frame(hb(5, 0x05), 0.0)
    out = c.on_frame(hb(5, 0x00), 0.05)
    assert out.events == (RemoteStateChanged(5, OP, INIT), BootupReceived(5))
    assert c.on_timer(0.1) is NOTHING and deadline(c) is None
    assert c.on_frame(hb(5, 0x00), 0.2).events == (BootupReceived(5),)
    c.on_frame(hb(5, 0x7F), 1.0)
    assert deadline(c) == pytest.approx(1.1)


def test_bootup_ends_a_loss():
    c = consumer(encode_consumer_entry(5, 100))
    c.on_frame(hb(5, 0x05), 0.0)
    c.on_timer(0.1)
    out = c.on_frame(hb(5, 0x00), 0.3)
    assert out.events == (RemoteStateChanged(5, OP, INIT), BootupReceived(5))
    assert not c.is_lost(5)
    assert c.on_frame(hb(5, 0x7F), 0.4).events == (RemoteStateChanged(5, INIT, PRE),)


def test_several_producers_with_their_own_times():
    c = consumer(encode_consumer_entry(1, 100), encode_consumer_entry(2, 300))
    c.on_frame(hb(1, 5), 0.0)
    c.on_frame(hb(2, 5), 0.0)
    assert deadline(c) == pytest.approx(0.1)
    assert c.on_timer(0.1).events == (HeartbeatTimeout(1),)
    assert deadline(c) == pytest.approx(0.3)
    c.on_frame(hb(2, 5), 0.2)
    assert c.on_timer(0.3) is NOTHING
    assert c.on_timer(0.5).events == (HeartbeatTimeout(2),)


def test_heartbeat_of_a_tracked_node_arms_a_later_added_timeout():
    m = HeartbeatMonitor()
    m.on_frame(hb(9, 5), 0.0)
    m.watch(3, 10.0, 0.0)
    m.on_frame(hb(3, 5), 0.0)
    assert deadline(m) == pytest.approx(10.0)
    m.watch(9, 0.1, 0.5)  # 9 was only tracked: supervision starts with its next heartbeat
    assert deadline(m) == pytest.approx(10.0)
    assert m.on_frame(hb(9, 5), 0.6) is NOTHING
    assert deadline(m) == pytest.approx(0.7)
    assert m.on_timer(0.7).events == (HeartbeatTimeout(9),)


def test_shorter_time_for_a_supervised_node_moves_the_deadline_earlier():
    m = HeartbeatMonitor()
    m.watch(3, 10.0, 0.0)
    m.on_frame(hb(3, 5), 0.0)
    m.watch(3, 0.5, 1.0)
    assert deadline(m) == 1.5
    assert m.on_timer(1.5).events == (HeartbeatTimeout(3),)


def test_unconfigured_nodes_and_other_frames_are_ignored():
    c = consumer(encode_consumer_entry(5, 100))
    assert c.on_frame(hb(6, 5), 0.0) is NOTHING
    assert c.on_frame(Frame(0x705, rtr=True), 0.0) is NOTHING
    assert c.on_frame(Frame(0x705, b"\x05", extended=True), 0.0) is NOTHING
    assert c.on_frame(Frame(0x700, b"\x05"), 0.0) is NOTHING
    assert c.on_frame(Frame(0x185, b"\x05"), 0.0) is NOTHING
    assert c.state(6) is None and c.timeout(6) == 0.0


def test_malformed_heartbeats_do_not_count():
    c = consumer(encode_consumer_entry(5, 100))
    (event,) = c.on_frame(Frame(0x705, b"\x05\x00"), 0.0).events
    assert isinstance(event, MalformedHeartbeat) and "exactly 1" in event.reason
    (event,) = c.on_frame(Frame(0x705, b""), 0.0).events
    assert isinstance(event, MalformedHeartbeat) and "0 data bytes" in event.reason
    (event,) = c.on_frame(hb(5, 0x85), 0.0).events
    assert event == MalformedHeartbeat(
        5, b"\x85", "heartbeat state 0x85 is no NMT state (00h, 04h, 05h, 7Fh)"
    )
    assert deadline(c) is None and c.state(5) is None


def test_set_entry_rules():
    c = consumer(encode_consumer_entry(5, 100))
    assert c.size == 4 and c.entry(1) == 0x00050064 and c.entry(2) == 0
    with pytest.raises(HeartbeatConfigError, match="a second time"):
        c.set_entry(2, encode_consumer_entry(5, 200), 0.0)
    c.set_entry(2, encode_consumer_entry(5, 0), 0.0)  # unused entry: allowed
    assert c.timeout(5) == pytest.approx(0.1)  # and sub 1 still watches node 5
    with pytest.raises(HeartbeatConfigError, match=r"sub-indexes 1\.\.4"):
        c.set_entry(5, 0, 0.0)
    with pytest.raises(HeartbeatConfigError, match=r"sub-indexes 1\.\.4"):
        c.entry(0)
    with pytest.raises(HeartbeatConfigError, match=r"outside 1\.\.127"):
        c.set_entry(3, 0x00800010, 0.0)
    with pytest.raises(HeartbeatConfigError, match=r"1\.\.127 entries"):
        HeartbeatConsumer(0)


def test_rewriting_an_entry():
    c = consumer(encode_consumer_entry(5, 100))
    c.on_frame(hb(5, 5), 0.0)
    # a new time for a supervised node re-arms it from now
    c.set_entry(1, encode_consumer_entry(5, 500), 0.05)
    assert deadline(c) == pytest.approx(0.1)  # early wake-up is harmless
    assert c.on_timer(0.1) is NOTHING and deadline(c) == pytest.approx(0.55)
    # moving the entry to another node forgets the first one
    c.set_entry(1, encode_consumer_entry(6, 100), 0.1)
    assert c.on_frame(hb(5, 5), 0.2) is NOTHING and c.timeout(5) == 0.0
    assert c.on_timer(1.0) is NOTHING
    # time 0 turns supervision of that node off
    c.on_frame(hb(6, 5), 1.0)
    c.set_entry(1, encode_consumer_entry(6, 0), 1.01)
    assert c.on_timer(5.0) is NOTHING and c.timeout(6) == 0.0


def test_monitor_watch_rules():
    m = HeartbeatMonitor()
    m.watch(4, 0.2, 0.0)
    m.on_frame(hb(4, 5), 0.0)
    m.watch(4, 0.0, 0.1)  # supervised -> only tracked
    assert m.on_timer(1.0) is NOTHING
    with pytest.raises(HeartbeatConfigError, match=">= 0"):
        m.watch(4, -1.0, 0.0)
    with pytest.raises(HeartbeatConfigError, match=r"1\.\.127"):
        m.watch(0, 1.0, 0.0)
    m.forget(4)
    assert m.state(4) is None and not m.is_lost(4)
    # the monitor tracks every node it hears, watched or not
    assert m.on_frame(hb(100, 0x7F), 2.0).events == (RemoteStateChanged(100, None, PRE),)
    assert m.on_frame(hb(100, 0x7F), 2.1) is NOTHING
    # a watched node that is lost stays lost across a change of its time
    m.watch(100, 0.125, 2.0)
    m.on_frame(hb(100, 0x7F), 2.25)
    assert m.on_timer(2.375).events == (HeartbeatTimeout(100),)
    m.watch(100, 0.5, 2.5)
    assert m.is_lost(100) and deadline(m) is None
