"""``cobus monitor`` behind a full bus: it drops frames and counts them instead of letting a
queue grow (issue 45)."""

from __future__ import annotations

import json
import threading
import time
import uuid
from typing import Any

import can
import pytest

from cobus.cli import main
from cobus.trace.monitor import BusReader


def _wait(condition: object, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():  # type: ignore[operator]
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.01)


def test_a_reader_with_no_room_left_drops_and_counts() -> None:
    channel = f"drops-{uuid.uuid4()}"
    notes: list[str] = []
    with BusReader({"interface": "virtual", "channel": channel}, notes.append, room=100) as reader:
        with can.Bus(interface="virtual", channel=channel) as sender:
            for n in range(1_000):
                sender.send(can.Message(arbitration_id=0x80, data=[n & 0xFF], is_extended_id=False))
            sender.send(can.Message(arbitration_id=0x80, is_error_frame=True))
            sender.send(can.Message(arbitration_id=0x181, data=bytes(12), is_fd=True))
            _wait(lambda: reader.received == 1_002)
        assert reader.dropped == 900  # (the first hundred kept, nothing queued beyond)
        items = reader.items()
        kept = [next(items) for _ in range(100)]
        assert [item[0].data[0] for item in kept if item is not None] == list(range(100))
        assert next(items) is None  # (empty: a tick)
    assert notes == [
        "error frame on the bus",
        "frame 181 skipped: not a classic CAN frame",
    ]


def test_an_error_frame_storm_is_a_line_a_second() -> None:
    channel = f"storm-{uuid.uuid4()}"
    notes: list[str] = []
    options: dict[str, Any] = {"interface": "virtual", "channel": channel}
    with BusReader(options, notes.append) as reader, can.Bus(**options) as sender:
        for _ in range(500):
            sender.send(can.Message(arbitration_id=0x80, is_error_frame=True))
        _wait(lambda: reader.received == 500)
    assert notes == ["error frame on the bus", "499 error frames on the bus"]


def test_a_bus_that_cannot_be_opened_is_a_connection_error() -> None:
    with pytest.raises(ConnectionError):
        BusReader({"interface": "nosuchbus", "channel": "x"}, print).open()


def test_the_monitor_says_how_many_it_dropped(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """A monitor whose decoding is too slow for the bus: the JSON's last line and a line on
    stderr say how many frames it dropped; memory holds what the queue holds."""
    import cobus.trace.monitor as monitor

    channel = f"drops-cli-{uuid.uuid4()}"
    original = BusReader.__init__

    def small(self: BusReader, options: dict[str, object], say: object, room: int = 0) -> None:
        original(self, options, say, room=50)

    monkeypatch.setattr(monitor.BusReader, "__init__", small)
    from cobus.trace.decoder import Decoder

    feed = Decoder.feed

    def slow(self: Decoder, frame: object, now: float) -> Any:
        time.sleep(0.002)  # (a decoder far slower than the bus)
        return feed(self, frame, now)  # type: ignore[arg-type]

    monkeypatch.setattr(Decoder, "feed", slow)
    result: list[int] = []
    command = ["monitor", "--duration", "1.5", "--json", "-i", "virtual", "-c", channel]
    thread = threading.Thread(target=lambda: result.append(main(command)))
    thread.start()
    time.sleep(0.5)  # (the monitor opens its bus)
    with can.Bus(interface="virtual", channel=channel) as sender:
        for n in range(2_000):
            sender.send(can.Message(arbitration_id=0x80, data=[n & 0xFF], is_extended_id=False))
    thread.join()
    assert result == [0]
    captured = capsys.readouterr()
    last = json.loads(captured.out.splitlines()[-1])
    assert last["dropped"] > 1_000
    assert f"{last['dropped']:,} frames dropped" in captured.err
