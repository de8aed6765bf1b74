"""Our SDO client against our SDO server, wired frame to frame, for sizes 0..2000 and every
transfer kind and setting (hypothesis)."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from cobus.proto.sdo import (
    DictBackend,
    DownloadDone,
    SdoAbortCode,
    SdoAbortedError,
    SdoClient,
    SdoServer,
    ServerAborted,
    ServerDownloaded,
    ServerUploaded,
    TransferFailed,
    UploadDone,
)
from tests.test_sdo_helpers import RX, TX, pair

IDX = 0x2000

# Sizes spread over 0..2000 (st.binary alone stays mostly short), contents from a seed.
values = st.builds(
    lambda size, seed: bytes((i * seed + seed // 7) & 0xFF for i in range(size)),
    st.one_of(st.integers(0, 16), st.integers(0, 2000)),
    st.integers(0, 255),
)

setups = st.fixed_dictionaries(
    {
        "client_crc": st.booleans(),
        "server_crc": st.booleans(),
        "client_block_size": st.integers(1, 127),
        "server_block_size": st.integers(1, 127),
        "pst": st.integers(0, 255),
    }
)


def machines(setup: dict[str, int], value: bytes) -> tuple[SdoClient, SdoServer, DictBackend]:
    backend = DictBackend({(IDX, 1): value, (IDX, 2): b""})
    server = SdoServer(
        RX, TX, backend, crc=bool(setup["server_crc"]), block_size=setup["server_block_size"]
    )
    client = SdoClient(
        RX,
        TX,
        crc=bool(setup["client_crc"]),
        block_size=setup["client_block_size"],
        pst=setup["pst"],
    )
    return client, server, backend


@settings(max_examples=150, deadline=None)
@given(value=values, block=st.booleans(), setup=setups)
def test_upload(value: bytes, block: bool, setup: dict[str, int]) -> None:
    client, server, _ = machines(setup, value)
    events = pair(client, server, client.start_upload(IDX, 1, 0.0, block=block))
    assert events == [UploadDone(IDX, 1, value), ServerUploaded(IDX, 1, len(value))] or events == [
        ServerUploaded(IDX, 1, len(value)),
        UploadDone(IDX, 1, value),
    ]
    assert not client.busy and not server.busy
    assert client.deadline is None and server.deadline is None


@settings(max_examples=150, deadline=None)
@given(
    value=values,
    block=st.booleans(),
    size_indicated=st.booleans(),
    expedited=st.booleans(),
    setup=setups,
)
def test_download(
    value: bytes, block: bool, size_indicated: bool, expedited: bool, setup: dict[str, int]
) -> None:
    client, server, backend = machines(setup, b"")
    out = client.start_download(
        IDX, 2, value, 0.0, block=block, size_indicated=size_indicated, expedited=expedited
    )
    events = pair(client, server, out)
    stored = backend.entries[(IDX, 2)]
    if expedited and not block and not size_indicated and 1 <= len(value) <= 4:
        assert stored == value + bytes(4 - len(value))  # 22h: the server sees 4 bytes
    else:
        assert stored == value
    assert set(events) == {DownloadDone(IDX, 2), ServerDownloaded(IDX, 2, len(stored))}
    assert not client.busy and not server.busy


@settings(max_examples=40, deadline=None)
@given(block=st.booleans(), upload=st.booleans(), setup=setups)
def test_refusals_reach_the_client(block: bool, upload: bool, setup: dict[str, int]) -> None:
    client, server, backend = machines(setup, b"x" * 50)
    backend.read_only.add((IDX, 1))
    backend.write_only.add((IDX, 1))
    if upload:
        out = client.start_upload(IDX, 1, 0.0, block=block)
        code = SdoAbortCode.READ_WRITE_ONLY
    else:
        out = client.start_download(IDX, 1, b"y" * 30, 0.0, block=block)
        code = SdoAbortCode.WRITE_READ_ONLY
    events = pair(client, server, out)
    assert ServerAborted(IDX, 1, code, by_peer=False) in events
    (failed,) = [e for e in events if isinstance(e, TransferFailed)]
    assert isinstance(failed.error, SdoAbortedError) and failed.error.code is code


def test_many_transfers_in_a_row_on_one_pair() -> None:
    client, server, backend = machines(
        {
            "client_crc": 1,
            "server_crc": 1,
            "client_block_size": 7,
            "server_block_size": 9,
            "pst": 3,
        },
        b"",
    )
    for n in range(0, 300, 7):
        value = bytes(range(n % 256)) * (n // 256 + 1)
        for block in (False, True):
            pair(client, server, client.start_download(IDX, 2, value, float(n), block=block))
            assert backend.entries[(IDX, 2)] == value
            events = pair(client, server, client.start_upload(IDX, 2, float(n), block=block))
            assert UploadDone(IDX, 2, value) in events


def _watched(
    client: SdoClient, server: SdoServer, out: object
) -> tuple[list[object], list[tuple[int, int | None]]]:
    """pair(), with the client's progress noted before every frame while it is busy."""
    seen: list[tuple[int, int | None]] = []

    def watch(frame: object, position: int, size: int) -> bool:
        if client.busy:
            seen.append(client.progress)
        return False

    return list(pair(client, server, out, drop=watch)), seen  # type: ignore[arg-type]


def test_progress_counts_the_bytes_of_every_kind_of_transfer() -> None:
    """``progress`` (bytes moved, bytes in all) grows frame by frame and is (0, None) when
    idle: what a progress bar draws."""
    from tests.test_sdo_helpers import make_server

    data = bytes(range(256)) * 3  # 768 bytes
    for block in (False, True):
        server = make_server({(IDX, 1): data})
        client = SdoClient(RX, TX)
        assert client.progress == (0, None)
        events, seen = _watched(client, server, client.start_upload(IDX, 1, 0.0, block=block))
        (done,) = [e for e in events if isinstance(e, UploadDone)]
        assert done.data == data
        moved = [n for n, _ in seen]
        assert moved == sorted(moved) and 0 < max(moved) <= len(data)
        assert {total for _, total in seen[2:]} == {len(data)}  # once the size came
        assert client.progress == (0, None)

        out = client.start_download(IDX, 1, data[::-1], 0.0, block=block)
        events, seen = _watched(client, server, out)
        assert any(isinstance(e, DownloadDone) for e in events)
        moved = [n for n, _ in seen]
        assert moved == sorted(moved) and max(moved) >= len(data) - 7 * (127 if block else 1)
        assert {total for _, total in seen} == {len(data)}
        assert client.progress == (0, None)
