import pytest

from cobus.proto import NOTHING, Frame
from cobus.proto.nmt import (
    MalformedNmt,
    MalformedNmtError,
    NmtCommand,
    NmtError,
    NmtRequest,
    NmtSlave,
    NmtState,
    NmtStateChanged,
    ResetCommunication,
    ResetNode,
    Service,
    bootup_frame,
    check_node_id,
    nmt_command_frame,
    parse_nmt,
)
from tests.golden import case

PRE, OP, STOP, INIT = (
    NmtState.PRE_OPERATIONAL,
    NmtState.OPERATIONAL,
    NmtState.STOPPED,
    NmtState.INITIALISING,
)


def nmt(cs: int, node: int) -> Frame:
    return Frame(0, bytes((cs, node)))


def booted(node_id: int = 27) -> NmtSlave:
    s = NmtSlave(node_id)
    s.boot(0.0)
    return s


# --- frames --------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("title", "command", "node"),
    [
        ("all nodes to stopped", NmtCommand.STOP, 0),
        ("reset node 17", NmtCommand.RESET_NODE, 17),
        ("start all nodes", NmtCommand.START, 0),
    ],
)
def test_command_frames_of_the_beckhoff_vectors(title, command, node):
    (step,) = case("beckhoff-cia301", title).steps
    assert nmt_command_frame(command, node) == step.frame
    assert parse_nmt(step.frame) == NmtRequest(command, node)


def test_command_frames_of_other_vectors():
    start_8 = case("thesis-zapi", "SYNC 20 ms").steps[1].frame
    assert nmt_command_frame(NmtCommand.START, 8) == start_8
    reset_comm_3 = case("ec-motor", "NMT reset of node 3").steps[0].frame
    assert nmt_command_frame(NmtCommand.RESET_COMMUNICATION, 3) == reset_comm_3
    assert nmt_command_frame(0x80, 127) == Frame(0, b"\x80\x7f")


def test_bootup_frame_of_the_vectors():
    (step,) = case("beckhoff-cia301", "boot-up of node 27").steps
    assert bootup_frame(27) == step.frame == Frame.parse("71B [1] 00")
    assert NmtSlave(27).boot(1.0).frames == (step.frame,)


@pytest.mark.parametrize("node", [-1, 128, 255, True])
def test_command_frame_refuses_bad_node_ids(node):
    with pytest.raises(NmtError, match=r"0 \(all nodes\) or 1\.\.127"):
        nmt_command_frame(NmtCommand.START, node)


def test_command_frame_refuses_unknown_command():
    with pytest.raises(NmtError, match="unknown NMT command 0x03"):
        nmt_command_frame(3, 1)


def test_node_id_checks():
    assert check_node_id(1) == 1 and check_node_id(0, broadcast=True) == 0
    with pytest.raises(NmtError, match=r"use 1\.\.127"):
        check_node_id(0)
    with pytest.raises(NmtError, match=r"use 1\.\.127"):
        bootup_frame(128)
    with pytest.raises(NmtError):
        NmtSlave(0)


@pytest.mark.parametrize(
    ("frame", "reason"),
    [
        (Frame(0, b"\x01"), "1 data bytes; it must carry exactly 2"),
        (Frame(0, b"\x01\x00\x00"), "3 data bytes"),
        (Frame(0, rtr=True), "remote frame"),
        (Frame(0, b"\x03\x00"), "unknown NMT command specifier 0x03"),
        (Frame(0, b"\x01\x80"), "node-ID 128"),
        (Frame(0x701, b"\x01\x00"), "not on the NMT identifier"),
        (Frame(0, b"\x01\x00", extended=True), "not on the NMT identifier"),
    ],
)
def test_parse_reports_malformed_frames(frame, reason):
    with pytest.raises(MalformedNmtError, match=reason):
        parse_nmt(frame)


# --- slave state machine ----------------------------------------------------------------------


def test_boot_sends_bootup_and_enters_preoperational():
    s = NmtSlave(27)
    assert s.state is INIT and s.deadline is None
    out = s.boot(0.5)
    assert out.frames == (Frame.parse("71B [1] 00"),)
    assert out.events == (NmtStateChanged(INIT, PRE),)
    assert s.state is PRE


def test_boot_twice_is_refused():
    s = booted()
    with pytest.raises(NmtError, match="not initialising"):
        s.boot(1.0)


def test_commands_are_ignored_while_initialising():
    s = NmtSlave(5)
    assert s.on_frame(nmt(0x01, 5), 0.0) is NOTHING
    assert s.state is INIT


@pytest.mark.parametrize(
    ("commands", "states"),
    [
        ([0x01], [OP]),
        ([0x02], [STOP]),
        ([0x01, 0x80], [OP, PRE]),
        ([0x02, 0x01], [STOP, OP]),
        ([0x02, 0x80], [STOP, PRE]),
        ([0x01, 0x02], [OP, STOP]),
    ],
)
def test_transitions(commands, states):
    s = booted(27)
    old = PRE
    for cs, new in zip(commands, states, strict=True):
        out = s.on_frame(nmt(cs, 27), 1.0)
        assert out.events == (NmtStateChanged(old, new),) and out.frames == ()
        assert s.state is new
        old = new


def test_broadcast_applies_and_other_nodes_are_ignored():
    s = booted(27)
    assert s.on_frame(nmt(0x01, 26), 1.0) is NOTHING
    assert s.state is PRE
    assert s.on_frame(nmt(0x01, 0), 1.0).events == (NmtStateChanged(PRE, OP),)


def test_same_state_command_reports_nothing():
    s = booted()
    assert s.on_frame(nmt(0x80, 0), 1.0) is NOTHING


@pytest.mark.parametrize(("cs", "event"), [(0x81, ResetNode()), (0x82, ResetCommunication())])
def test_reset_commands_leave_the_boot_up_to_the_owner(cs, event):
    s = booted(17)
    s.on_frame(nmt(0x01, 0), 1.0)
    out = s.on_frame(nmt(cs, 17), 2.0)
    assert out.frames == ()
    assert out.events == (NmtStateChanged(OP, INIT), event)
    assert s.state is INIT and s.allowed(Service.BOOTUP)
    # the owner resets, then boots: the boot-up message goes out now
    again = s.boot(2.1)
    assert again.frames == (Frame.parse("711 [1] 00"),)
    assert again.events == (NmtStateChanged(INIT, PRE),)


def test_reset_in_preoperational_also_resets():
    s = booted(3)
    out = s.on_frame(Frame.parse("000 [2] 82 03"), 1.0)
    assert out.events == (NmtStateChanged(PRE, INIT), ResetCommunication())


def test_malformed_frames_become_events():
    s = booted(27)
    out = s.on_frame(Frame(0, b"\x01"), 1.0)
    (event,) = out.events
    assert isinstance(event, MalformedNmt) and event.data == b"\x01"
    assert "exactly 2" in event.reason
    (event,) = s.on_frame(Frame(0, b"\x07\x1b"), 1.0).events
    assert isinstance(event, MalformedNmt) and "0x07" in event.reason
    (event,) = s.on_frame(Frame(0, rtr=True), 1.0).events
    assert isinstance(event, MalformedNmt) and "remote" in event.reason
    (event,) = s.on_frame(Frame(0, b"\x01\xff"), 1.0).events
    assert isinstance(event, MalformedNmt) and "255" in event.reason
    assert s.state is PRE


def test_frames_on_other_identifiers_are_not_nmt():
    s = booted(27)
    assert s.on_frame(Frame(0x71B, b"\x01\x1b"), 1.0) is NOTHING
    assert s.on_frame(Frame(0, b"\x01\x1b", extended=True), 1.0) is NOTHING
    assert s.on_timer(5.0) is NOTHING


def test_apply_for_local_decisions():
    s = booted(27)
    s.apply(NmtCommand.START, 1.0)
    out = s.apply(NmtCommand.ENTER_PREOPERATIONAL, 2.0)  # e.g. life guarding expired
    assert out.events == (NmtStateChanged(OP, PRE),)
    assert s.apply(0x01, 3.0).events == (NmtStateChanged(PRE, OP),)
    with pytest.raises(NmtError, match="unknown NMT command"):
        s.apply(0x42, 4.0)


# --- service gating --------------------------------------------------------------------------


def flags(s: NmtSlave) -> tuple[bool, bool, bool]:
    return s.sdo_allowed, s.pdo_allowed, s.emcy_allowed


def test_services_per_state():
    s = NmtSlave(1)
    assert s.services == {Service.BOOTUP}
    assert flags(s) == (False, False, False)
    s.boot(0.0)
    assert flags(s) == (True, False, True)
    for service in (Service.SYNC, Service.TIME, Service.NMT, Service.HEARTBEAT):
        assert s.allowed(service)
    assert not s.allowed(Service.BOOTUP)
    s.on_frame(nmt(0x01, 1), 1.0)
    assert flags(s) == (True, True, True) and s.allowed(Service.TIME)
    s.on_frame(nmt(0x02, 1), 2.0)
    assert s.services == {Service.NMT, Service.ERROR_CONTROL}
    assert s.allowed(Service.HEARTBEAT) and flags(s) == (False, False, False)
