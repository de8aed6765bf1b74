import pytest

from cobus.proto import NOTHING, Frame, Machine
from cobus.proto.guarding import (
    BootupReceived,
    GuardingConfigError,
    GuardingMaster,
    GuardingNodeLost,
    GuardingResponder,
    GuardingResumed,
    GuardingStateChanged,
    GuardingTimeout,
    GuardingToggleError,
    LifeGuardingExpired,
    LifeGuardingResumed,
    MalformedGuardingReply,
)
from cobus.proto.nmt import NmtState
from tests.golden import case

PRE, OP, STOP, INIT = (
    NmtState.PRE_OPERATIONAL,
    NmtState.OPERATIONAL,
    NmtState.STOPPED,
    NmtState.INITIALISING,
)
RTR_27 = Frame.parse("71B [0] RTR")


def deadline(machine: Machine) -> float | None:
    return machine.deadline


def reply(node: int, byte: int) -> Frame:
    return Frame(0x700 + node, bytes((byte,)))


# --- responder against the golden vectors ------------------------------------------------------


@pytest.mark.parametrize(
    ("title", "state"),
    [
        ("node guarding of node 27 in operational", OP),
        ("node guarding of node 27 in pre-operational", PRE),
    ],
)
def test_responder_answers_the_beckhoff_sequences(title, state):
    c = case("beckhoff-cia301", title)
    node = int(c.settings["node"])
    r = GuardingResponder(node, lambda: state)
    now = 0.0
    pending: list[Frame] = []
    for step in c.steps:
        if step.direction == ">":
            assert not pending
            pending = list(r.on_frame(step.frame, now).frames)
            now += 0.25
        else:
            assert pending.pop(0) == step.frame
    assert not pending


def test_master_produces_and_accepts_the_beckhoff_sequence():
    c = case("beckhoff-cia301", "node guarding of node 27 in operational")
    m = GuardingMaster(27, 250, 3)
    first = m.start(0.0)
    sent = [first.frames[0]]
    events = []
    for step in c.steps:
        if step.direction == "<":
            events += m.on_frame(step.frame, 0.125).events
            tick = deadline(m)
            assert tick is not None
            out = m.on_timer(tick)
            sent += out.frames
            events += out.events
    expected_requests = [s.frame for s in c.steps if s.direction == ">"]
    assert sent[: len(expected_requests)] == expected_requests
    assert events == [GuardingStateChanged(27, None, OP)]
    assert m.state is OP


# --- responder ----------------------------------------------------------------------------------


def test_responder_toggle_follows_replies_and_resets():
    state = [STOP]
    r = GuardingResponder(1, lambda: state[0])
    assert r.on_frame(Frame(0x701, rtr=True), 0.0).frames == (reply(1, 0x04),)
    state[0] = OP
    assert r.on_frame(Frame(0x701, rtr=True, dlc=1), 0.1).frames == (reply(1, 0x85),)
    assert r.toggle == 0
    r.on_frame(Frame(0x701, rtr=True), 0.2)
    assert r.toggle == 1
    r.reset()
    assert r.toggle == 0
    assert r.on_frame(Frame(0x701, rtr=True), 0.3).frames == (reply(1, 0x05),)


def test_responder_ignores_what_is_not_its_request():
    r = GuardingResponder(1, lambda: OP)
    assert r.on_frame(Frame(0x701, b"\x05"), 0.0) is NOTHING
    assert r.on_frame(Frame(0x702, rtr=True), 0.0) is NOTHING
    assert r.on_frame(Frame(0x701, rtr=True, extended=True), 0.0) is NOTHING
    assert r.toggle == 0


def test_responder_stays_silent_while_initialising():
    r = GuardingResponder(1, lambda: INIT)
    assert r.on_frame(Frame(0x701, rtr=True), 0.0) is NOTHING
    assert r.toggle == 0


def test_responder_refuses_a_bad_state_source():
    r = GuardingResponder(1, lambda: 0x33)  # type: ignore[arg-type,return-value]
    with pytest.raises(GuardingConfigError, match="not an NmtState"):
        r.on_frame(Frame(0x701, rtr=True), 0.0)


def test_life_guarding_arms_on_first_request_expires_once_and_resumes():
    r = GuardingResponder(27, lambda: OP)
    r.set_guard_time(250, 0.0)
    r.set_life_time_factor(2, 0.0)
    assert r.life_time == 0.5
    assert deadline(r) is None  # armed only by the first request
    r.on_frame(RTR_27, 1.0)
    assert deadline(r) == 1.5
    r.on_frame(RTR_27, 1.25)
    assert r.on_timer(1.5) is NOTHING and deadline(r) == 1.75
    assert r.on_timer(1.75).events == (LifeGuardingExpired(27),)
    assert deadline(r) is None and r.on_timer(5.0) is NOTHING
    out = r.on_frame(RTR_27, 6.0)
    assert out.frames == (reply(27, 0x05),)  # third reply: toggle 0 again
    assert out.events == (LifeGuardingResumed(27),)
    assert r.on_frame(RTR_27, 6.25).events == ()


def test_life_guarding_off_with_zero_and_reconfigured_while_running():
    r = GuardingResponder(27, lambda: OP)
    r.set_guard_time(100, 0.0)
    r.on_frame(RTR_27, 0.0)
    assert deadline(r) is None  # factor 0: life guarding off
    r.set_life_time_factor(3, 0.5)
    assert deadline(r) is None  # still waits for a request
    r.on_frame(RTR_27, 1.0)
    assert deadline(r) == pytest.approx(1.3)
    r.set_guard_time(200, 1.1)  # running: restarts with the new life time
    assert deadline(r) == pytest.approx(1.7)
    r.on_timer(1.7)
    r.set_guard_time(0, 2.0)  # off: no more expiry, no pending loss
    assert deadline(r) is None
    r.set_guard_time(100, 2.0)
    assert r.on_frame(RTR_27, 2.5).events == ()
    r.on_timer(3.0)
    r.reset()
    assert deadline(r) is None and r.on_frame(RTR_27, 4.0).events == ()


def test_responder_validation():
    r = GuardingResponder(1, lambda: OP)
    with pytest.raises(GuardingConfigError, match="100Ch"):
        r.set_guard_time(70000, 0.0)
    with pytest.raises(GuardingConfigError, match="100Dh"):
        r.set_life_time_factor(256, 0.0)
    with pytest.raises(GuardingConfigError, match=r"1\.\.127"):
        GuardingResponder(128, lambda: OP)


# --- master -------------------------------------------------------------------------------------


def test_master_polls_every_guard_time_and_reports_timeouts():
    m = GuardingMaster(5, 250, 3)
    assert (m.running, deadline(m), m.on_timer(1.0)) == (False, None, NOTHING)
    assert m.start(0.0).frames == (Frame(0x705, rtr=True),)
    assert (m.running, deadline(m)) == (True, 0.25)
    assert m.on_frame(reply(5, 0x7F), 0.01).events == (GuardingStateChanged(5, None, PRE),)
    out = m.on_timer(0.25)
    assert out.frames == (Frame(0x705, rtr=True),) and out.events == ()
    out = m.on_timer(0.5)  # no reply to the second request
    assert out.frames == (Frame(0x705, rtr=True),)
    assert out.events == (GuardingTimeout(5),)
    assert m.on_frame(reply(5, 0xFF), 0.51) is NOTHING  # valid: toggle 1 then
    assert m.on_timer(0.6) is NOTHING  # nothing due


def test_master_declares_the_node_lost_after_the_life_time_once():
    m = GuardingMaster(5, 250, 2)
    m.start(0.0)
    m.on_frame(reply(5, 0x05), 0.125)
    # life time 0.5 s from the last valid reply: lost at 0.625
    m.on_timer(0.25)
    out = m.on_timer(0.5)
    assert out.events == (GuardingTimeout(5),)
    assert deadline(m) == 0.625
    out = m.on_timer(0.625)
    assert out.events == (GuardingNodeLost(5),) and out.frames == ()
    assert m.lost and deadline(m) == 0.75
    out = m.on_timer(0.75)  # still polling, but no repeated timeout/lost reports
    assert out.frames == (Frame(0x705, rtr=True),) and out.events == ()
    out = m.on_frame(reply(5, 0x85), 0.8)
    assert out.events == (GuardingResumed(5, OP),)
    assert not m.lost


def test_master_resume_with_a_new_state():
    m = GuardingMaster(5, 250, 1)
    m.start(0.0)
    m.on_frame(reply(5, 0x05), 0.1)
    m.on_timer(0.25)
    m.on_timer(0.35)
    assert m.lost
    out = m.on_frame(reply(5, 0xFF), 0.4)
    assert out.events == (GuardingStateChanged(5, OP, PRE), GuardingResumed(5, PRE))


def test_master_timeout_and_loss_due_together():
    m = GuardingMaster(5, 250, 1)
    m.start(0.0)
    out = m.on_timer(0.25)
    assert out.events == (GuardingTimeout(5), GuardingNodeLost(5))
    assert out.frames == (Frame(0x705, rtr=True),)


def test_master_toggle_error_discards_the_reply_and_resyncs():
    m = GuardingMaster(5, 250, 3)
    m.start(0.0)
    out = m.on_frame(reply(5, 0x85), 0.1)  # first reply must have toggle 0
    assert out.events == (GuardingToggleError(5, expected=0, received=1),)
    assert m.state is None
    assert m.on_frame(reply(5, 0x05), 0.2).events == (GuardingStateChanged(5, None, OP),)
    out = m.on_frame(reply(5, 0x05), 0.3)  # duplicate reply: same toggle again
    assert out.events == (GuardingToggleError(5, expected=1, received=0),)


def test_master_state_changes_and_bootup():
    m = GuardingMaster(5, 250, 3)
    m.start(0.0)
    m.on_frame(reply(5, 0x05), 0.1)
    assert m.on_frame(reply(5, 0x84), 0.2).events == (GuardingStateChanged(5, OP, STOP),)
    out = m.on_frame(reply(5, 0x00), 0.3)
    assert out.events == (GuardingStateChanged(5, STOP, INIT), BootupReceived(5))
    assert m.on_frame(reply(5, 0x00), 0.31).events == (BootupReceived(5),)
    # after a boot-up the node's toggle starts at 0 again
    assert m.on_frame(reply(5, 0x7F), 0.4).events == (GuardingStateChanged(5, INIT, PRE),)


def test_master_reports_malformed_replies():
    m = GuardingMaster(5, 250, 3)
    m.start(0.0)
    (event,) = m.on_frame(Frame(0x705, b"\x05\x00"), 0.1).events
    assert isinstance(event, MalformedGuardingReply) and "exactly 1" in event.reason
    (event,) = m.on_frame(reply(5, 0x33), 0.1).events
    assert isinstance(event, MalformedGuardingReply) and "0x33" in event.reason
    (event,) = m.on_frame(reply(5, 0x80), 0.1).events
    assert isinstance(event, MalformedGuardingReply) and "0x00" in event.reason
    assert m.on_frame(Frame(0x705, rtr=True), 0.1) is NOTHING
    assert m.on_frame(reply(6, 0x05), 0.1) is NOTHING
    assert m.on_frame(Frame(0x705, b"\x05", extended=True), 0.1) is NOTHING
    assert m.state is None


def test_master_stop_and_restart():
    m = GuardingMaster(5, 250, 3)
    m.start(0.0)
    m.on_frame(reply(5, 0x05), 0.1)
    m.stop()
    assert deadline(m) is None and m.on_timer(10.0) is NOTHING
    # replies still tracked while stopped, but no life time runs
    assert m.on_frame(reply(5, 0x84), 10.1).events == (GuardingStateChanged(5, OP, STOP),)
    m.start(20.0)
    assert deadline(m) == 20.25
    assert m.on_frame(reply(5, 0x04), 20.1) is NOTHING  # toggle restarts at 0


def test_master_skips_missed_polls_after_a_stall():
    m = GuardingMaster(5, 250, 100)
    m.start(0.0)
    m.on_timer(10.0)
    assert deadline(m) == 10.25


def test_master_validation():
    with pytest.raises(GuardingConfigError, match=r"1\.\.65535 ms"):
        GuardingMaster(5, 0, 3)
    with pytest.raises(GuardingConfigError, match=r"1\.\.255"):
        GuardingMaster(5, 100, 0)
    with pytest.raises(GuardingConfigError, match=r"1\.\.127"):
        GuardingMaster(0, 100, 3)
