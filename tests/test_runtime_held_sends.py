"""A blocking caller sends after letting go of the protocol lock where its own frames wake
its reader (python-can's ``udp_multicast``, issue 20): the frames nobody here hears are kept
while its step runs and go out once the lock is free; a refused one goes to the backlog as
:meth:`AsyncNetwork.send` would have put it there; a frame heard here keeps the order."""

from __future__ import annotations

import random
import time

import can
import pytest

from cobus.device import add_device, minimal_od
from cobus.proto import Frame
from cobus.runtime import Network, RealTimeLoop
from cobus.runtime.events import TxQueueFull, TxResumed
from tests.test_runtime_fd_read import _multicast_or_skip


def _record_sends(
    net: Network, monkeypatch: pytest.MonkeyPatch, refuse: set[int] | None = None
) -> list[tuple[int, bool]]:
    """Each message the bus of ``net`` is given, refused or not: (identifier, whether the
    sending thread held the protocol lock); the identifiers in ``refuse`` are refused once."""
    bus = net.aio.bus
    loop = net.aio.loop
    assert isinstance(loop, RealTimeLoop)
    send = bus.send
    sent: list[tuple[int, bool]] = []
    left = set(refuse or ())

    def recording(msg: can.Message, timeout: float | None = None) -> None:
        sent.append((msg.arbitration_id, loop.lock_held()))
        if msg.arbitration_id in left:
            left.discard(msg.arbitration_id)
            raise can.CanOperationError("transmit buffer full (test)")
        send(msg, timeout)

    monkeypatch.setattr(bus, "send", recording)
    return sent


def _multicast_pair() -> tuple[Network, Network]:
    from can.interfaces.udp_multicast import UdpMulticastBus

    group = UdpMulticastBus.DEFAULT_GROUP_IPv6
    port = random.randrange(20000, 60000)
    _multicast_or_skip(group, port)
    master = Network(interface="udp_multicast", channel=group, port=port)
    field = Network(interface="udp_multicast", channel=group, port=port)
    return master, field


def test_over_udp_multicast_the_request_goes_out_after_the_lock(monkeypatch):
    master, field = _multicast_pair()
    with master, field:
        add_device(field, 5, minimal_od())
        sent = _record_sends(master, monkeypatch)
        sdo = master.add_remote(5, sdo_timeout=2.0).sdo
        assert sdo.upload(0x1000) == (0x191).to_bytes(4, "little")
        sdo.download(0x1017, 0, (250).to_bytes(2, "little"))
        assert [s for s in sent if s[0] == 0x605] == [(0x605, False), (0x605, False)]
        assert master.aio._held is None  # nothing is kept after the step
        assert master.aio.frames_sent == 2


def test_a_refused_request_goes_to_the_backlog_and_the_transfer_still_ends(monkeypatch):
    master, field = _multicast_pair()
    with master, field:
        add_device(field, 5, minimal_od())
        events: list[object] = []
        master.add_listener(events.append)
        sent = _record_sends(master, monkeypatch, refuse={0x605})
        sdo = master.add_remote(5, sdo_timeout=2.0).sdo
        assert sdo.upload(0x1000) == (0x191).to_bytes(4, "little")
        # refused outside the lock, queued under it, sent by the loop's retry
        assert sent == [(0x605, False), (0x605, True)]
        assert any(isinstance(e, TxQueueFull) for e in events)
        deadline = time.monotonic() + 2.0
        while not any(isinstance(e, TxResumed) for e in events) and time.monotonic() < deadline:
            time.sleep(0.01)
        assert any(isinstance(e, TxResumed) for e in events)
        assert master.aio.frames_sent == 1


def test_a_frame_heard_here_goes_out_at_once_after_what_was_kept(monkeypatch):
    """Kept frames go first, then the heard one under the lock, echoed; nothing more is kept
    in that step."""
    with Network(interface="virtual", channel=f"held-{random.random()}") as net:
        aio = net.aio
        loop = aio.loop
        assert isinstance(loop, RealTimeLoop)
        sent = _record_sends(net, monkeypatch)
        heard: list[Frame] = []
        net.subscribe(0x202, lambda frame, now: heard.append(frame))
        aio._sends_after_lock = True  # what udp_multicast sets (here: a virtual bus)
        with loop.protocol_lock:
            aio._hold_sends()
            aio.send(Frame(0x201, b"\x01"))  # nobody here hears it: kept
            assert sent == []
            aio.send(Frame(0x202, b"\x02"))  # heard here: 201h first, then 202h, now
            aio.send(Frame(0x203, b"\x03"))  # nothing is kept any more
            assert aio._take_held() == []
        loop.wake_if_pending()
        assert sent == [(0x201, True), (0x202, True), (0x203, True)]
        assert aio.frames_sent == 3
        deadline = time.monotonic() + 2.0
        while not heard and time.monotonic() < deadline:
            time.sleep(0.01)
        assert heard == [Frame(0x202, b"\x02")]


def test_other_buses_send_under_the_lock(monkeypatch):
    """Where the bus does not wake this side's reader for its own frames, nothing is kept."""
    channel = f"held-{random.random()}"
    with (
        Network(interface="virtual", channel=channel) as master,
        Network(interface="virtual", channel=channel) as field,
    ):
        add_device(field, 5, minimal_od())
        sent = _record_sends(master, monkeypatch)
        assert master.add_remote(5, sdo_timeout=2.0).sdo.upload(0x1000)
        assert sent == [(0x605, True)]
