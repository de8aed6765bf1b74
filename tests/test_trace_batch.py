"""The batch decoder gives the frame-by-frame decoder's records, byte for byte (issue 45):
on a simulated session (segmented and block SDO, a PDO remapped mid-trace, EMCY, NMT,
guarding, LSS) and on random traces that mix every kind of frame in hostile orders."""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import random
import struct
from pathlib import Path
from typing import Any

import can
import numpy as np
import pytest

from cobus.device import DictionaryBuilder, export_eds
from cobus.master import load_network
from cobus.od import DataType, loads
from cobus.runtime import AsyncNetwork
from cobus.runtime.bus import message_to_frame
from cobus.sim.drive402 import SimulatedDrive402 as Servo
from cobus.trace import Decoder
from cobus.trace.batch import BatchDecoder
from cobus.trace.blocks import message_blocks

from .util import simulate

LINE = Path(__file__).parent.parent / "examples/networks/line.yml"


def _servo_od() -> Any:
    async def export() -> str:
        async with AsyncNetwork() as net:
            return export_eds(Servo(net, 10).od)

    od = loads(simulate(export()))
    od.node_id = 10
    return od


def _odd_eds() -> str:
    """Node 5: values of every shape a PDO can carry (REAL32, REAL64, BOOLEAN, INTEGER24,
    a VISIBLE_STRING), which the random traces map into its TPDO1 by SDO."""
    b = DictionaryBuilder(device_type=0, device_name="odd", tpdos=1)
    for index, name, data_type in (
        (0x2001, "ratio", DataType.REAL32),
        (0x2002, "ready", DataType.BOOLEAN),
        (0x2003, "count", DataType.INTEGER24),
        (0x2004, "tag", DataType.VISIBLE_STRING),
        (0x2005, "precise", DataType.REAL64),
    ):
        default = "ab" if data_type == DataType.VISIBLE_STRING else None
        b.variable(index, name, data_type, access="ro", mappable=True, default=default)
    return export_eds(b.od)


def _dictionaries() -> dict[int, Any]:
    odd = loads(_odd_eds())
    odd.node_id = 5
    return {10: _servo_od(), 5: odd}


def _decoders() -> tuple[Decoder, Decoder]:
    network = load_network(LINE)
    return (
        Decoder(_dictionaries(), network=network),
        Decoder(_dictionaries(), network=network),
    )


def _frame_by_frame(decoder: Decoder, messages: list[can.Message]) -> list[Any]:
    """What ``cobus decode`` did frame by frame."""
    out: list[Any] = []
    first = messages[0].timestamp
    now = first
    for msg in messages:
        now = msg.timestamp
        frame = message_to_frame(msg)
        if frame is not None:
            out += decoder.feed(frame, now - first)
    return out + decoder.flush(now - first)


def _batched(decoder: Decoder, messages: list[can.Message], size: int) -> list[Any]:
    batch = BatchDecoder(decoder=decoder)
    first = messages[0].timestamp
    out: list[Any] = []
    for block in message_blocks(messages, size):
        out += batch.decode(block, first).records()
    return out + batch.flush(messages[-1].timestamp - first)


def _stats(decoder: Decoder) -> dict[int, Any]:
    return {
        node: (s.summary(), list(s.timeline), list(s.heartbeat_intervals), s._statuswords)
        for node, s in sorted(decoder.stats.items())
    }


def _same(messages: list[can.Message], sizes: tuple[int, ...] = (1, 7, 500, 65_536)) -> None:
    reference, _ = _decoders()
    expected = _frame_by_frame(reference, messages)
    for size in sizes:
        decoder, _ = _decoders()
        got = _batched(decoder, messages, size)
        assert len(got) == len(expected), size
        for a, b in zip(got, expected, strict=True):  # (repr: a NaN equals a NaN)
            assert repr(a) == repr(b), size
        assert _stats(decoder) == _stats(reference), size
        assert {k: (p.node, p.number, p.tpdo) for k, p in decoder._pdos.items()} == {
            k: (p.node, p.number, p.tpdo) for k, p in reference._pdos.items()
        }
        assert decoder._toggle == reference._toggle
        assert decoder._requested == reference._requested
        assert decoder._guard_asked == reference._guard_asked


def _msg(t: float, cob: int, data: bytes = b"", **options: Any) -> can.Message:
    return can.Message(
        timestamp=t,
        arbitration_id=cob,
        data=data,
        is_extended_id=options.pop("is_extended_id", False),
        **options,
    )


def _session() -> list[can.Message]:
    """A master and the simulated servo: boot, segmented and block SDO, a TPDO remapped
    while it runs, SYNC, heartbeats, an emergency, NMT, guarding, LSS."""

    async def main() -> list[can.Message]:
        async with AsyncNetwork() as net:
            servo = Servo(net, 10, name="servo")
            od = loads(export_eds(servo.od))
            out: list[can.Message] = []
            net.subscribe_all(
                lambda f, now: out.append(
                    _msg(now, f.cob_id, f.data, is_remote_frame=f.rtr, dlc=f.dlc)
                    if f.rtr
                    else _msg(now, f.cob_id, f.data)
                )
            )
            servo.start()
            node = net.add_remote(10, od)
            await node.sdo.upload(0x1008, 0)  # segmented
            await node.sdo.upload(0x1021, 0, block=True)  # block, kilobytes
            await node.sdo.download(0x1017, 0, (10).to_bytes(2, "little"))
            net.nmt.send(0x01, 10)
            net.sync.start(0.002)
            await asyncio.sleep(0.2)
            # TPDO1 remapped while it runs: the statusword only
            await node.sdo.download(0x1800, 1, (0x8000018A).to_bytes(4, "little"))
            await node.sdo.download(0x1A00, 0, b"\x00")
            await node.sdo.download(0x1A00, 1, (0x60410010).to_bytes(4, "little"))
            await node.sdo.download(0x1A00, 0, b"\x01")
            await node.sdo.download(0x1800, 1, (0x18A).to_bytes(4, "little"))
            await asyncio.sleep(0.2)
            servo.inject("overcurrent")  # an emergency
            with contextlib.suppress(Exception):
                await node.sdo.download(0x1008, 0, b"x" * 30, block=True)  # aborted
            net.nmt.send(0x80, 0)
            await asyncio.sleep(0.1)
            net.sync.stop()
            return out

    return simulate(main())


def test_a_simulated_session_gives_the_same_records_batched() -> None:
    messages = _session()
    kinds = {r.kind for r in _frame_by_frame(_decoders()[0], messages)}
    assert {"sdo", "pdo", "sync", "hb", "nmt", "emcy"} <= kinds
    _same(messages)


def _random_trace(seed: int, count: int = 3_000) -> list[can.Message]:
    """Frames of every kind in random order: PDOs of an EDS and of a network file (short
    ones too), SYNC with and without counter, heartbeats, boot-ups, guarding requests and
    answers, NMT resets, SDO writes that remap a PDO, statusword reads, EMCY, LSS, remote,
    extended, error and CAN FD frames, junk."""
    rng = random.Random(seed)
    out: list[can.Message] = []
    t = 1_700_000_000.0
    statuswords = [0x0250, 0x0231, 0x0233, 0x0237, 0x0637, 0x0208]

    def sdo(node: int, index: int, sub: int, value: int, size: int = 4) -> list[can.Message]:
        cs = {1: 0x2F, 2: 0x2B, 4: 0x23}[size]
        req = bytes([cs, index & 0xFF, index >> 8, sub]) + value.to_bytes(4, "little")
        return [
            _msg(0, 0x600 + node, req),
            _msg(0, 0x580 + node, bytes([0x60, index & 0xFF, index >> 8, sub, 0, 0, 0, 0])),
        ]

    for _ in range(count):
        t += rng.choice((0.0, 0.0001, 0.001, 0.01, 0.3, 1.5))
        pick = rng.random()
        batch: list[can.Message]
        if pick < 0.25:
            sw = rng.choice(statuswords)
            size = rng.choice((8, 8, 8, 6, 2, 1, 0))
            payload = sw.to_bytes(2, "little") + rng.randbytes(6)
            batch = [_msg(0, rng.choice((0x18A, 0x28A)), payload[:size])]  # (two carry it)
        elif pick < 0.33:
            cob = rng.choice((0x183, 0x203, 0x182, 0x28A, 0x20A, 0x185, 0x185, 0x185))
            payload = rng.randbytes(rng.choice((8, 8, 8, rng.randint(0, 8))))
            if cob == 0x185 and rng.random() < 0.5:  # NaN, infinities, -0.0, a subnormal
                special = rng.choice((math.nan, math.inf, -math.inf, -0.0, 1e-45, 1.5))
                double = rng.random() < 0.5
                payload = struct.pack("<d" if double else "<f", special)
                payload = (payload + rng.randbytes(8))[:8]
            batch = [_msg(0, cob, payload)]
        elif pick < 0.40:
            cob = rng.randrange(0x180, 0x580)
            batch = [_msg(0, cob, rng.randbytes(rng.randint(0, 8)))]
        elif pick < 0.50:
            batch = [_msg(0, 0x080, bytes([rng.randrange(256)]) if rng.random() < 0.5 else b"")]
        elif pick < 0.62:
            node = rng.choice((10, 3, 2, 5))
            state = rng.choice((0x05, 0x7F, 0x04, 0x85, 0xFF, 0x00, rng.randrange(256)))
            batch = [_msg(0, 0x700 + node, bytes([state]))]
        elif pick < 0.66:
            node = rng.choice((10, 5))
            batch = [_msg(0, 0x700 + node, b"", is_remote_frame=True, dlc=1)]
        elif pick < 0.68:
            batch = [
                _msg(
                    0, 0x000, bytes([rng.choice((0x81, 0x82, 0x01, 0x80)), rng.choice((0, 10, 5))])
                )
            ]
        elif pick < 0.72:
            number = rng.choice((0, 1))
            node = rng.choice((10, 3))
            batch = rng.choice(
                (
                    sdo(node, 0x1A00 + number, 0, 0, 1),
                    sdo(node, 0x1A00 + number, 1, 0x60410010),
                    sdo(node, 0x1A00 + number, 2, 0x60640020),
                    sdo(node, 0x1A00 + number, 1, 0x60610008),
                    sdo(node, 0x1A00 + number, 0, rng.choice((1, 2)), 1),
                    sdo(node, 0x1800 + number, 1, 0x180 + 0x100 * number + node),
                    sdo(node, 0x1800 + number, 1, 0x80000000 | (0x180 + node)),
                    sdo(node, 0x1800 + number, 1, rng.choice((0x58B, 0x60B))),  # (SDO's)
                    sdo(node, 0x1800 + number, 5, 100, 2),  # (event timer: no new mapping)
                    sdo(node, 0x1017, 0, 100, 2),
                )
            )
        elif pick < 0.73:  # node 5's TPDO1 mapped to values of other shapes
            mapped = rng.choice(
                (
                    (0x20010020, 0x20020008),
                    (0x20030018, 0x20040010),
                    (0x20050040,),
                    (0x20010020, 0x20040080),  # (a 16-character string: past any frame)
                )
            )
            batch = sdo(5, 0x1A00, 0, 0, 1)
            for sub, entry in enumerate(mapped, 1):
                batch += sdo(5, 0x1A00, sub, entry)
            batch += sdo(5, 0x1A00, 0, len(mapped), 1)
        elif pick < 0.75:
            sw = rng.choice(statuswords)
            batch = [
                _msg(0, 0x60A, bytes([0x40, 0x41, 0x60, 0, 0, 0, 0, 0])),
                _msg(0, 0x58A, bytes([0x4B, 0x41, 0x60, 0]) + sw.to_bytes(4, "little")),
            ]
        elif pick < 0.78:
            batch = [_msg(0, 0x08A, bytes([0x10, 0x73, 0x01, 0, 0, 0, 0, 0]))]
        elif pick < 0.80:
            batch = [_msg(0, rng.choice((0x7E4, 0x7E5)), rng.randbytes(8))]
        elif pick < 0.83:
            batch = [_msg(0, rng.randrange(0x800), b"", is_remote_frame=True, dlc=rng.randrange(9))]
        elif pick < 0.86:
            batch = [
                _msg(
                    0, rng.randrange(1 << 29), rng.randbytes(rng.randint(0, 8)), is_extended_id=True
                )
            ]
        elif pick < 0.88:
            batch = [_msg(0, 0x20000080, b"", is_error_frame=True, is_extended_id=True)]
        elif pick < 0.89:
            batch = [_msg(0, 0x18A, rng.randbytes(12), is_fd=True)]
        elif pick < 0.90:  # (a classic frame of 12 bytes, as a .csv of an FD bus has them)
            batch = [_msg(0, rng.choice((0x18A, 0x080, 0x60B)), rng.randbytes(12))]
        elif pick < 0.91:  # (on an SDO COB-ID a PDO may have been moved to)
            batch = [_msg(0, rng.choice((0x58B, 0x60B)), rng.randbytes(8))]
        else:
            batch = [_msg(0, rng.randrange(0x800), rng.randbytes(rng.randint(0, 8)))]
        for msg in batch:
            msg.timestamp = t
            out.append(msg)
            t += rng.choice((0.0, 0.0002))
    return out


@pytest.mark.parametrize("seed", range(4))
def test_random_traces_give_the_same_records_batched(seed: int) -> None:
    _same(_random_trace(seed))


def test_the_tables_hold_typed_columns() -> None:
    """The bulk as columns: a PDO's values typed as its mapping says, SYNC counters,
    heartbeat states."""
    messages = [
        _msg(10.0, 0x18A, bytes([0x37, 0x06, 0x10, 0x27, 0, 0, 0xFF, 0xFF])),
        _msg(10.001, 0x080, b"\x05"),
        _msg(10.002, 0x080, b""),
        _msg(10.003, 0x70A, b"\x05"),
        _msg(10.004, 0x18A, bytes([0x37, 0x02])),  # short: the statusword only
    ]
    decoder, _ = _decoders()
    (block,) = message_blocks(messages)
    decoded = BatchDecoder(decoder=decoder).decode(block, 10.0)
    assert decoded.sync_counter.tolist() == [5, -1]
    assert decoded.heartbeat_node.tolist() == [10] and decoded.heartbeat_state.tolist() == [5]
    (table,) = decoded.pdos
    assert table.index.tolist() == [0, 4] and table.present is not None
    assert table.present.tolist() == [len(table.names), 1]
    statusword = table.columns[table.names[0]]
    assert isinstance(statusword, np.ndarray) and statusword.tolist()[:2] == [0x0637, 0x0237]
    assert decoder.stats[10].drive_state is not None


def _reference_lines(messages: list[can.Message], options: list[str], network: Any) -> list[str]:
    """What ``cobus decode`` printed frame by frame before it decoded in blocks."""
    from cobus.trace._cli import _plain

    as_json = "--json" in options
    kinds = (
        set(options[options.index("--filter") + 1].split(",")) if "--filter" in options else None
    )
    node = int(options[options.index("--node") + 1]) if "--node" in options else None
    decoder = Decoder(_dictionaries(), network=network)
    first = messages[0].timestamp
    out: list[str] = []

    def emit(rec: Any) -> None:
        if kinds is not None and rec.kind not in kinds:
            return
        if node is not None and not rec.concerns(node):
            return
        if as_json:
            body = {k: _plain(v) for k, v in vars(rec).items()}
            out.append(json.dumps({"kind": rec.kind, "text": str(rec), **body}))
        else:
            out.append(f"{rec.time:12.6f}  {rec}")

    now = first
    for msg in messages:
        now = msg.timestamp
        if msg.is_error_frame:
            if kinds is None and node is None and not as_json:
                out.append(f"{now - first:12.6f}  error frame")
            continue
        frame = message_to_frame(msg)
        if frame is not None:
            for rec in decoder.feed(frame, now - first):
                emit(rec)
    for rec in decoder.flush(now - first):
        emit(rec)
    return out


@pytest.mark.parametrize("suffix", [".blf", ".log", ".asc"])
def test_cobus_decode_prints_what_it_printed_frame_by_frame(
    suffix: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Text and JSON lines, with and without filters, character for character what the
    frame-by-frame path printed (the bulk formatted from columns, the rest by record)."""
    from cobus.cli import main

    messages = [m for m in _random_trace(7, 3_000) if not m.is_fd] + _session()[:2_000]
    t = messages[0].timestamp
    for msg in messages:  # (one clock for both parts; .log keeps microseconds)
        msg.timestamp = t = max(t, round(msg.timestamp, 6))
    path = tmp_path / f"trace{suffix}"
    with can.Logger(str(path)) as logger:
        for msg in messages:
            logger(msg)
    read = list(can.LogReader(str(path)))
    network = load_network(LINE)
    eds = tmp_path / "servo.eds"
    eds.write_text(export_eds(_servo_od()))
    odd = tmp_path / "odd.eds"
    odd.write_text(_odd_eds())
    for options in (
        [],
        ["--json"],
        ["--filter", "pdo,hb,sync"],
        ["--node", "10", "--json"],
        ["--filter", "sdo,emcy,nmt"],
    ):
        capsys.readouterr()
        args = ["decode", str(path), "--eds", f"10={eds}", "--eds", f"5={odd}"]
        args += ["--network", str(LINE), *options]
        assert main(args) == 0
        got = capsys.readouterr().out.splitlines()
        expected = _reference_lines(read, options, network)
        assert len(got) == len(expected), options
        for a, b in zip(got, expected, strict=True):
            assert a == b, options
