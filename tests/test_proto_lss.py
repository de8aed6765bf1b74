"""LSS (CiA 305) frame by frame: the slave, the master's services, fastscan; the timing on a
simulated wire (no bus, no clock: the machines' deadlines drive the time)."""

from __future__ import annotations

import random
from typing import Any

import pytest

from cobus.proto import Event, Frame, Out
from cobus.proto.lss import (
    UNCONFIGURED,
    BitTimingActivated,
    BitTimingConfigured,
    ConfigurationStored,
    Fastscan,
    FastscanFailed,
    FastscanFieldFound,
    FastscanFieldRetried,
    FastscanFound,
    FastscanNothingFound,
    FastscanStarted,
    LssConfirmed,
    LssError,
    LssIdentified,
    LssIdentity,
    LssInquired,
    LssMaster,
    LssNoAnswer,
    LssSelected,
    LssSlave,
    LssState,
    LssStateSwitched,
    LssStrayAnswer,
    NodeIdAssigned,
    NodeIdConfigured,
    StoreFailed,
    bit_timing_index,
)

ME = LssIdentity(0x360, 0x1234, 0x0001_0000, 0x2A)


def req(text: str) -> Frame:
    return Frame(0x7E5, bytes.fromhex(text))


def ans(text: str) -> Frame:
    return Frame(0x7E4, bytes.fromhex(text))


def hexes(out: Out) -> list[str]:
    return [f"{f.cob_id:03X} {f.data.hex(' ')}" for f in out.frames]


def state_of(slave: LssSlave) -> LssState:
    return slave.state


def configured(slave: LssSlave) -> None:
    assert slave.on_frame(req("04 01 00 00 00 00 00 00"), 0).events == (
        LssStateSwitched(LssState.CONFIGURATION, "global"),
    )


# ---------------------------------------------------------------- the slave


def test_switch_state_global_and_what_waiting_refuses() -> None:
    slave = LssSlave(ME, 5)
    assert slave.on_frame(req("5E 00 00 00 00 00 00 00"), 0) == Out()  # waiting: no inquiry
    assert slave.on_frame(req("11 07 00 00 00 00 00 00"), 0) == Out()  # nor a node-ID
    configured(slave)
    assert hexes(slave.on_frame(req("5E 00 00 00 00 00 00 00"), 0)) == [
        "7E4 5e 05 00 00 00 00 00 00"
    ]
    out = slave.on_frame(req("04 00 00 00 00 00 00 00"), 0)
    assert out.events == (LssStateSwitched(LssState.WAITING, "global"),)
    assert slave.state is LssState.WAITING
    assert slave.on_frame(req("04 00"), 0) == Out()  # CiA 305: 8 bytes or nothing
    assert slave.on_frame(req("04 07 00 00 00 00 00 00"), 0) == Out()  # no such state


def test_switch_state_selective_answers_only_the_whole_identity_in_order() -> None:
    slave = LssSlave(ME, 5)
    asks = ["40 60 03 00 00", "41 34 12 00 00", "42 00 00 01 00", "43 2a 00 00 00"]
    outs = [slave.on_frame(req(a + " 00 00 00"), 0) for a in asks]
    assert [hexes(o) for o in outs[:3]] == [[], [], []]
    assert hexes(outs[3]) == ["7E4 44 00 00 00 00 00 00 00"]
    assert outs[3].events == (LssStateSwitched(LssState.CONFIGURATION, "selective"),)
    other = LssSlave(LssIdentity(0x360, 0x1234, 0x0001_0000, 0x2B), 6)
    assert [hexes(other.on_frame(req(a + " 00 00 00"), 0)) for a in asks] == [[], [], [], []]
    jumbled = LssSlave(ME, 7)
    order = [asks[0], asks[2], asks[1], asks[3]]  # out of order: starts again
    assert [hexes(jumbled.on_frame(req(a + " 00 00 00"), 0)) for a in order] == [[], [], [], []]
    assert jumbled.state is LssState.WAITING


def test_configure_node_id_pending_until_switched_back_then_assigned() -> None:
    slave = LssSlave(ME)  # unconfigured
    assert not slave.configured
    configured(slave)
    assert hexes(slave.on_frame(req("11 80 00 00 00 00 00 00"), 0)) == [
        "7E4 11 01 00 00 00 00 00 00"  # 128: out of range
    ]
    assert hexes(slave.on_frame(req("11 00 00 00 00 00 00 00"), 0))[0].startswith("7E4 11 01")
    out = slave.on_frame(req("11 0c 00 00 00 00 00 00"), 0)
    assert hexes(out) == ["7E4 11 00 00 00 00 00 00 00"]
    assert out.events == (NodeIdConfigured(12),)
    assert (slave.active_node_id, slave.pending_node_id) == (UNCONFIGURED, 12)
    out = slave.on_frame(req("04 00 00 00 00 00 00 00"), 0)
    assert out.events == (LssStateSwitched(LssState.WAITING, "global"), NodeIdAssigned(12))
    assert slave.active_node_id == 12 and slave.configured


def test_a_configured_device_takes_a_new_node_id_at_its_next_reset() -> None:
    slave = LssSlave(ME, 5)
    configured(slave)
    slave.on_frame(req("11 09 00 00 00 00 00 00"), 0)
    out = slave.on_frame(req("04 00 00 00 00 00 00 00"), 0)
    assert NodeIdAssigned(9) not in out.events and slave.active_node_id == 5
    slave.node_id_active()  # the device reset its communication
    assert slave.active_node_id == 9


def test_bit_timing_configured_refused_and_activated() -> None:
    slave = LssSlave(ME, 5, bit_rates={2, 3, 4})
    configured(slave)
    assert slave.on_frame(req("15 e8 03 00 00 00 00 00"), 0) == Out()  # nothing to switch to
    assert hexes(slave.on_frame(req("13 00 00 00 00 00 00 00"), 0)) == [
        "7E4 13 01 00 00 00 00 00 00"  # 1 Mbit/s: not this device's
    ]
    assert hexes(slave.on_frame(req("13 01 03 00 00 00 00 00"), 0))[0].startswith("7E4 13 01")
    assert hexes(slave.on_frame(req("13 00 09 00 00 00 00 00"), 0))[0].startswith("7E4 13 01")
    out = slave.on_frame(req("13 00 03 00 00 00 00 00"), 0)
    assert hexes(out) == ["7E4 13 00 00 00 00 00 00 00"]
    assert out.events == (BitTimingConfigured(3, 250),)
    out = slave.on_frame(req("15 e8 03 00 00 00 00 00"), 0)
    assert out == Out((), (BitTimingActivated(1.0, 3),))  # no answer, 1000 ms
    assert bit_timing_index(250) == 3 and bit_timing_index(10) == 8
    with pytest.raises(LssError, match="not in CiA 305's bit timing table"):
        bit_timing_index(300)


def test_store_configuration_answers_with_the_standard_error_codes() -> None:
    unsupported = LssSlave(ME, 5)
    configured(unsupported)
    out = unsupported.on_frame(req("17 00 00 00 00 00 00 00"), 0)
    assert hexes(out) == ["7E4 17 01 00 00 00 00 00 00"]
    assert out.events == (StoreFailed(1, "not supported"),)

    kept: list[tuple[int, int | None]] = []
    slave = LssSlave(ME, 5, store=lambda node, bits: kept.append((node, bits)) or 0)
    configured(slave)
    slave.on_frame(req("11 0c 00 00 00 00 00 00"), 0)
    out = slave.on_frame(req("17 00 00 00 00 00 00 00"), 0)
    assert hexes(out) == ["7E4 17 00 00 00 00 00 00 00"] and kept == [(12, None)]
    assert out.events == (ConfigurationStored(12, None),)

    def broken(node: int, bits: int | None) -> int:
        raise OSError("read-only file system")

    failing = LssSlave(ME, 5, store=broken)
    configured(failing)
    out = failing.on_frame(req("17 00 00 00 00 00 00 00"), 0)
    assert hexes(out) == ["7E4 17 02 00 00 00 00 00 00"]  # media access error
    assert out.events == (StoreFailed(2, "OSError: read-only file system"),)


def test_inquire_identity_and_node_id() -> None:
    slave = LssSlave(ME, 5)
    configured(slave)
    got = [
        hexes(slave.on_frame(req(f"{cs} 00 00 00 00 00 00 00"), 0))[0]
        for cs in ["5a", "5b", "5c", "5d", "5e"]
    ]
    assert got == [
        "7E4 5a 60 03 00 00 00 00 00",
        "7E4 5b 34 12 00 00 00 00 00",
        "7E4 5c 00 00 01 00 00 00 00",
        "7E4 5d 2a 00 00 00 00 00 00",
        "7E4 5e 05 00 00 00 00 00 00",
    ]


def test_identify_remote_slave_by_ranges_and_non_configured() -> None:
    slave = LssSlave(ME)

    def identify(rev: tuple[int, int], serial: tuple[int, int]) -> list[str]:
        values = (0x360, 0x1234, *rev, *serial)
        outs = [
            slave.on_frame(Frame(0x7E5, bytes((cs,)) + v.to_bytes(4, "little") + bytes(3)), 0)
            for cs, v in zip(range(0x46, 0x4C), values, strict=True)
        ]
        assert all(not o.frames for o in outs[:5])
        return hexes(outs[5])

    assert identify((0, 0xFFFF_FFFF), (0x20, 0x2A)) == ["7E4 4f 00 00 00 00 00 00 00"]
    assert identify((0, 0xFFFF), (0x20, 0x2A)) == []  # revision 1.0 outside
    assert identify((0x1_0000, 0x1_0000), (0x2B, 0x30)) == []
    assert hexes(slave.on_frame(req("4c 00 00 00 00 00 00 00"), 0)) == [
        "7E4 50 00 00 00 00 00 00 00"
    ]
    assert LssSlave(ME, 5).on_frame(req("4c 00 00 00 00 00 00 00"), 0) == Out()


def test_fastscan_on_the_slave_bit_by_bit() -> None:
    slave = LssSlave(ME)

    def scan(number: int, bit: int, sub: int, following: int) -> Out:
        body = number.to_bytes(4, "little") + bytes((bit, sub, following))
        return slave.on_frame(Frame(0x7E5, b"\x51" + body), 0)

    assert hexes(scan(0, 0x80, 0, 0)) == ["7E4 4f 00 00 00 00 00 00 00"]
    assert hexes(scan(0, 31, 0, 0)) == ["7E4 4f 00 00 00 00 00 00 00"]  # bit 31 of 360h is 0
    assert hexes(scan(0, 9, 0, 0)) == []  # bit 9 of 360h is 1
    assert hexes(scan(0x200, 9, 0, 0)) != []
    assert hexes(scan(0x360, 0, 1, 2)) == []  # not at the product yet
    assert hexes(scan(0x361, 0, 0, 1)) == []  # wrong vendor
    assert hexes(scan(0x360, 0, 0, 1)) != []  # vendor confirmed: on to the product
    assert hexes(scan(0x1234, 0, 1, 2)) != [] and hexes(scan(0x1_0000, 0, 2, 3)) != []
    assert state_of(slave) is LssState.WAITING
    out = scan(0x2A, 0, 3, 0)  # the serial, wrapping to the vendor: this slave is selected
    assert hexes(out) != [] and state_of(slave) is LssState.CONFIGURATION
    assert out.events == (LssStateSwitched(LssState.CONFIGURATION, "fastscan"),)
    assert hexes(LssSlave(ME, 5).on_frame(req("51 00 00 00 00 80 00 00"), 0)) == []
    assert hexes(scan(0, 32, 0, 0)) == []  # bit 32 does not exist


def test_an_answer_delay_holds_every_answer_back() -> None:
    slave = LssSlave(ME, answer_delay=0.02)
    out = slave.on_frame(req("4c 00 00 00 00 00 00 00"), 1.0)
    assert out.frames == () and slave.deadline == pytest.approx(1.02)
    assert slave.on_timer(1.01) == Out()
    assert hexes(slave.on_timer(1.02)) == ["7E4 50 00 00 00 00 00 00 00"]
    assert slave.deadline is None


def test_bad_slave_options_are_refused_with_what_to_give() -> None:
    with pytest.raises(LssError, match=r"give 1\.\.127, or 0xFF"):
        LssSlave(ME, 0)
    with pytest.raises(LssError, match="give an LssIdentity"):
        LssSlave((1, 2, 3, 4), 5)  # type: ignore[arg-type]
    with pytest.raises(LssError, match="serial -1 is no UNSIGNED32"):
        LssIdentity(1, 2, 3, -1)
    with pytest.raises(LssError, match="answer_delay"):
        LssSlave(ME, answer_delay=-1)
    with pytest.raises(LssError, match="give indices of CiA 305's table"):
        LssSlave(ME, bit_rates={5})  # reserved


# ---------------------------------------------------------------- the master's services


def test_master_services_frames_and_answers() -> None:
    m = LssMaster(timeout=0.1)
    assert hexes(m.switch_global(LssState.CONFIGURATION)) == ["7E5 04 01 00 00 00 00 00 00"]
    assert hexes(m.switch_selective(ME, 0)) == [
        "7E5 40 60 03 00 00 00 00 00",
        "7E5 41 34 12 00 00 00 00 00",
        "7E5 42 00 00 01 00 00 00 00",
        "7E5 43 2a 00 00 00 00 00 00",
    ]
    assert m.busy and m.deadline == pytest.approx(0.1)
    with pytest.raises(LssError, match="is under way"):
        m.store(0)
    assert m.on_frame(ans("44 00 00 00 00 00 00 00"), 0.01).events == (LssSelected(ME),)
    assert not bool(m.busy)  # (a property: mypy would keep it True)
    assert hexes(m.configure_node_id(12, 0)) == ["7E5 11 0c 00 00 00 00 00 00"]
    assert m.on_frame(ans("11 01 00 00 00 00 00 00"), 0).events == (
        LssConfirmed("configure node-ID", 1, 0, "node-ID out of range"),
    )
    assert hexes(m.configure_bit_timing(bit_timing_index(125), 0)) == [
        "7E5 13 00 04 00 00 00 00 00"
    ]
    (ok,) = m.on_frame(ans("13 00 00 00 00 00 00 00"), 0).events
    assert isinstance(ok, LssConfirmed) and ok.ok and ok.text == ""
    assert hexes(m.activate_bit_timing(0.5)) == ["7E5 15 f4 01 00 00 00 00 00"]
    assert hexes(m.store(0)) == ["7E5 17 00 00 00 00 00 00 00"]
    assert m.on_frame(ans("17 ff 07 00 00 00 00 00"), 0).events == (
        LssConfirmed("store configuration", 0xFF, 7, "manufacturer-specific error 7 (FFh)"),
    )
    m.inquire("serial", 0)
    assert m.on_frame(ans("5d 2a 00 00 00 00 00 00"), 0).events == (LssInquired("serial", 42),)
    m.inquire("node_id", 0)
    assert m.on_frame(ans("5e 0c 00 00 00 00 00 00"), 0).events == (LssInquired("node_id", 12),)
    assert hexes(m.identify_unconfigured(0)) == ["7E5 4c 00 00 00 00 00 00 00"]
    assert m.on_frame(ans("50 00 00 00 00 00 00 00"), 0).events == (LssIdentified("unconfigured"),)
    assert len(m.identify_remote(0x360, 0x1234, (0, 5), (1, 99), 0).frames) == 6
    assert m.on_frame(ans("4f 00 00 00 00 00 00 00"), 0).events == (LssIdentified("remote"),)


def test_master_timeouts_and_stray_answers() -> None:
    m = LssMaster(timeout=0.2)
    m.inquire("vendor", 1.0)
    assert m.on_timer(1.1) == Out()
    assert m.on_timer(1.2).events == (LssNoAnswer("inquire vendor", 0.2),)
    assert m.on_frame(ans("5a 60 03 00 00 00 00 00"), 1.3).events == (
        LssStrayAnswer(bytes.fromhex("5a 60 03 00 00 00 00 00")),
    )
    m.inquire("product", 2.0)
    (stray,) = m.on_frame(ans("5a 60 03 00 00 00 00 00"), 2.01).events  # not the product
    assert isinstance(stray, LssStrayAnswer) and m.busy


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda m: m.configure_node_id(0, 0), r"give 1\.\.127, or 0xFF"),
        (lambda m: m.configure_node_id(True, 0), r"give 1\.\.127, or 0xFF"),
        (lambda m: m.configure_bit_timing(5, 0), r"give 0\.\.4, 6\.\.8"),
        (lambda m: m.activate_bit_timing(70), "at most 65.535 s"),
        (lambda m: m.inquire("colour", 0), "give one of vendor"),
        (lambda m: m.switch_global(2), "give 0 \\(waiting\\) or 1"),
        (lambda m: m.identify_remote(1, 2, (5, 4), (0, 1), 0), "low bound is above"),
        (lambda m: m.identify_remote(1, 2, (0, 1 << 32), (0, 1), 0), "no UNSIGNED32"),
    ],
)
def test_master_refuses_bad_requests_with_what_to_give(call: Any, message: str) -> None:
    with pytest.raises(LssError, match=message):
        call(LssMaster())


# ---------------------------------------------------------------- a simulated wire


class Wire:
    """A master machine and slaves on one bus: each frame reaches the others ``latency``
    seconds later; time jumps from one frame or deadline to the next."""

    def __init__(self, slaves: list[LssSlave], latency: float = 0.001) -> None:
        self.slaves, self.latency, self.now = slaves, latency, 0.0
        self.flight: list[tuple[float, int, Frame]] = []  # (arrival, 0: to slaves / 1: master)
        self.events: list[Event] = []
        self.slave_events: list[Event] = []
        self.requests = 0

    def send(self, out: Out, to_master: bool) -> None:
        for f in out.frames:
            self.flight.append((self.now + self.latency, int(to_master), f))
            self.requests += not to_master
        (self.events if not to_master else self.slave_events).extend(out.events)

    def run(self, master: Any, first: Out, until: float = 600.0) -> list[Event]:
        self.send(first, False)
        while self.now < until:
            times = [t for t, _, _ in self.flight]
            times += [d for d in [master.deadline, *(s.deadline for s in self.slaves)] if d]
            if not times:
                break
            self.now = min(times)
            arrived = [x for x in self.flight if x[0] <= self.now]
            self.flight = [x for x in self.flight if x[0] > self.now]
            for _, to_master, f in arrived:
                if to_master:
                    self.send(master.on_frame(f, self.now), False)
                else:
                    for s in self.slaves:
                        self.send(s.on_frame(f, self.now), True)
            for s in self.slaves:
                if s.deadline is not None and s.deadline <= self.now:
                    self.send(s.on_timer(self.now), True)
            if master.deadline is not None and master.deadline <= self.now:
                self.send(master.on_timer(self.now), False)
        return self.events


def _random_identity(rng: random.Random) -> LssIdentity:
    return LssIdentity(0x360, rng.choice([0x1234, 0x1235]), 0x0001_0000, rng.getrandbits(32))


def test_fastscan_finds_four_unconfigured_devices_one_after_another() -> None:
    rng = random.Random(305)
    slaves = [LssSlave(_random_identity(rng)) for _ in range(4)]
    slaves.append(LssSlave(_random_identity(rng), 5))  # configured: never found
    wire = Wire(slaves)
    found: list[LssIdentity] = []
    for node_id in (10, 11, 12, 13):
        scan = Fastscan()
        events = wire.run(scan, scan.start(wire.now))
        hit = [e for e in events if isinstance(e, FastscanFound)][-1]
        assert hit.answers == 1 and scan.done
        found.append(hit.identity)
        chosen = [s for s in slaves if s.state is LssState.CONFIGURATION]
        assert [s.identity for s in chosen] == [hit.identity]  # that one, and only it
        master = LssMaster()
        wire.run(master, master.configure_node_id(node_id, wire.now))
        wire.send(master.switch_global(LssState.WAITING), False)
        wire.run(master, Out())
        assert NodeIdAssigned(node_id) in wire.slave_events
    assert sorted(found, key=lambda i: i.serial) == sorted(
        (s.identity for s in slaves[:4]), key=lambda i: i.serial
    )
    scan = Fastscan()
    assert wire.run(scan, scan.start(wire.now))[-1] == FastscanNothingFound(None, None)


def test_fastscan_adapts_its_wait_and_estimates_the_scan() -> None:
    wire = Wire([LssSlave(ME)], latency=0.002)
    scan = Fastscan(floor=0.01, ceiling=0.5, factor=4)
    t0 = wire.now
    events = wire.run(scan, scan.start(t0))
    started = next(e for e in events if isinstance(e, FastscanStarted))
    assert scan.slowest == pytest.approx(0.004)  # there and back
    assert started.window == pytest.approx(0.016)  # 4 x the round trip, above the floor
    assert scan.exchanges == 1 + 4 * 33
    took = wire.now - t0
    assert took == pytest.approx(0.5 + 4 * 33 * 0.016)  # not 133 windows of the ceiling
    assert started.estimate == pytest.approx((4 * 32 + 4) * 0.016)
    fields = [(e.field, e.value) for e in events if isinstance(e, FastscanFieldFound)]
    assert fields == [
        ("vendor", 0x360),
        ("product", 0x1234),
        ("revision", 0x1_0000),
        ("serial", 42),
    ]


def test_fastscan_skips_the_known_fields() -> None:
    wire = Wire([LssSlave(ME)])
    scan = Fastscan({"vendor": 0x360, "product": 0x1234, "revision": 0x1_0000})
    events = wire.run(scan, scan.start(0))
    assert scan.exchanges == 1 + 3 + 33
    assert FastscanFieldFound("vendor", 0x360, True) in events
    assert events[-1] == FastscanFound(ME, 1)
    other = Wire([LssSlave(ME)])
    scan = Fastscan({"vendor": 0x361})
    assert other.run(scan, scan.start(0))[-1] == FastscanNothingFound("vendor", 0x361)
    with pytest.raises(LssError, match="known field 'colour'"):
        Fastscan({"colour": 1})


def test_fastscan_reports_two_devices_with_one_identity() -> None:
    wire = Wire([LssSlave(ME), LssSlave(ME)])
    scan = Fastscan()
    assert wire.run(scan, scan.start(0))[-1] == FastscanFound(ME, 2)


def test_fastscan_rescans_a_field_misread_by_a_late_answer() -> None:
    slave = LssSlave(ME)
    wire = Wire([slave])
    scan = Fastscan(floor=0.01, ceiling=0.05)
    wire.run(scan, scan.start(0), until=0.0011)  # the reset probe: answered after 2 ms
    slave.answer_delay = 0.03  # then the slave slows down: its answers miss the 10 ms window
    events = wire.run(scan, Out())
    retried = [e for e in events if isinstance(e, FastscanFieldRetried)]
    assert [e.field for e in retried] == ["vendor"]  # misread once, scanned again, slower
    assert events[-1] == FastscanFound(ME, 1)
    assert not any(isinstance(e, FastscanFailed) for e in events)


def test_fastscan_gives_up_on_a_field_it_cannot_confirm_twice() -> None:
    slave = LssSlave(ME)
    wire = Wire([slave])
    scan = Fastscan(floor=0.01, ceiling=0.02)
    wire.run(scan, scan.start(0), until=0.0011)
    slave.answer_delay = 0.05  # later than the ceiling itself
    events = wire.run(scan, Out())
    assert isinstance(events[-1], FastscanFailed) and events[-1].field == "vendor"
    assert "got no answer twice" in events[-1].reason and scan.done


def test_a_refused_request_leaves_the_pending_one_alone() -> None:
    m = LssMaster()
    other = LssIdentity(1, 2, 3, 4)
    m.switch_selective(ME, 0)
    with pytest.raises(LssError, match="under way"):
        m.switch_selective(other, 0)
    assert m.on_frame(ans("44 00 00 00 00 00 00 00"), 0).events == (LssSelected(ME),)
    m.inquire("vendor", 0)
    with pytest.raises(LssError, match="under way"):
        m.inquire("serial", 0)
    assert m.on_frame(ans("5a 60 03 00 00 00 00 00"), 0).events == (LssInquired("vendor", 0x360),)


@pytest.mark.parametrize(
    ("said", "answer", "reason"),
    [
        (None, 0, None),
        (True, 0, None),
        (1, 1, "not supported"),
        (False, 2, "media access error"),
        (5, 2, "store returned 5, not 0, 1 or 2"),
    ],
)
def test_what_store_returns_becomes_the_standard_answer(
    said: object, answer: int, reason: str | None
) -> None:
    slave = LssSlave(ME, 5, store=lambda n, b: said)  # type: ignore[arg-type,return-value]
    configured(slave)
    out = slave.on_frame(req("17 00 00 00 00 00 00 00"), 0)
    assert out.frames[0].data[1] == answer
    if reason is None:
        assert out.events == (ConfigurationStored(5, None),)
    else:
        assert out.events == (StoreFailed(answer, reason),)
