"""cobus decode --summary (issue 45): a trace's bus load, periods, jitter, latencies, aborts,
emergencies and time line, checked on generated traces whose figures are known; the frames'
bits on the wire against a bit-by-bit reference; the same summary whatever the block size."""

from __future__ import annotations

import json
import random
import subprocess
import sys
from pathlib import Path
from typing import Any

import can
import numpy as np
import pytest

from cobus.trace.blocks import message_blocks
from cobus.trace.summary import TraceSummary


def _reference_bits(cob: int, ext: bool, rtr: bool, dlc: int, data: bytes) -> int:
    """A classic CAN frame's bits, written out one by one: the stuffed part (start of frame
    to the CRC), a stuff bit after five equal ones, then 13 bits never stuffed."""
    if ext:
        bits = f"0{cob >> 18:011b}11{cob & 0x3FFFF:018b}{int(rtr)}00{dlc:04b}"
    else:
        bits = f"0{cob:011b}{int(rtr)}00{dlc:04b}"
    if not rtr:
        bits += "".join(f"{b:08b}" for b in data[:dlc])
    crc = 0
    for ch in bits:
        top = int(ch) ^ (crc >> 14)
        crc = (crc << 1) & 0x7FFF
        if top:
            crc ^= 0x4599
    bits += f"{crc:015b}"
    stuffed, run, last = 0, 0, ""
    for ch in bits:
        run = run + 1 if ch == last else 1
        last = ch
        if run == 5:
            stuffed += 1
            last, run = ("1" if ch == "0" else "0"), 1
    return len(bits) + stuffed + 13


def _message(t: float, cob: int, data: bytes = b"", **options: Any) -> can.Message:
    return can.Message(timestamp=t, arbitration_id=cob, data=data, is_extended_id=False, **options)


def test_the_bits_of_each_frame_with_its_stuff_bits() -> None:
    from cobus.trace.blocks import frame_bits

    rng = random.Random(45)
    messages = [_message(0.0, 0x000)]  # 34 dominant bits: 6 stuff bits, 53 in all
    for n in range(2000):
        ext = n % 3 == 0
        rtr = n % 7 == 0
        dlc = rng.randrange(9)
        cob = rng.randrange(1 << 29) if ext else rng.randrange(1 << 11)
        data = bytes(rng.choice((0, 0xFF, rng.randrange(256))) for _ in range(dlc))
        messages.append(
            can.Message(
                arbitration_id=cob,
                is_extended_id=ext,
                is_remote_frame=rtr,
                dlc=dlc,
                data=None if rtr else data,
            )
        )
    (block,) = message_blocks(messages)
    got = frame_bits(block).tolist()
    want = [
        _reference_bits(
            m.arbitration_id, m.is_extended_id, m.is_remote_frame, m.dlc, bytes(m.data or b"")
        )
        for m in messages
    ]
    assert got == want
    assert got[0] == 53  # (47 bits, the shortest frame, and 6 stuff bits)
    eight = [
        g
        for g, m in zip(got, messages, strict=True)
        if m.dlc == 8 and not m.is_extended_id and not m.is_remote_frame
    ]
    assert eight and all(111 <= g <= 111 + 24 for g in eight)  # (24 stuff bits at most)


def _trace() -> list[can.Message]:
    """Node 5 boots, beats every 100 ms (+-2 ms), is started, misses one beat and boots
    again; SYNC every 10 ms (+-0.25 ms) with its TPDO1 1.5 ms after; SDO reads answered
    after 1..4 ms, one abort, one left unfinished; an emergency."""
    out = [_message(0.010, 0x705, b"\x00")]
    beat = 0.1
    for k in range(30):
        if k == 12:
            continue  # (a missed beat)
        state = b"\x7f" if k < 5 else b"\x05"
        out.append(_message(beat * (k + 1) + (0.002 if k % 2 else -0.002), 0x705, state))
    out.append(_message(0.55, 0x000, b"\x01\x05"))
    out.append(_message(3.2, 0x705, b"\x00"))  # (a re-boot)
    for k in range(300):
        t = 0.01 * k + (0.00025 if k % 2 else -0.00025)
        out.append(_message(t + 0.001, 0x080))
        out.append(_message(t + 0.0025, 0x185, bytes((k % 256, 0, 0, 0))))
    for k, wait in enumerate((0.001, 0.002, 0.003, 0.004)):
        t = 1.0 + 0.1 * k + 0.0031
        out.append(_message(t, 0x605, bytes((0x40, 0x00, 0x10, 0, 0, 0, 0, 0))))
        out.append(_message(t + wait, 0x585, bytes((0x43, 0x00, 0x10, 0, 0x91, 1, 0, 0))))
    out.append(_message(1.6031, 0x605, bytes((0x40, 0xFF, 0x5F, 0, 0, 0, 0, 0))))
    abort = (0x80, 0xFF, 0x5F, 0, 0, 0, 2, 6)  # 06020000h: object does not exist
    out.append(_message(1.6041, 0x585, bytes(abort)))
    out.append(_message(2.5031, 0x605, bytes((0x40, 0x08, 0x10, 0, 0, 0, 0, 0))))
    out.append(_message(2.5061, 0x585, bytes((0x41, 0x08, 0x10, 0, 20, 0, 0, 0))))
    out.append(_message(2.7031, 0x085, bytes((0x30, 0x81, 0x11, 0, 0, 0, 0, 0))))
    out.sort(key=lambda m: m.timestamp)
    return out


def _summary(messages: list[can.Message], size: int = 65_536) -> TraceSummary:
    return TraceSummary(bitrate=250_000).feed(message_blocks(messages, size))


def test_the_figures_of_a_trace_whose_figures_are_known() -> None:
    messages = _trace()
    r = _summary(messages).result()
    start = messages[0].timestamp
    assert r["frames"] == len(messages) and r["duration"] == pytest.approx(3.2 - start)
    (node,) = r["nodes"]
    hb = node["heartbeat"]
    assert node["heartbeats"] == 29 and node["bootups"] == 2 and node["reboots"] == 1
    assert hb["missed"] == 1 and hb["min"] == pytest.approx(0.096)
    assert hb["max"] == pytest.approx(0.2)  # (the missed beat's interval)
    sync = r["sync"]
    assert sync["count"] == 299 and sync["mean"] == pytest.approx(0.01, abs=2e-6)
    assert (sync["min"], sync["max"]) == (pytest.approx(0.0095), pytest.approx(0.0105))
    assert sync["jitter"] == pytest.approx(0.0005, rel=1e-3)
    (pdo,) = [c for c in r["cob_ids"] if c["cob_id"] == 0x185]
    assert pdo["pdo"] == "TPDO1 of node 5" and pdo["frames"] == 300
    age = pdo["age_after_sync"]
    assert (age["min"], age["max"]) == (pytest.approx(0.0015), pytest.approx(0.0015))
    assert node["tpdos"] == 300 and node["rpdos"] == 0
    lat = node["sdo_latency"]
    assert lat["count"] == 6
    assert (lat["min"], lat["max"]) == (pytest.approx(0.001), pytest.approx(0.004))
    assert node["sdo_transfers"] == 5
    assert node["sdo_aborts"] == {"0x06020000 object does not exist in the object dictionary": 1}
    (unfinished,) = node["sdo_unfinished"]
    assert "1008h" in unfinished
    assert node["emergencies"] == {"8130h Life guard error or heartbeat error": 1}
    events = [e["event"] for e in r["timeline"]]
    assert events[:3] == ["node 5 boot-up", "node 5 PRE-OPERATIONAL", "NMT start node 5"]
    assert "node 5 OPERATIONAL" in events and events[-1] == "node 5 boot-up"
    # the bus load: each frame's bits at 250 kbit/s
    bits = [_reference_bits(m.arbitration_id, False, False, m.dlc, bytes(m.data)) for m in messages]
    load = r["bus_load"]
    assert load["mean"] == pytest.approx(sum(bits) / 250_000 / r["duration"])
    firsts = [b for b, m in zip(bits, messages, strict=True) if m.timestamp - start < 1.0]
    assert load["per_window"][0] == {"start": 0.0, "load": pytest.approx(sum(firsts) / 250_000)}
    text = "\n".join(_summary(messages).lines())
    assert "SDO abort 1x: 0x06020000 object does not exist in the object dictionary" in text
    assert "heartbeat: 29 beats" in text and "1 missed" in text


def _rounded(value: Any) -> Any:
    if isinstance(value, float):
        return round(value, 9)
    if isinstance(value, dict):
        return {k: _rounded(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_rounded(v) for v in value]
    return value


def test_the_same_summary_whatever_the_blocks() -> None:
    """Blocks of 7 frames or of all: intervals, ages, bursts and SDO pairs carry over."""
    messages = _trace()
    whole = _rounded(_summary(messages).result())
    assert _rounded(_summary(messages, 7).result()) == whole
    assert _rounded(_summary(messages, 1).result()) == whole


def test_the_longest_burst_of_back_to_back_frames() -> None:
    """Twenty frames that follow each other as fast as the bus carries them, amid a slow
    heartbeat: the burst is those twenty."""
    messages = [_message(0.1 * k, 0x701, b"\x05") for k in range(10)]
    frame = 111 / 250_000  # (8 zero bytes: 111 bits and the stuff bits)
    messages += [_message(0.55 + k * frame * 1.2, 0x181, bytes(8)) for k in range(20)]
    messages.sort(key=lambda m: m.timestamp)
    burst = _summary(messages).result()["longest_burst"]
    assert burst["frames"] == 20


def test_an_empty_trace_and_bad_settings() -> None:
    r = TraceSummary().feed([]).result()
    assert r["frames"] == 0 and r["bus_load"]["mean"] is None and r["nodes"] == []
    with pytest.raises(ValueError, match="bit rate"):
        TraceSummary(bitrate=0)
    with pytest.raises(ValueError, match="window"):
        TraceSummary(window=0)
    assert np.__name__ == "numpy"


def test_cobus_decode_summary(tmp_path: Path) -> None:
    path = tmp_path / "bench.log"
    with can.Logger(str(path)) as logger:
        for msg in _trace():
            logger(msg)
    base = [sys.executable, "-m", "cobus", "decode", str(path), "--summary"]
    done = subprocess.run([*base, "--bitrate", "250000"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert "bus load at 250 kbit/s" in done.stdout
    assert "SDO abort 1x: 0x06020000 object does not exist in the object dictionary" in done.stdout
    done = subprocess.run([*base, "--json"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    data = json.loads(done.stdout)
    assert data["bitrate"] == 500_000 and data["nodes"][0]["node"] == 5
    for extra, said in [
        (["--node", "5"], "--node does not go with --summary"),
        (["--bitrate", "fast"], "a bit rate in bit/s"),
        (["--window", "0"], "above 0"),
    ]:
        done = subprocess.run([*base, *extra], capture_output=True, text=True)
        assert done.returncode == 2 and said in done.stderr, done.stderr


def test_what_the_review_of_the_summary_found() -> None:
    """result() twice gives the same; missed beats whatever the blocks; times that step
    back; latencies past the sample kept; a node silent at the end; LSS frames no node's;
    the last window of a few frames left out; too short a window refused."""
    beats = [_message(0.1 * k, 0x705, b"\x05") for k in range(20)]
    beats += [_message(2.5 + 0.1 * k, 0x705, b"\x05") for k in range(20)]  # (after 0.6 s)
    beats.append(_message(9.0, 0x181, bytes(2)))  # (node 5 silent from 4.4 s on)
    for size in (1, 2, 5, 1000):
        (node,) = [n for n in _summary(beats, size).result()["nodes"] if n["node"] == 5]
        assert node["heartbeat"]["missed"] == 5 + 45, size
    summary = _summary(beats)
    assert summary.result() == summary.result()
    back = [_message(1.0, 0x181, bytes(8)), _message(0.5, 0x181, bytes(8))]
    back += [_message(2.0 + k, 0x181, bytes(8)) for k in range(3)]
    assert _summary(back).result()["frames"] == 5  # (no exception)
    assert _summary([_message(0.0, 0x181), _message(1e9, 0x181)]).result()["frames"] == 2
    from cobus.trace import summary as module

    many = TraceSummary()
    stats = many._node(5)
    for _k in range(module.KEEP + 10):
        stats.latency(0.001)
    stats.latency(0.05)
    many.feed([])
    lat = many.result()["nodes"][0]["sdo_latency"]
    assert lat["count"] == module.KEEP + 11 and lat["max"] == 0.05
    lss = [_message(0.01 * k, 0x7E5, bytes((0x4C, 0, 0, 0, 0, 0, 0, 0))) for k in range(50)]
    lss.append(_message(1.0, 0x764, b"\x05"))
    nodes = {n["node"]: n["frames"] for n in _summary(lss).result()["nodes"]}
    assert nodes == {100: 1}
    tail = [_message(0.001 * k, 0x181, bytes(8)) for k in range(1000)]
    tail.append(_message(1.05, 0x181, bytes(8)))
    windows = _summary(tail).result()["bus_load"]["per_window"]
    assert [w["start"] for w in windows] == [0.0]
    with pytest.raises(ValueError, match="at least"):
        TraceSummary(bitrate=500_000, window=0.001)


def test_the_timeline_keeps_the_earliest_events() -> None:
    from cobus.trace import summary as module

    events = [_message(0.001 * k, 0x000, b"\x01\x05") for k in range(module.TIMELINE + 50)]
    for size in (1, 65_536):
        r = _summary(events, size).result()
        assert len(r["timeline"]) == module.TIMELINE and r["timeline_dropped"] == 50
        assert r["timeline"][0]["time"] == 0.0
        assert r["timeline"][-1]["time"] == pytest.approx(0.001 * (module.TIMELINE - 1))
