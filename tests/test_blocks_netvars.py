"""CAN network variables: the definition file (every problem with file, line and key), the
packing, and two controllers — two networks on one virtual bus, simulated clock — exchanging
three lists cyclically, on change and on event, with frame loss injected."""

from __future__ import annotations

import asyncio
import textwrap
from itertools import count
from typing import Any

import can
import pytest

from cobus.blocks.netvar_lists import NetVarConfigError, loads_netvars
from cobus.blocks.netvars import (
    AsyncNetworkVariables,
    ListIncomplete,
    ListReceived,
    ListRequested,
    ListStale,
    NetVarEvent,
    NetworkVariables,
)
from cobus.od import DataType
from cobus.proto import Frame
from cobus.runtime import AsyncNetwork, Network, NetworkClosedError, TxOverflowError
from cobus.sim.faults import FaultyBus

from .util import simulate

PLANT = """
controllers: [plc1, plc2]
lists:
  status:
    id: 0x300
    sender: plc1
    transmit: cyclic
    interval: 10 ms
    variables:
      cycle: UNSIGNED32
      speed: REAL32
      running: BOOLEAN
      temps: {array: INTEGER16, length: 4}
      motor: {struct: {current: REAL32, voltage: UNSIGNED16}}
      label: {string: 6}
  alarms:
    id: 0x310
    sender: plc2
    transmit: on_change
    min_gap: 50 ms
    request_at_boot: true
    variables: {code: UNSIGNED16, active: BOOLEAN}
  recipe:
    id: 0x320
    sender: plc1
    transmit: on_event
    event: send
    frames: 4
    variables: {send: BOOLEAN, number: UNSIGNED32, setpoint: REAL64, name: {string: 5}}
"""
_ids = count()


def definition() -> Any:
    return loads_netvars(textwrap.dedent(PLANT), path="plant.yml")


def test_lists_are_flattened_packed_and_split_into_frames() -> None:
    plant = definition()
    status = plant["status"]
    assert [v.name for v in status.variables] == [
        "cycle",
        "speed",
        "running",
        "temps[0]",
        "temps[1]",
        "temps[2]",
        "temps[3]",
        "motor.current",
        "motor.voltage",
        "label",
    ]
    assert status.size == 4 + 4 + 1 + 8 + 4 + 2 + 6 == 29
    assert status.frames == 5 and list(status.cob_ids) == [0x300, 0x301, 0x302, 0x303, 0x304]
    values = {v.name: v.zero for v in status.variables} | {"cycle": 7, "label": "pump"}
    payload = status.pack(values)
    frames = status.split(payload, counter=9)
    assert [len(f) for f in frames] == [8, 8, 8, 8, 2]
    assert all(f[0] == 9 for f in frames) and frames[0][1:5] == b"\x07\0\0\0"
    assert status.unpack(payload)["label"] == "pump"
    alarms = plant["alarms"]
    assert alarms.frames == 1 and alarms.split(b"\x01\x00\x01", 3) == [b"\x01\x00\x01"]
    assert plant["recipe"].reserved == 4 and plant["recipe"].frames == 3
    assert plant["recipe"].variable("setpoint").data_type is DataType.REAL64
    with pytest.raises(KeyError, match="has no variable 'speed'; it has: code, active"):
        alarms.variable("speed")


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        (
            "lists:\n  a: {id: 0x300, sender: x, interval: 10, variables: {v: u32, w: u32, "
            "x: u8}}\n"
            "  b:\n    sender: x\n    interval: 10\n    variables: {v: u8}\n    id: 0x301\n",
            "net.yml:7: lists.b.id: COB-IDs 301h.. overlap list 'a' (300h..301h)",
        ),
        (
            "lists:\n  a:\n    id: 0x300\n    sender: x\n    interval: 10\n    frames: 1\n"
            "    variables: {v: REAL64, w: u8}\n",
            "net.yml:6: lists.a.frames: the variables take 9 bytes, 2 frames; 1 frame(s) carry 8",
        ),
        (
            "lists:\n  a: {id: 0x300, sender: x, interval: 10, variables: {v: {string: 112}, "
            "w: {string: 10}}}\n",
            "a list carries at most 112 bytes (16 frames): split it",
        ),
        (
            "lists:\n  a: {id: 0x701, sender: x, interval: 10, variables: {v: u8}}\n",
            "lists.a.id: COB-ID 701h is reserved by CANopen",
        ),
        (
            "lists:\n  a: {id: 0x80, sender: x, interval: 10, variables: {v: u8}}\n",
            "lists.a.id: COB-ID 080h is reserved by CANopen",
        ),
        (
            "lists:\n  a: {id: 0x300, sender: x, interval: 10, min_gap: 5, variables: {v: u8}}\n",
            "lists.a.min_gap: only an on_change list has one",
        ),
        (
            "lists:\n  a: {id: 0x300, sender: x, interval: 0.1, variables: {v: u8}}\n",
            "lists.a.interval: at least 1 ms",
        ),
        (
            "lists:\n  a: {id: 0x300, sender: x, interval: 10, variables: {v: u17}}\n",
            "net.yml:2: lists.a.variables.v: type 'u17' is not a CiA 301 type of fixed size",
        ),
        (
            "lists:\n  a: {id: 0x300, sender: x, variables: {v: u8}}\n",
            "lists.a.interval: a cyclic list needs an interval above 0",
        ),
        (
            "lists:\n  a: {id: 0x300, sender: x, transmit: on_event, event: v, "
            "variables: {v: u8}}\n",
            "lists.a.event: 'v' is no BOOLEAN",
        ),
        (
            "controllers: [plc1]\nlists:\n  a: {id: 0x300, sender: plc9, interval: 10, "
            "variables: {v: u8}}\n",
            "lists.a.sender: 'plc9' is not one of the controllers (plc1)",
        ),
        (
            "lists:\n  a: {id: 0x300, sender: x, interval: 10, variables: {v: u8}, colour: 1}\n",
            "lists.a.colour: unknown key",
        ),
        ("lists: {}\n", "lists: give the variable lists"),
        ("", "the file is empty"),
    ],
)
def test_a_bad_definition_names_file_line_and_key(text: str, expected: str) -> None:
    with pytest.raises(NetVarConfigError) as exc:
        loads_netvars(text, path="net.yml")
    assert expected in str(exc.value)


class Controller:
    def __init__(self, net: AsyncNetwork, me: str) -> None:
        self.lists = AsyncNetworkVariables(net, definition(), me=me)
        self.events: list[NetVarEvent] = []
        self.lists.add_listener(self.events.append)

    def of(self, kind: type, name: str) -> list[Any]:
        return [e for e in self.events if isinstance(e, kind) and e.list == name]


def test_two_controllers_exchange_three_lists_with_frame_loss() -> None:
    channel = f"netvars-{next(_ids)}"

    async def main() -> tuple[Controller, Controller, list[Frame]]:
        bus1 = can.Bus(interface="virtual", channel=channel)
        bus2 = FaultyBus(can.Bus(interface="virtual", channel=channel), loss=0.05, seed=3)
        net1 = await AsyncNetwork(bus1).connect()
        net2 = await AsyncNetwork(bus2).connect()
        wire: list[Frame] = []
        net1.subscribe_all(lambda f, now: wire.append(f))
        plc1, plc2 = Controller(net1, "plc1"), Controller(net2, "plc2")
        loop = asyncio.get_running_loop()

        def tick(n: int) -> None:  # plc1's program: a new, self-consistent value set each ms
            plc1.lists.set(
                "status",
                {
                    "cycle": n,
                    "speed": n / 4,
                    "running": n % 2 == 1,
                    **{f"temps[{k}]": n + k for k in range(4)},
                    "motor.current": n / 8,
                    "motor.voltage": n % 65536,
                    "label": f"n{n % 1000}",
                },
            )
            loop.call_later(0.001, tick, n + 1)

        tick(0)
        plc1.lists.start()
        await asyncio.sleep(0.05)
        plc2.lists["alarms.code"] = 17  # before plc1 listens: plc1 asks for it when it starts
        plc2.lists.start()
        plc2.lists.set("alarms", {"code": 17, "active": True})
        await asyncio.sleep(0.05)
        plc1.lists.close()
        plc1 = Controller(net1, "plc1")  # plc1 restarts: request_at_boot
        plc1.lists.start()
        await asyncio.sleep(0.01)
        assert plc1.lists["alarms.code"] == 17
        for code in (18, 19, 20):  # three changes within the 50 ms gap: two transmissions
            plc2.lists["alarms.code"] = code
            await asyncio.sleep(0.005)
        await asyncio.sleep(0.1)
        plc1.lists.set("recipe", {"number": 42, "setpoint": 1.25, "name": "bread"})
        await asyncio.sleep(0.05)
        assert not plc2.of(ListReceived, "recipe")  # on event only
        plc1.lists["recipe.send"] = True  # rising edge: sent
        plc1.lists["recipe.send"] = True  # no edge
        await asyncio.sleep(0.05)
        plc1.lists["recipe.send"] = False
        plc1.lists["recipe.send"] = True  # another edge
        await asyncio.sleep(2.0)
        await net1.disconnect()
        await net2.disconnect()
        return plc1, plc2, wire

    plc1, plc2, wire = simulate(main())
    # cyclic: every 10 ms a set; each one received is consistent, none mixed of two
    sets = [e.values for e in plc2.of(ListReceived, "status")]
    assert len(sets) > 150
    for values in sets:
        n = values["cycle"]
        if n == 0:  # the restarted plc1's first set, before its program ran: all zero
            assert values["label"] == "" and values["temps[3]"] == 0
            continue
        assert values["speed"] == n / 4 and values["motor.current"] == n / 8
        assert [values[f"temps[{k}]"] for k in range(4)] == [n + k for k in range(4)]
        assert values["label"] == f"n{n % 1000}" and values["running"] == (n % 2 == 1)
    lost = plc2.of(ListIncomplete, "status")
    assert lost and all(e.missing for e in lost)
    assert len(sets) + len(lost) <= 235  # one transmission each 10 ms, about 2.3 s
    assert str(lost[0]).startswith("list status: frame(s) ")
    # on change with a 50 ms gap: 17 at once, then 18..20 folded into one after the gap
    codes = [e.values["code"] for e in plc1.of(ListReceived, "alarms")]
    assert codes[0] == 17 and codes[-1] == 20 and 18 not in codes
    alarm_frames = [(f.data[0]) for f in wire if f.cob_id == 0x310 and not f.rtr]
    assert alarm_frames.count(19) + alarm_frames.count(20) <= 2
    assert any(f.cob_id == 0x310 and f.rtr for f in wire)  # plc1's request at boot
    assert plc2.of(ListRequested, "alarms")
    # on event: twice, for the two rising edges
    recipes = plc2.of(ListReceived, "recipe")
    assert len(recipes) == 2 and recipes[0].values["name"] == "bread"
    assert recipes[0].values["setpoint"] == 1.25
    assert plc1.lists.statistics()["recipe"] == {"sent": 2, "failed": 0}
    stale = plc2.of(ListStale, "status")
    assert stale and stale[0].silence == pytest.approx(0.03)  # plc1 stopped at the end


def test_a_reader_cannot_write_and_values_are_checked() -> None:
    async def main() -> None:
        async with AsyncNetwork() as net:
            plc2 = AsyncNetworkVariables(net, definition(), me="plc2")
            with pytest.raises(PermissionError, match="'status' is written by 'plc1'"):
                plc2["status.cycle"] = 1
            with pytest.raises(ValueError):
                plc2["alarms.code"] = 70000
            with pytest.raises(ValueError, match="longer than 6 characters"):
                AsyncNetworkVariables(net, definition(), me="plc1")["status.label"] = "toolong"
            with pytest.raises(KeyError, match=r"name a variable as LIST\.VARIABLE"):
                plc2["code"]
            with pytest.raises(ValueError, match="'plc3' is not in the definition"):
                AsyncNetworkVariables(net, definition(), me="plc3")

    simulate(main())


def test_the_blocking_face() -> None:
    with Network(simulated=True) as net:
        plc1 = NetworkVariables(net, definition(), me="plc1")
        plc2 = NetworkVariables(net, definition(), me="plc2")
        plc2.start()
        plc1.start()
        plc1.set("recipe", {"number": 7, "send": True})
        net.sleep(0.1)
        assert plc2["recipe.number"] == 7 and plc2.age("recipe") == pytest.approx(0.1)
        assert plc2.values("recipe")["send"] is True
        plc1.close()
        plc2.close()


LINE = """
lists:
  wide:
    id: 0x680
    sender: plc1
    transmit: on_event
    variables: {a: UNSIGNED32, b: UNSIGNED32, c: UNSIGNED32, d: UNSIGNED32}
  small:
    id: 0x690
    sender: plc1
    transmit: on_change
    frames: 2
    variables: {x: UNSIGNED8, go: BOOLEAN}
"""


def test_a_reader_never_mixes_frames_of_two_transmissions() -> None:
    async def main() -> tuple[list[Any], list[Any], dict[str, Any]]:
        async with AsyncNetwork() as net:
            plant = loads_netvars(LINE)
            reader = AsyncNetworkVariables(net, plant, me="plc2")
            events: list[NetVarEvent] = []
            reader.add_listener(events.append)
            reader.start()
            wide = plant["wide"]

            def frames(counter: int, value: int) -> list[Frame]:
                payload = wide.pack({"a": value, "b": value, "c": value, "d": value})
                return [Frame(0x680 + k, d) for k, d in enumerate(wide.split(payload, counter))]

            old, new = frames(0, 5), frames(0, 6)  # the same counter: a writer restarted
            net.send(old[1])
            await asyncio.sleep(3600)
            net.send(new[0])
            net.send(new[1])  # no frame 2: not complete
            net.send(new[1])  # a duplicate: ignored
            await asyncio.sleep(0.01)
            for frame in frames(1, 7):
                net.send(frame)
            net.send(frames(1, 7)[2])  # the last frame again: nothing new
            await asyncio.sleep(0.01)
            received = [e.values for e in events if isinstance(e, ListReceived)]
            lost = [e for e in events if isinstance(e, ListIncomplete)]
            return received, lost, reader.statistics()["wide"]

    received, lost, stats = simulate(main())
    assert received == [{"a": 7, "b": 7, "c": 7, "d": 7}]  # never 5 and 6 mixed
    assert [(e.counter, e.missing) for e in lost] == [(0, (0, 2)), (0, (2,))]
    assert stats == {"received": 1, "incomplete": 2, "malformed": 0}


def test_a_reader_that_starts_first_gets_the_list_and_edges_are_truthy() -> None:
    async def main() -> tuple[Any, Any, list[str], int]:
        async with AsyncNetwork() as net:
            plant = loads_netvars(LINE)
            reader = AsyncNetworkVariables(net, plant, me="plc2")
            reader.start()  # first: nothing to read yet
            await asyncio.sleep(1)
            writer = AsyncNetworkVariables(net, plant, me="plc1")
            writer["small.x"] = 9
            writer.start()  # an on_change list goes out once at the start
            await asyncio.sleep(0.01)
            small = reader.values("small")
            with pytest.raises(NetworkClosedError, match="start"):
                AsyncNetworkVariables(net, plant, me="plc1").send("wide")
            writer["wide.a"] = 1
            sent = writer.statistics()["wide"]["sent"]
            failures: list[str] = []
            writer.add_listener(lambda e: failures.append(str(e)) if "not sent" in str(e) else 0)
            real_send = net.send

            def refuse(frame: Frame) -> None:
                raise TxOverflowError("the backlog is full")

            net.send = refuse  # type: ignore[method-assign]
            writer.send("wide")
            net.send = real_send  # type: ignore[method-assign]
            writer.close()
            with pytest.raises(NetworkClosedError, match="closed"):
                writer["small.x"] = 1
            return small, writer.values("small"), failures, sent

    small, mine, failures, sent = simulate(main())
    assert small == {"x": 9, "go": False}
    assert mine["x"] == 9 and sent == 0
    assert failures == ["list wide: not sent: the backlog is full"]


def test_a_hostile_definition_is_refused_quickly() -> None:
    nested = "{array: {array: {array: {array: u99, length: 112}, length: 112}, length: 112}, "
    head = "lists:\n  a: {id: 0x300, sender: x, interval: 10, variables: {v: "
    text = f"{head}{nested}length: 112}}}}}}\n"
    with pytest.raises(NetVarConfigError) as exc:
        loads_netvars(text)
    assert len(exc.value.problems) == 1 and "u99" in str(exc.value)
