"""Helpers shared by the SDO tests (and a check of the helpers themselves)."""

from __future__ import annotations

from collections import deque
from collections.abc import Callable

from cobus.proto import Event, Frame, Out
from cobus.proto.sdo import DictBackend, SdoClient, SdoServer

NODE = 5
RX = 0x600 + NODE  # the server receives here, the client sends here
TX = 0x580 + NODE


def f(text: str) -> Frame:
    """A frame from trace notation, e.g. ``f("605 40 00 10 00 00 00 00 00")``."""
    return Frame.parse(text)


def c2s(*data: int) -> Frame:
    """A client-to-server frame of the default channel with ``data`` padded to 8 bytes."""
    return Frame(RX, bytes(data) + bytes(8 - len(data)))


def s2c(*data: int) -> Frame:
    """A server-to-client frame of the default channel with ``data`` padded to 8 bytes."""
    return Frame(TX, bytes(data) + bytes(8 - len(data)))


def abort_frame(cob_id: int, index: int, subindex: int, code: int) -> Frame:
    return Frame(
        cob_id,
        bytes((0x80, index & 0xFF, index >> 8, subindex)) + code.to_bytes(4, "little"),
    )


def running(machine: SdoClient | SdoServer) -> bool:
    """``machine.busy``, through a call so that mypy does not narrow it across inputs."""
    return machine.busy


def make_server(entries: dict[tuple[int, int], bytes] | None = None, **kwargs: object) -> SdoServer:
    backend = DictBackend(entries if entries is not None else {})
    return SdoServer(RX, TX, backend, **kwargs)  # type: ignore[arg-type]


def pair(
    client: SdoClient,
    server: SdoServer,
    out: Out,
    now: float = 0.0,
    *,
    drop: Callable[[Frame, int, int], bool] | None = None,
) -> list[Event]:
    """Run a client and a server against each other from the client's first ``out``.

    Frames are delivered in order; ``drop(frame, position, batch_size)`` may lose a frame the
    server sends or the client sends (position within the batch it was sent in). Returns all
    events of both sides in the order they happened.
    """
    events: list[Event] = list(out.events)
    queue: deque[tuple[bool, Frame, int, int]] = deque()

    def post(to_server: bool, frames: tuple[Frame, ...]) -> None:
        for i, frame in enumerate(frames):
            queue.append((to_server, frame, i, len(frames)))

    post(True, out.frames)
    steps = 0
    while queue:
        steps += 1
        assert steps < 1_000_000, "client and server do not stop talking"
        to_server, frame, position, size = queue.popleft()
        if drop is not None and drop(frame, position, size):
            continue
        answer = server.on_frame(frame, now) if to_server else client.on_frame(frame, now)
        events.extend(answer.events)
        post(not to_server, answer.frames)
    return events


def test_pair_runs_an_expedited_read() -> None:
    server = make_server({(0x1000, 0): b"\x91\x01\x00\x00"})
    client = SdoClient(RX, TX)
    events = pair(client, server, client.start_upload(0x1000, 0, 0.0))
    assert len(events) == 2
    assert not client.busy and not server.busy


def test_frame_builders() -> None:
    assert c2s(0x40, 0x00, 0x10) == f("605 [8] 40 00 10 00 00 00 00 00")
    assert s2c(0x60) == f("585 [8] 60 00 00 00 00 00 00 00")
    assert abort_frame(TX, 0x2000, 1, 0x06020000) == f("585 [8] 80 00 20 01 00 00 02 06")
