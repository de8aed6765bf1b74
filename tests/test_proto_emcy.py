import pytest

from cobus.proto import NOTHING, Frame, Machine
from cobus.proto.emcy import (
    EmcyCobId,
    EmcyCode,
    EmcyConsumer,
    EmcyError,
    EmcyProducer,
    EmcyQueueOverflow,
    EmcyReceived,
    ErrorRegister,
    MalformedEmcy,
    describe,
    emcy_frame_data,
    parse_emcy,
)
from tests.golden import case


def deadline(machine: Machine) -> float | None:
    return machine.deadline


# --- codes ------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("code", "text"),
    [
        (0x0000, "Error reset or no error"),
        (0x8110, "CAN overrun (objects lost)"),
        (0x8120, "CAN in error passive mode"),
        (0x8130, "Life guard error or heartbeat error"),
        (0x8140, "Recovered from bus off"),
        (0x8150, "CAN-ID collision"),
        (0x8210, "PDO not processed due to length error"),
        (0x8220, "PDO length exceeded"),
        (0x8230, "DAM MPDO not processed, destination object not available"),
        (0x8240, "Unexpected SYNC data length"),
        (0x8250, "RPDO timeout"),
        (0x8100, "Communication – generic"),
        (0x1000, "Generic error"),
        (0xFF00, "Device specific – generic error"),
    ],
)
def test_defined_codes(code, text):
    assert describe(code) == text
    assert EmcyCode(code).text == text


@pytest.mark.parametrize(
    ("code", "text"),
    [
        (0x0012, "Error reset or no error"),
        (0x2110, "Current, CANopen device input side (2110h)"),
        (0x2230, "Current inside the CANopen device (2230h)"),
        (0x2310, "Current, CANopen device output side (2310h)"),
        (0x2400, "Current (2400h)"),
        (0x3110, "Mains voltage (3110h)"),
        (0x3210, "Voltage inside the CANopen device (3210h)"),
        (0x3310, "Output voltage (3310h)"),
        (0x4310, "Temperature (4310h)"),
        (0x4110, "Ambient temperature (4110h)"),
        (0x4210, "Device temperature (4210h)"),
        (0x5200, "CANopen device hardware (5200h)"),
        (0x6010, "CANopen device software (6010h)"),
        (0x6110, "Internal software (6110h)"),
        (0x6201, "User software (6201h)"),
        (0x6310, "Data set (6310h)"),
        (0x7303, "Additional modules (7303h)"),
        (0x8311, "Monitoring (8311h)"),
        (0x8111, "Communication (8111h)"),
        (0x8260, "Protocol error (8260h)"),
        (0x9001, "External error (9001h)"),
        (0xF001, "Additional functions (F001h)"),
        (0xFF42, "Device specific (FF42h)"),
        (0x1234, "Generic error (1234h)"),
    ],
)
def test_codes_fall_back_to_their_class(code, text):
    assert describe(code) == text


@pytest.mark.parametrize("code", [0xA000, 0xE123, 0xF100])
def test_codes_of_no_class(code):
    assert "no CiA 301 class" in describe(code)


def test_describe_refuses_non_u16():
    with pytest.raises(EmcyError, match="UNSIGNED16"):
        describe(0x10000)


def test_error_register_bits():
    assert (int(ErrorRegister.GENERIC), int(ErrorRegister.MANUFACTURER)) == (0x01, 0x80)
    reg = ErrorRegister(0x08) | ErrorRegister.GENERIC
    assert ErrorRegister.TEMPERATURE in reg and ErrorRegister.CURRENT not in reg
    assert [int(b) for b in ErrorRegister] == [1, 2, 4, 8, 0x10, 0x20, 0x40, 0x80]


# --- consumer ---------------------------------------------------------------------------------


def test_stober_vectors_decode():
    c = EmcyConsumer()
    fault, ack = case("stober-mds5000", "EMCY on motor temperature").steps
    (event,) = c.on_frame(fault.frame, 0.0).events
    assert event == EmcyReceived(
        1, 0x4310, ErrorRegister.TEMPERATURE, bytes([0x29, 0, 0, 0, 0]), "Temperature (4310h)"
    )
    assert not event.is_reset
    (event,) = c.on_frame(ack.frame, 0.0).events
    assert isinstance(event, EmcyReceived)
    assert event.code == 0 and event.register == 0 and event.is_reset
    assert event.manufacturer_data == bytes([0x1E, 0, 0, 0, 0])
    assert event.text == "Error reset or no error"


def test_malformed_emcy_is_an_event():
    c = EmcyConsumer()
    (event,) = c.on_frame(Frame(0x85, b"\x10\x43\x08"), 0.0).events
    assert event == MalformedEmcy(
        5, b"\x10\x43\x08", "emergency with 3 data bytes; CiA 301 emergencies carry 8"
    )
    (event,) = c.on_frame(Frame(0x85, rtr=True), 0.0).events
    assert isinstance(event, MalformedEmcy) and "remote" in event.reason


def test_consumer_ignores_other_identifiers_and_remaps():
    c = EmcyConsumer()
    assert c.on_frame(Frame(0x80, bytes(8)), 0.0) is NOTHING  # SYNC, not EMCY
    assert c.on_frame(Frame(0x100, bytes(8)), 0.0) is NOTHING
    assert c.on_frame(Frame(0x81, bytes(8), extended=True), 0.0) is NOTHING
    c.set_cob_id(5, 0x3F5)
    assert c.on_frame(Frame(0x85, bytes(8)), 0.0) is NOTHING
    (event,) = c.on_frame(Frame(0x3F5, bytes(8)), 0.0).events
    assert isinstance(event, EmcyReceived) and event.node_id == 5
    c.set_cob_id(6, 0x81)  # node 1's pre-defined identifier may be taken over
    (event,) = c.on_frame(Frame(0x81, bytes(8)), 0.0).events
    assert isinstance(event, EmcyReceived) and event.node_id == 6
    with pytest.raises(EmcyError, match="already assigned to node 5"):
        c.set_cob_id(7, 0x3F5)
    c.set_cob_id(5, 0x1234, extended=True)
    assert c.on_frame(Frame(0x3F5, bytes(8)), 0.0) is NOTHING
    (event,) = c.on_frame(Frame(0x1234, bytes(8), extended=True), 0.0).events
    assert isinstance(event, EmcyReceived) and event.node_id == 5
    with pytest.raises(EmcyError, match="already assigned to node 5"):
        c.set_cob_id(8, 0x1234, extended=True)
    with pytest.raises(EmcyError, match="11-bit"):
        c.set_cob_id(5, 0x800)
    with pytest.raises(EmcyError, match=r"1\.\.127"):
        c.set_cob_id(0, 0x100)
    assert deadline(c) is None and c.on_timer(1.0) is NOTHING


def test_parse_emcy_function():
    event = parse_emcy(Frame(0x90, bytes.fromhex("3081110102030405")), 0x10)
    assert event == EmcyReceived(
        0x10,
        0x8130,
        ErrorRegister.GENERIC | ErrorRegister.COMMUNICATION,
        bytes([1, 2, 3, 4, 5]),
        "Life guard error or heartbeat error",
    )


# --- frame data and COB-ID --------------------------------------------------------------------


def test_frame_data():
    assert emcy_frame_data(0x4310, 0x08, b"\x29") == bytes.fromhex("1043082900000000")
    with pytest.raises(EmcyError, match="at most 5"):
        emcy_frame_data(0x1000, 1, bytes(6))
    with pytest.raises(EmcyError, match="UNSIGNED16"):
        emcy_frame_data(0x10000, 1)
    with pytest.raises(EmcyError, match="UNSIGNED8"):
        emcy_frame_data(0x1000, 0x100)


def test_cob_id_codec():
    assert EmcyCobId.from_u32(0x85) == EmcyCobId(0x85, True, False)
    assert EmcyCobId.from_u32(0x80000085) == EmcyCobId(0x85, False, False)
    assert EmcyCobId.from_u32(0x20012345) == EmcyCobId(0x12345, True, True)
    assert EmcyCobId(0x85, False).to_u32() == 0x80000085
    assert EmcyCobId(0x12345, True, True).to_u32() == 0x20012345
    with pytest.raises(EmcyError, match="bit 30"):
        EmcyCobId.from_u32(0x40000085)
    with pytest.raises(EmcyError, match="needs bit 29"):
        EmcyCobId.from_u32(0x800)
    with pytest.raises(EmcyError, match="UNSIGNED32"):
        EmcyCobId.from_u32(-1)


# --- producer ---------------------------------------------------------------------------------


def test_producer_sends_the_stober_frames():
    p = EmcyProducer(1)
    fault, ack = (s.frame for s in case("stober-mds5000", "EMCY on motor temperature").steps)
    assert p.send(0x4310, ErrorRegister.TEMPERATURE, b"\x29", 0.0).frames == (fault,)
    assert p.error_register == ErrorRegister.TEMPERATURE
    assert p.reset(2.0, 0, b"\x1e").frames == (ack,)  # byte 3 = E82 event 30 (1Eh)
    assert int(p.error_register) == 0
    assert p.history == (0x4310,)  # resets are not errors
    assert p.on_frame(fault, 3.0) is NOTHING


def test_inhibit_time_queues_and_sends_at_its_end():
    p = EmcyProducer(4)
    p.set_inhibit_time(1250, 0.0)  # 125 ms
    first = p.send(0x1000, 1, b"", 0.0)
    assert len(first.frames) == 1 and deadline(p) is None
    assert p.send(0x2310, 3, b"\x01", 0.0625) is NOTHING  # queued, not lost
    assert p.send(0x3110, 5, b"", 0.07) is NOTHING
    assert deadline(p) == 0.125
    assert p.on_timer(0.1) is NOTHING
    (frame,) = p.on_timer(0.125).frames
    assert frame.data[:2] == b"\x10\x23"
    assert deadline(p) == 0.25
    (frame,) = p.on_timer(0.25).frames
    assert frame.data[:2] == b"\x10\x31"
    assert deadline(p) is None
    # a request while the queue is empty but inhibit still runs also waits
    assert p.send(0x1000, 1, b"", 0.3125) is NOTHING
    assert deadline(p) == 0.375
    assert len(p.on_timer(0.375).frames) == 1
    # after the inhibit time: immediate
    assert len(p.send(0x1000, 1, b"", 0.5).frames) == 1


def test_queue_overflow_is_reported():
    p = EmcyProducer(4, queue_size=1)
    p.set_inhibit_time(10, 0.0)
    p.send(0x1000, 1, b"", 0.0)
    assert p.send(0x1001, 1, b"", 0.0) is NOTHING
    assert p.send(0x1002, 1, b"", 0.0).events == (EmcyQueueOverflow(0x1002),)
    assert p.history[0] == 0x1002  # still recorded


def test_changing_the_inhibit_time_while_running():
    p = EmcyProducer(4)
    p.set_inhibit_time(1000, 0.0)
    p.send(0x1000, 1, b"", 0.0)
    p.send(0x1001, 1, b"", 0.01)
    p.set_inhibit_time(500, 0.02)  # the running period now ends at 0.05
    assert deadline(p) == pytest.approx(0.05)
    assert len(p.on_timer(0.05).frames) == 1
    p.set_inhibit_time(0, 0.06)
    assert len(p.send(0x1002, 1, b"", 0.06).frames) == 1
    with pytest.raises(EmcyError, match="1015h"):
        p.set_inhibit_time(0x10000, 0.0)


def test_history_newest_first_with_depth():
    p = EmcyProducer(4, depth=3)
    for i, code in enumerate((0x1000, 0x2000, 0x3000, 0x4000)):
        p.send(code, 1, b"", float(i), info=i)
    assert list(p.history) == [0x00034000, 0x00023000, 0x00012000]
    assert p.error_field(0) == 3
    assert p.error_field(1) == 0x00034000 and p.error_field(3) == 0x00012000
    with pytest.raises(EmcyError, match=r"sub-indexes 0\.\.3"):
        p.error_field(4)
    p.write_error_count(0)
    assert list(p.history) == [] and p.error_field(0) == 0
    with pytest.raises(EmcyError, match="holds no error"):
        p.error_field(1)
    with pytest.raises(EmcyError, match="accepts only 0"):
        p.write_error_count(2)
    p.record(0x5000, info=0xBEEF)
    assert p.history == (0xBEEF5000,)
    with pytest.raises(EmcyError, match="additional information"):
        p.record(0x5000, info=0x10000)
    with pytest.raises(EmcyError, match="UNSIGNED16"):
        p.record(-1)


def test_no_history():
    p = EmcyProducer(4, depth=0)
    p.send(0x1000, 1, b"", 0.0)
    assert p.history == () and p.error_field(0) == 0
    with pytest.raises(EmcyError, match="sub-indexes"):
        p.error_field(1)


def test_cob_id_of_the_producer():
    p = EmcyProducer(4)
    assert p.cob_id == 0x84
    p.set_cob_id(0x80000084)  # invalid: nothing is sent, the history still records
    assert p.send(0x1000, 1, b"", 0.0) is NOTHING
    assert p.history == (0x1000,)
    p.set_cob_id(0x20000123)
    (frame,) = p.send(0x1000, 1, b"", 1.0).frames
    assert frame.cob_id == 0x123 and frame.extended
    assert p.cob_id == 0x20000123


def test_invalidating_drops_the_queue():
    p = EmcyProducer(4)
    p.set_inhibit_time(1000, 0.0)
    p.send(0x1000, 1, b"", 0.0)
    p.send(0x1001, 1, b"", 0.01)
    p.set_cob_id(0x80000084)
    assert deadline(p) is None and p.on_timer(1.0) is NOTHING


def test_producer_validation():
    with pytest.raises(EmcyError, match=r"1\.\.127"):
        EmcyProducer(0)
    with pytest.raises(EmcyError, match="254"):
        EmcyProducer(1, depth=255)
    with pytest.raises(EmcyError, match="at least 1"):
        EmcyProducer(1, queue_size=0)
    with pytest.raises(EmcyError, match="at most 5"):
        EmcyProducer(1).send(0x1000, 1, bytes(6), 0.0)
