"""The panel's queues (cobus.apps.panel.hub): conflation, numbered events, resync, stalls."""

from __future__ import annotations

import pytest

from cobus.apps.panel.hub import RECENT_EVENTS, Hub


class Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def test_a_new_client_starts_with_a_snapshot_of_everything() -> None:
    hub = Hub(Clock())
    hub.update({"a": 1})
    hub.event("x", text="one")
    client = hub.connect()
    (snapshot,) = client.messages()
    assert snapshot["type"] == "snapshot"
    assert snapshot["state"] == {"a": 1}
    assert snapshot["seq"] == 1
    assert [e["text"] for e in snapshot["events"]] == ["one"]
    assert not client.ready.is_set()


def test_telemetry_is_conflated_to_the_latest_value_per_key() -> None:
    hub = Hub(Clock())
    client = hub.connect()
    client.messages()
    for value in range(1000):
        hub.update({"speed": value, "load": 5})
    assert client.depth == 2  # one entry per key, however often it changed
    delta = client.delta()
    assert delta["values"] == {"speed": 999, "load": 5}
    hub.update({"load": 5})  # unchanged: nothing to send
    assert client.depth == 0 and not client.ready.is_set()


def test_events_are_kept_in_order_with_their_numbers() -> None:
    hub = Hub(Clock())
    client = hub.connect()
    client.messages()
    for n in range(5):
        hub.event("alarm", n=n)
    messages = client.messages()
    assert [m["seq"] for m in messages] == [1, 2, 3, 4, 5]
    assert all(m["type"] == "event" for m in messages)


def test_a_client_that_falls_behind_gets_a_snapshot_instead_of_a_gap() -> None:
    hub = Hub(Clock(), max_events=10)
    client = hub.connect()
    client.messages()
    for n in range(25):
        hub.event("e", n=n)
        hub.update({"k": n})
    assert client.overflows == 1
    (snapshot,) = client.messages()
    assert snapshot["type"] == "snapshot" and snapshot["seq"] == 25
    assert snapshot["state"]["k"] == 24
    hub.event("e", n=25)
    assert [m["seq"] for m in client.messages()] == [26]


def test_replies_go_before_events_and_survive_a_snapshot() -> None:
    hub = Hub(Clock())
    client = hub.connect()
    hub.event("e")
    client.reply({"type": "ack", "id": 1})
    messages = client.messages()
    assert [m["type"] for m in messages] == ["ack", "snapshot"]


def test_a_client_whose_send_hangs_is_dropped_and_the_others_stay() -> None:
    clock = Clock()
    hub = Hub(clock, stall=2.0)
    stuck, fine = hub.connect(), hub.connect()
    stuck.sending_since = 0.0
    clock.now = 1.9
    assert hub.check() == []
    clock.now = 2.0
    assert hub.check() == [stuck]
    assert stuck.closed.startswith("stalled") and stuck.ready.is_set()
    assert hub.clients == {fine} and hub.dropped == 1
    hub.event("after")  # the dropped client is no longer fed
    assert not stuck.events


def test_plotted_keys_keep_a_series_and_snapshots_carry_it() -> None:
    clock = Clock()
    hub = Hub(clock)
    hub.plot("bus_load")
    for t in range(3):
        clock.now = float(t)
        hub.update({"bus_load": 10.0 + t, "other": t})
    hub.update({"bus_load": float("nan")})
    assert hub.snapshot()["series"] == {"bus_load": [[0.0, 10.0], [1.0, 11.0], [2.0, 12.0]]}


def test_recent_events_are_bounded() -> None:
    hub = Hub(Clock())
    for n in range(RECENT_EVENTS + 50):
        hub.event("e", n=n)
    events = hub.snapshot()["events"]
    assert len(events) == RECENT_EVENTS and events[-1]["seq"] == RECENT_EVENTS + 50


@pytest.mark.parametrize(
    ("options", "text"), [({"max_events": 0}, "max_events"), ({"stall": 0}, "stall")]
)
def test_bad_limits_are_refused(options: dict[str, float], text: str) -> None:
    with pytest.raises(ValueError, match=text):
        Hub(Clock(), **options)  # type: ignore[arg-type]


def test_values_json_cannot_carry_become_null() -> None:
    hub = Hub(Clock())
    hub.update({"x": float("nan"), "y": {"a": [1.0, float("inf")]}})
    assert hub.state == {"x": None, "y": {"a": [1.0, None]}}
    client = hub.connect()
    client.messages()
    assert hub.update({"x": float("nan")}) == {}  # not sent again every tick
