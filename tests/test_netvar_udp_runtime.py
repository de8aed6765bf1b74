"""Network variables over UDP at run time (issue 46): cobus <-> cobus on 127.0.0.1, lists
reassembled only from the telegrams of one transmission, junk counted and dropped."""

from __future__ import annotations

import asyncio
import struct
from typing import Any

import pytest

from cobus.blocks.gvl import loads_gvl
from cobus.blocks.netvar_udp import Telegram, UdpDefinition, UdpVarList, iec_type, layout
from cobus.blocks.netvars import (
    AsyncUdpNetworkVariables,
    ListIncomplete,
    ListMalformed,
    ListReceived,
    ListRequested,
    ListSendFailed,
    NetVarEvent,
)


def _list(name: str, list_id: int, items: list[tuple[str, str]], **options: Any) -> UdpVarList:
    return UdpVarList(name, list_id, layout([(n, iec_type(t)) for n, t in items]), **options)


#: Three telegrams a transmission: 200, 200 and 104 bytes.
BIG = [(f"s{i}", "STRING(99)") for i in range(5)] + [("last", "DINT")]


async def _until(check: Any, timeout: float = 3.0) -> None:
    deadline = asyncio.get_running_loop().time() + timeout
    while not check():
        if asyncio.get_running_loop().time() > deadline:
            raise AssertionError("condition not reached in time")
        await asyncio.sleep(0.005)


def test_cobus_to_cobus_over_udp_on_localhost() -> None:
    async def run() -> None:
        lists = [
            _list("big", 5, BIG, interval=0.02),
            _list("flags", 6, [("a", "BOOL"), ("b", "INT")], pack=False, interval=0.02),
        ]
        receiver = AsyncUdpNetworkVariables(UdpDefinition.of(lists), port=0)
        await receiver.open()
        got: list[NetVarEvent] = []
        receiver.add_listener(got.append)
        sender = AsyncUdpNetworkVariables(
            UdpDefinition.of(lists), send=["big", "flags"], port=0, to=receiver.address
        )
        values = {f"s{i}": f"text {i}" * 3 for i in range(5)} | {"last": -70_000}
        sender.set("big", values)
        sender.set("flags", {"a": True, "b": -3})
        await sender.open()
        try:
            await _until(lambda: receiver.statistics()["big"]["received"] >= 2)
            await _until(lambda: receiver.statistics()["flags"]["received"] >= 2)
            assert receiver.values("big") == values
            assert receiver["flags.a"] is True and receiver["flags.b"] == -3
            assert not any(isinstance(e, ListIncomplete | ListMalformed) for e in got)
            counters = [e.counter for e in got if isinstance(e, ListReceived) and e.list == "big"]
            assert counters[:2] == [0, 1]
            assert receiver.dropped()["not_telegrams"] == 0
            assert sender.statistics()["big"]["sent"] >= 2
            with pytest.raises(PermissionError, match="written by"):
                receiver.set("big", {"last": 1})
        finally:
            sender.close()
            receiver.close()

    asyncio.run(run())


def _telegrams(lst: UdpVarList, values: dict[str, Any], counter: int) -> list[bytes]:
    return [t.to_bytes() for t in lst.telegrams(lst.pack_values(values), counter)]


def test_a_list_only_whole_and_from_one_transmission() -> None:
    async def run() -> None:
        big = _list("big", 5, BIG, interval=10.0)
        lists = AsyncUdpNetworkVariables(UdpDefinition.of([big]), port=0)
        await lists.open()
        got: list[NetVarEvent] = []
        lists.add_listener(got.append)
        try:
            first = {f"s{i}": f"a{i}" for i in range(5)} | {"last": 1}
            second = {f"s{i}": f"b{i}" for i in range(5)} | {"last": 2}
            one, two = _telegrams(big, first, 7), _telegrams(big, second, 8)
            # telegram 1 of transmission 7 lost: nothing delivered, the gap reported
            lists.datagram(one[0])
            lists.datagram(one[2])
            lists.datagram(two[2])  # (another counter: 7 ends incomplete)
            lists.datagram(two[0])
            lists.datagram(two[0])  # (a datagram twice: ignored)
            assert not [e for e in got if isinstance(e, ListReceived)]
            (gap,) = [e for e in got if isinstance(e, ListIncomplete)]
            assert (gap.counter, gap.missing) == (7, (1,))
            lists.datagram(two[1])
            (received,) = [e for e in got if isinstance(e, ListReceived)]
            assert received.values == second and received.counter == 8
            assert lists.values("big") == second
            # late telegrams of an older transmission mix with nothing, and a whole older
            # transmission (or one taken already, again) does not roll the values back
            lists.datagram(one[1])
            lists.datagram(one[0])
            for data in _telegrams(big, first, 7) + two:
                lists.datagram(data)
            assert lists.values("big") == second
            assert lists.statistics()["big"] == {
                "received": 1,
                "incomplete": 1,
                "malformed": 0,
                "flagged": 0,
                "late": 8,
            }
            # nor does a late telegram cost the transmission being gathered
            three = _telegrams(big, first, 9)
            lists.datagram(three[0])
            lists.datagram(one[2])
            lists.datagram(three[1])
            lists.datagram(three[2])
            assert lists.values("big") == first and lists.statistics()["big"]["incomplete"] == 1
            # the counter wraps at 65535; a sender that starts again far behind is heard
            for counter in (0xFFF0, 0xFFFF, 0, 5_000, 3):
                for data in _telegrams(big, second if counter % 2 else first, counter):
                    lists.datagram(data)
            last = [e for e in got if isinstance(e, ListReceived)][-5:]
            assert [e.counter for e in last] == [0xFFF0, 0xFFFF, 0, 5_000, 3]
        finally:
            lists.close()

    asyncio.run(run())


def test_junk_foreign_and_flagged_telegrams_are_counted_and_dropped() -> None:
    async def run() -> None:
        small = _list("small", 1, [("flag", "BOOL"), ("count", "INT"), ("ratio", "REAL")])
        lists = AsyncUdpNetworkVariables(UdpDefinition.of([small]), port=0)
        await lists.open()
        got: list[NetVarEvent] = []
        lists.add_listener(got.append)
        try:
            example = bytes.fromhex(
                "00 2D 53 33 00 00 00 00 01 00 00 00 03 00 1B 00 01 00 00 00 01 D2 04 C3 F5 48 40"
            )
            for junk in (b"", b"hello", example[:-1], b"\x00-S4" + example[4:], bytes(300)):
                lists.datagram(junk, ("10.0.0.9", 1202))
            foreign = bytearray(example)
            foreign[8] = 99  # (list 99: not one of ours)
            lists.datagram(bytes(foreign))
            flagged = bytearray(example)
            flagged[18] = 0x02  # (a checksum: not published, never guessed at)
            lists.datagram(bytes(flagged))
            wrong = Telegram(1, 0, 2, 5, example[20:]).to_bytes()  # (2 values said, 3 there)
            lists.datagram(wrong)
            beyond = Telegram(1, 1, 3, 5, example[20:]).to_bytes()  # (a second telegram)
            lists.datagram(beyond)
            assert lists.dropped() == {
                "datagrams": 9,
                "not_telegrams": 5,
                "foreign": 1,
                "of_own_lists": 0,
                "requests": 0,
            }
            assert lists.last_junk is not None and lists.last_junk[0] == ("10.0.0.9", 1202)
            reasons = [e.reason for e in got if isinstance(e, ListMalformed)]
            assert "flags 02h" in reasons[0]
            malformed = next(e for e in got if isinstance(e, ListMalformed))
            assert str(malformed).startswith("list small (identifier 1): telegram with flags")
            assert "2 values in 7 bytes, the definition has 3 in 7" in reasons[1]
            assert "telegram 1: the list has 1 telegram(s)" in reasons[2]
            assert lists.statistics()["small"]["flagged"] == 1
            assert not [e for e in got if isinstance(e, ListReceived)]
            lists.datagram(example)
            assert lists["small.count"] == 1234
        finally:
            lists.close()

    asyncio.run(run())


def test_requests_are_answered_and_broadcast_needs_asking() -> None:
    async def run() -> None:
        mine = _list(
            "mine",
            3,
            [("x", "UDINT")],
            transmit="on_event",
            modes=frozenset({"on_event"}),
            event=None,
        )
        listener = AsyncUdpNetworkVariables(UdpDefinition.of([mine]), port=0)
        await listener.open()
        sender = AsyncUdpNetworkVariables(
            UdpDefinition.of([mine]), send=["mine"], port=0, to=listener.address
        )
        events: list[NetVarEvent] = []
        sender.add_listener(events.append)
        await sender.open()
        try:
            sender.set("mine", {"x": 77})
            sender.datagram(mine.request().to_bytes())
            assert [type(e) for e in events] == [ListRequested]
            await _until(lambda: listener.statistics()["mine"]["received"] == 1)
            assert listener["mine.x"] == 77 and sender.dropped()["requests"] == 1
        finally:
            sender.close()
            listener.close()
        # a broadcast address without broadcast=True: refused, said how to allow it
        wide = AsyncUdpNetworkVariables(UdpDefinition.of([mine]), send=["mine"], port=0)
        failed: list[NetVarEvent] = []
        wide.add_listener(failed.append)
        await wide.open()
        try:
            wide.send("mine")
            (event,) = failed
            assert isinstance(event, ListSendFailed) and "broadcast=True" in event.reason
        finally:
            wide.close()

    asyncio.run(run())


def test_cyclic_and_on_change_together_as_codesys_allows() -> None:
    gvl = """<GVL><Declarations><![CDATA[VAR_GLOBAL
    level : REAL;
END_VAR]]></Declarations>
<NetvarSettings Protocol="UDP">
<ListIdentifier>9</ListIdentifier><Pack>True</Pack><Checksum>False</Checksum>
<Acknowledge>False</Acknowledge><CyclicTransmission>True</CyclicTransmission>
<TransmissionOnChange>True</TransmissionOnChange><TransmissionOnEvent>False</TransmissionOnEvent>
<Interval>T#10s</Interval><MinGap>T#1ms</MinGap><EventVariable></EventVariable>
</NetvarSettings></GVL>"""

    async def run() -> None:
        lst = loads_gvl(gvl, name="tank")
        receiver = AsyncUdpNetworkVariables(UdpDefinition.of([lst]), port=0)
        await receiver.open()
        sender = AsyncUdpNetworkVariables(
            UdpDefinition.of([lst]), send=["tank"], port=0, to=receiver.address
        )
        await sender.open()
        try:
            await _until(lambda: receiver.statistics()["tank"]["received"] == 1)  # (the cycle)
            sender["tank.level"] = 2.5  # (a change: sent now, not in 10 s)
            await _until(lambda: receiver["tank.level"] == 2.5)
            assert struct.pack("<f", 2.5) == lst.pack_values({"level": 2.5})
        finally:
            sender.close()
            receiver.close()

    asyncio.run(run())


def test_what_cannot_be_opened_or_defined_says_why() -> None:
    one = _list("a", 1, [("x", "INT")])
    with pytest.raises(ValueError, match="one identifier, 1"):
        AsyncUdpNetworkVariables(UdpDefinition({"a": one, "b": _list("b", 1, [("y", "INT")])}))
    with pytest.raises(KeyError, match="no variable list nope"):
        AsyncUdpNetworkVariables(UdpDefinition.of([one]), send=["nope"])

    async def run() -> None:
        first = AsyncUdpNetworkVariables(UdpDefinition.of([one]), port=0)
        await first.open()
        try:
            taken = AsyncUdpNetworkVariables(UdpDefinition.of([one]), port=first.address[1])
            with pytest.raises(OSError, match=r"cannot listen on 127\.0\.0\.1:"):
                await taken.open()
        finally:
            first.close()

    asyncio.run(run())


def test_requests_in_a_storm_are_one_transmission_and_ports_are_checked() -> None:
    async def run() -> None:
        mine = _list("mine", 3, [("x", "UDINT")], interval=60.0)
        listener = AsyncUdpNetworkVariables(UdpDefinition.of([mine]), port=0)
        await listener.open()
        sender = AsyncUdpNetworkVariables(
            UdpDefinition.of([mine]), send=["mine"], port=0, to=listener.address
        )
        await sender.open()
        try:
            await _until(lambda: listener.statistics()["mine"]["received"] == 1)
            for _ in range(50):
                sender.datagram(mine.request().to_bytes())
            assert sender.statistics()["mine"]["sent"] == 2  # (the cycle's, and one answer)
            assert sender.dropped()["requests"] == 50
            # its own list heard back (a broadcast) is counted, not taken
            sender.datagram(_telegrams(mine, {"x": 1}, 0)[0])
            assert sender.dropped()["of_own_lists"] == 1 and sender["mine.x"] == 0
        finally:
            sender.close()
            listener.close()

    asyncio.run(run())
    with pytest.raises(ValueError, match=r"port 70000: a UDP port is 0\.\.65535"):
        AsyncUdpNetworkVariables(UdpDefinition.of([_list("a", 1, [("x", "INT")])]), port=70000)
    from cobus.blocks.netvars import AsyncNetworkVariables

    with pytest.raises(TypeError, match="use AsyncUdpNetworkVariables"):
        AsyncNetworkVariables(None, UdpDefinition.of([_list("a", 1, [("x", "INT")])]), me="x")


def test_a_port_shared_with_another_program_on_this_host() -> None:
    async def run() -> None:
        one = _list("a", 1, [("x", "INT")])
        first = AsyncUdpNetworkVariables(UdpDefinition.of([one]), port=0, share_port=True)
        await first.open()
        second = AsyncUdpNetworkVariables(
            UdpDefinition.of([one]), port=first.address[1], share_port=True
        )
        try:
            await second.open()  # (both listen: a CODESYS runtime and cobus)
            assert second.address == first.address
        finally:
            second.close()
            first.close()

    asyncio.run(run())


def test_a_sender_that_starts_again_is_heard_after_the_late_window() -> None:
    async def run() -> None:
        small = _list("small", 2, [("x", "DINT")], interval=10.0)
        lists = AsyncUdpNetworkVariables(UdpDefinition.of([small]), port=0)
        await lists.open()
        try:
            for counter in (5, 6, 7):
                lists.datagram(_telegrams(small, {"x": counter}, counter)[0])
            lists.datagram(_telegrams(small, {"x": -1}, 6)[0])  # (a repeat: dropped)
            assert lists["small.x"] == 7 and lists.statistics()["small"]["late"] == 1
            await asyncio.sleep(0.3)  # (past the late window: a sender that started again)
            lists.datagram(_telegrams(small, {"x": 100}, 0)[0])
            assert lists["small.x"] == 100
            # a partial set left behind long ago does not make new telegrams late
            big = _list("big", 5, BIG, interval=10.0)
            other = AsyncUdpNetworkVariables(UdpDefinition.of([big]), port=0)
            await other.open()
            try:
                values = {f"s{i}": "x" for i in range(5)} | {"last": 1}
                other.datagram(_telegrams(big, values, 5)[0])
                await asyncio.sleep(0.15)  # (beyond the set window of 0.1 s)
                for data in _telegrams(big, values | {"last": 2}, 3):
                    other.datagram(data)
                assert other["big.last"] == 2 and other.statistics()["big"]["late"] == 0
            finally:
                other.close()
        finally:
            lists.close()

    asyncio.run(run())


def test_a_dual_stack_bind_sends_to_an_ipv4_name() -> None:
    import socket

    try:
        with socket.socket(socket.AF_INET6, socket.SOCK_DGRAM) as probe:
            probe.bind(("::", 0))
    except OSError:
        pytest.skip("no IPv6 on this host")
    one = _list("a", 1, [("x", "INT")], interval=10.0)

    async def run() -> None:
        receiver = AsyncUdpNetworkVariables(UdpDefinition.of([one]), port=0)
        await receiver.open()
        to = ("localhost", receiver.address[1])  # (a name with IPv4 addresses only)
        sender = AsyncUdpNetworkVariables(
            UdpDefinition.of([one]), send=["a"], bind="::", port=0, to=to
        )
        failed: list[NetVarEvent] = []
        sender.add_listener(failed.append)
        sender.set("a", {"x": 5})
        try:
            await sender.open()
            await _until(lambda: receiver["a.x"] == 5)
            assert not failed
        finally:
            sender.close()
            receiver.close()

    asyncio.run(run())
