"""What a bench engineer asks of a trace (``cobus decode FILE --summary``).

:class:`TraceSummary` takes a trace block by block (:mod:`cobus.trace.blocks`) and keeps only
counters and bounded samples, so a trace of any length fits in constant memory:

- bus load per window of time, from the bit rate and each frame's real length on the wire
  (bit stuffing included); frames per second per COB-ID and per node; the longest burst of
  back-to-back frames;
- per node: heartbeat period (min/mean/max, jitter, missed beats), boot-ups and re-boots,
  RPDO and TPDO counts, SDO request-to-answer latency (min/median/p99/max), aborts with
  their texts, transfers the trace ended in, emergencies with their texts;
- SYNC period and jitter, and each PDO's age after the SYNC before it;
- NMT commands and state changes as a time line.

The bulk - PDOs, SYNC, heartbeats - is counted with numpy a block at a time; SDO, EMCY,
NMT and LSS frames (a few percent of a real trace) go through the exact
:class:`~cobus.trace.decoder.Decoder`, so SDO transfers, abort texts and a device's own
emergency texts are the decoder's.
"""

from __future__ import annotations

import heapq
import math
import random
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from cobus.proto import Frame
from cobus.trace.blocks import ERROR, EXTENDED, FD, REMOTE, FrameBlock, frame_bits
from cobus.trace.decoder import (
    Bootup,
    Decoder,
    EmergencyRecord,
    LssSession,
    NmtCommandRecord,
    SdoTransfer,
)

__all__ = ["TraceSummary"]

#: Samples kept per node for the latency percentiles (the earliest ones).
KEEP = 100_000
#: Entries the time line keeps (the earliest; the rest are counted).
TIMELINE = 5_000

_STATE = {0x04: "STOPPED", 0x05: "OPERATIONAL", 0x7F: "PRE-OPERATIONAL"}
#: Function codes of the default connection set (COB-ID & 780h).
_TPDO = {0x180: 1, 0x280: 2, 0x380: 3, 0x480: 4}
_RPDO = {0x200: 1, 0x300: 2, 0x400: 3, 0x500: 4}


#: Intervals a node's heartbeat period is taken from (their median).
_PERIOD_FROM = 16
#: Entries of LSS sessions kept.
_LSS_KEPT = 1_000


def _missed(gaps: npt.NDArray[np.float64], period: float) -> int:
    """Beats missing in ``gaps``: an interval over 1.5 periods lacks all but one."""
    if not period or not len(gaps):
        return 0
    late = gaps > 1.5 * period
    return int(np.maximum(1, np.round(gaps[late] / period) - 1).sum())


@dataclass
class _Series:
    """Intervals seen one at a time: count, min, max, sum, sum of squares."""

    count: int = 0
    low: float = math.inf
    high: float = -math.inf
    total: float = 0.0
    squares: float = 0.0

    def add(self, values: npt.NDArray[np.float64]) -> None:
        if len(values):
            self.count += len(values)
            self.low = min(self.low, float(values.min()))
            self.high = max(self.high, float(values.max()))
            self.total += float(values.sum())
            self.squares += float(np.square(values).sum())

    @property
    def mean(self) -> float | None:
        return self.total / self.count if self.count else None

    @property
    def jitter(self) -> float | None:
        """The standard deviation."""
        if not self.count:
            return None
        mean = self.total / self.count
        return math.sqrt(max(0.0, self.squares / self.count - mean * mean))

    def as_dict(self) -> dict[str, Any] | None:
        if not self.count:
            return None
        return {
            "count": self.count,
            "min": self.low,
            "mean": self.mean,
            "max": self.high,
            "jitter": self.jitter,
        }


@dataclass
class _Node:
    heartbeats: int = 0
    intervals: _Series = field(default_factory=_Series)
    #: The period missed beats are counted against: the median of the first intervals.
    period: float | None = None
    first: list[float] = field(default_factory=list)
    missed: int = 0
    last_beat: float | None = None
    last_boot: bool = False  # (the last message was a boot-up: no interval from it)
    state: int | None = None
    bootups: int = 0
    reboots: int = 0
    guarding: int = 0
    sdo_asked: float | None = None
    #: Latencies: how many, the least, the most, and a sample of at most KEEP for the
    #: median and p99 (every one until then; a uniform one after, the same each run).
    latencies: list[float] = field(default_factory=list)
    answered: int = 0
    fastest: float = math.inf
    slowest: float = -math.inf
    draw: random.Random = field(default_factory=lambda: random.Random(45))

    def latency(self, value: float) -> None:
        self.answered += 1
        self.fastest = min(self.fastest, value)
        self.slowest = max(self.slowest, value)
        if len(self.latencies) < KEEP:
            self.latencies.append(value)
        else:
            slot = self.draw.randrange(self.answered)
            if slot < KEEP:
                self.latencies[slot] = value

    transfers: int = 0
    aborts: dict[str, int] = field(default_factory=dict)
    unfinished: list[str] = field(default_factory=list)
    emcy: dict[str, int] = field(default_factory=dict)


class TraceSummary:
    """The summary of a trace fed with :meth:`add` (blocks in time order); :meth:`result`
    gives it as data, :meth:`lines` as text. ``bitrate`` (bit/s) and ``window`` (s) set the
    bus load's measure; ``dictionaries`` (node -> its dictionary) and ``network`` are the
    decoder's, for PDO COB-IDs, names and a device's emergency texts."""

    def __init__(
        self,
        bitrate: int = 500_000,
        window: float = 1.0,
        dictionaries: Mapping[int, Any] | None = None,
        network: Any = None,
    ) -> None:
        if bitrate <= 0:
            raise ValueError(f"bit rate {bitrate}: give it in bit/s, e.g. 500000")
        shortest = max(0.01, 20 * 135 / max(bitrate, 1))
        if not window >= shortest:
            raise ValueError(
                f"window {window} s: give at least {shortest:g} s (twenty frames at "
                f"{bitrate} bit/s), or the load of one frame fills it"
            )
        self.bitrate = bitrate
        self.window = window
        self.decoder = Decoder(dictionaries, network=network)
        self.frames = 0
        self.error_frames = 0
        self.fd_frames = 0
        self.start: float | None = None
        self.end: float | None = None
        self._bits: dict[int, int] = {}  # window -> bits
        self._per_cob: dict[int, int] = {}  # cob (| 1 << 31 when extended) -> frames
        self._nodes: dict[int, _Node] = {}
        self._sync = _Series()
        self._last_sync: float | None = None
        self._age: dict[int, _Series] = {}  # PDO COB-ID -> its age after the SYNC
        self._burst = (0, 0.0, 0.0)  # frames, start, end
        self._run = (0, 0.0, 0.0)  # the burst under way at the end of the last block
        self._last_end: float | None = None  # when the last frame's last bit was sent
        #: The earliest TIMELINE events: (-time, order, text), a heap of the latest on top.
        self._timeline: list[tuple[float, int, str]] = []
        self._events = 0
        self.timeline_dropped = 0
        self.lss: list[str] = []

    def _node(self, node: int) -> _Node:
        found = self._nodes.get(node)
        if found is None:
            found = self._nodes[node] = _Node()
        return found

    def _event(self, when: float, text: str) -> None:
        self._events += 1
        entry = (-when, -self._events, text)
        if len(self._timeline) < TIMELINE:
            heapq.heappush(self._timeline, entry)
        else:
            self.timeline_dropped += 1
            if entry > self._timeline[0]:  # (earlier than the latest kept)
                heapq.heapreplace(self._timeline, entry)

    @property
    def timeline(self) -> list[tuple[float, str]]:
        """The time line's earliest :data:`TIMELINE` events, in time order."""
        return [(-t, text) for t, _n, text in sorted(self._timeline, reverse=True)]

    # ------------------------------------------------------------------ feeding

    def add(self, block: FrameBlock) -> None:
        """Count one block of frames (after the blocks before it)."""
        n = len(block)
        if n == 0:
            return
        if self.start is None:
            self.start = float(block.time[0])
        self.end = float(block.time[-1])
        t = block.time - self.start
        flags = block.flags
        bad = (flags & (ERROR | FD)) != 0
        self.error_frames += int(((flags & ERROR) != 0).sum())
        self.fd_frames += int(((flags & FD) != 0).sum())
        self.frames += n
        good = ~bad
        ext = (flags & EXTENDED) != 0
        rtr = (flags & REMOTE) != 0
        cob = block.cob_id.astype(np.int64)
        key = np.where(ext, cob | (1 << 31), cob)[good]
        ids, counts = np.unique(key, return_counts=True)
        for k, c in zip(ids.tolist(), counts.tolist(), strict=True):
            self._per_cob[k] = self._per_cob.get(k, 0) + c
        bits = frame_bits(block)
        slots = (t // self.window).astype(np.int64)
        windows, where = np.unique(slots, return_inverse=True)  # (times may step back)
        sums = np.bincount(where.ravel(), weights=bits)
        for slot, v in zip(windows.tolist(), sums.tolist(), strict=True):
            if v:
                self._bits[slot] = self._bits.get(slot, 0) + int(v)
        self._bursts(t, bits, good)
        std = good & ~ext
        func = cob & 0x780
        node = cob & 0x7F
        self._sync_and_pdos(t, std & ~rtr, cob, func)
        self._heartbeats(block, t, std, rtr, func, node)
        slow = std & (
            (cob == 0)
            | ((func == 0x080) & (node != 0))
            | (func == 0x580)
            | (func == 0x600)
            | (cob == 0x7E4)
            | (cob == 0x7E5)
        )
        for i in np.flatnonzero(slow).tolist():
            self._slow(block, i, float(t[i]))

    def _bursts(
        self, t: npt.NDArray[np.float64], bits: npt.NDArray[np.int64], good: npt.NDArray[Any]
    ) -> None:
        """The longest run of frames that follow each other on the bus with no more than
        one frame's room between them (the bus busy all along)."""
        times = t[good]
        if not len(times):
            return
        length = bits[good] / self.bitrate
        # a frame continues the burst when it came within twice its own length of the
        # frame before it (timestamps mark a frame's end: back to back is one length)
        gaps = np.diff(times, prepend=np.nan)
        if self._last_end is not None:
            gaps[0] = times[0] - self._last_end
        joined = gaps <= 2 * length
        count, began, _end = self._run
        best = self._burst
        starts = np.flatnonzero(~joined)
        # runs inside this block: between the frames that start one
        edges = np.concatenate(([0], starts, [len(times)]))
        for a, b in zip(edges[:-1].tolist(), edges[1:].tolist(), strict=True):
            if b <= a:
                continue
            if a == 0 and joined[0] and count:
                run = (count + b - a, began, float(times[b - 1]))
            else:
                run = (b - a, float(times[a]), float(times[b - 1]))
            if run[0] > best[0]:
                best = run
            count, began = run[0], run[1]
        self._run = (count, began, float(times[-1]))
        self._burst = best
        self._last_end = float(times[-1])

    def _sync_and_pdos(
        self,
        t: npt.NDArray[np.float64],
        data: npt.NDArray[Any],
        cob: npt.NDArray[np.int64],
        func: npt.NDArray[np.int64],
    ) -> None:
        is_sync = data & (cob == 0x080)
        syncs = t[is_sync]
        if len(syncs):
            before = [] if self._last_sync is None else [self._last_sync]
            series = np.concatenate((before, syncs))
            self._sync.add(np.diff(series))
        is_pdo = data & (func >= 0x180) & (func <= 0x500)
        if not is_pdo.any():
            if len(syncs):
                self._last_sync = float(syncs[-1])
            return
        pdo_t = t[is_pdo]
        pdo_cob = cob[is_pdo]
        known = np.concatenate(([] if self._last_sync is None else [self._last_sync], syncs))
        if len(known):
            where = np.searchsorted(known, pdo_t, side="right") - 1
            ok = where >= 0
            ages = pdo_t[ok] - known[where[ok]]
            for c in np.unique(pdo_cob[ok]).tolist():
                self._age.setdefault(c, _Series()).add(ages[pdo_cob[ok] == c])
        if len(syncs):
            self._last_sync = float(syncs[-1])

    def _heartbeats(
        self,
        block: FrameBlock,
        t: npt.NDArray[np.float64],
        std: npt.NDArray[Any],
        rtr: npt.NDArray[Any],
        func: npt.NDArray[np.int64],
        node: npt.NDArray[np.int64],
    ) -> None:
        ec = std & (func == 0x700) & (node != 0)
        if not ec.any():
            return
        beat = ec & ~rtr & (block.dlc == 1)
        first = block.data[:, 0]
        guard_reply = beat & ((first & 0x80) != 0)
        beat = beat & ~guard_reply
        for n in np.unique(node[ec]).tolist():
            stats = self._node(n)
            mine = node == n
            stats.guarding += int((guard_reply & mine).sum())
            rows = np.flatnonzero(beat & mine)
            if not len(rows):
                continue
            states = first[rows]
            times = t[rows]
            boot = states == 0
            stats.heartbeats += int((~boot).sum())
            self._intervals(stats, times, boot)
            # boot-ups and state changes, in their order
            changes = np.flatnonzero(states[1:] != states[:-1]) + 1
            head = [0] if stats.state != int(states[0]) else []
            picks = sorted({*head, *changes.tolist(), *np.flatnonzero(boot).tolist()})
            for i in picks:
                value = int(states[i])
                when = float(times[i])
                if value == 0:
                    stats.bootups += 1
                    if stats.state is not None:
                        stats.reboots += 1
                    self._event(when, f"node {n} boot-up")
                elif value != stats.state:
                    name = _STATE.get(value, f"state {value:02X}h")
                    self._event(when, f"node {n} {name}")
                stats.state = value

    def _intervals(
        self, stats: _Node, times: npt.NDArray[np.float64], boot: npt.NDArray[Any]
    ) -> None:
        before = stats.last_beat
        series = np.concatenate(([before] if before is not None else [], times))
        restart = np.concatenate(([stats.last_boot] if before is not None else [], boot)).astype(
            bool
        )
        gaps = np.diff(series)
        keep = ~restart[1:] & ~restart[:-1]  # (an interval touching a boot-up is none)
        gaps = gaps[keep] if len(gaps) else gaps
        stats.last_beat = float(times[-1])
        stats.last_boot = bool(boot[-1])
        if not len(gaps):
            return
        if stats.period is None:  # (the first intervals wait for the period they set)
            stats.first.extend(gaps.tolist())
            if len(stats.first) >= _PERIOD_FROM:
                self._period(stats)
        else:
            stats.missed += _missed(gaps, stats.period)
        stats.intervals.add(gaps)

    @staticmethod
    def _period(stats: _Node) -> None:
        """The node's period: the median of its first intervals, which are then checked
        against it like every later one."""
        first = np.array(stats.first, dtype=np.float64)
        stats.period = float(np.median(first[:_PERIOD_FROM]))
        stats.missed += _missed(first, stats.period)
        stats.first = []

    def _slow(self, block: FrameBlock, i: int, now: float) -> None:
        dlc = int(block.dlc[i])
        rtr = bool(block.flags[i] & REMOTE)
        data = b"" if rtr else bytes(block.data[i, : min(dlc, 8)])
        cob = int(block.cob_id[i])
        frame = Frame(cob, data, rtr=rtr, dlc=min(dlc, 8) if rtr else None)
        func, node = cob & 0x780, cob & 0x7F
        if not rtr and func == 0x600:
            self._node(node).sdo_asked = now
        elif not rtr and func == 0x580:
            stats = self._node(node)
            if stats.sdo_asked is not None:
                stats.latency(now - stats.sdo_asked)
                stats.sdo_asked = None
        for rec in self.decoder.feed(frame, now):
            self._record(rec)

    def _record(self, rec: Any) -> None:
        if isinstance(rec, SdoTransfer):
            stats = self._node(rec.node)
            if rec.mode == "incomplete":
                if len(stats.unfinished) < 100:
                    stats.unfinished.append(str(rec))
                return
            stats.transfers += 1
            if rec.abort_code is not None:
                text = str(rec).split(" ABORTED ", 1)[-1].rsplit(" (", 1)[0]
                stats.aborts[text] = stats.aborts.get(text, 0) + 1
        elif isinstance(rec, EmergencyRecord):
            stats = self._node(rec.node)
            text = (
                f"{rec.code:04X}h error reset"
                if rec.code >> 8 == 0
                else f"{rec.code:04X}h {rec.text}"
            )
            stats.emcy[text] = stats.emcy.get(text, 0) + 1
            self._event(rec.time, f"node {rec.node} EMCY {text}")
        elif isinstance(rec, NmtCommandRecord):
            who = "all nodes" if rec.target == 0 else f"node {rec.target}"
            self._event(rec.time, f"NMT {rec.command} {who}")
        elif isinstance(rec, LssSession):
            if len(self.lss) < _LSS_KEPT:
                self.lss.append(str(rec))
            self._event(rec.time, str(rec))
        elif isinstance(rec, Bootup):  # (not fed: heartbeats are counted in bulk)
            pass

    def feed(self, blocks: Iterable[FrameBlock]) -> TraceSummary:
        """:meth:`add` each block; then the transfers the trace ended in. Returns self."""
        for block in blocks:
            self.add(block)
        self.finish()
        return self

    def finish(self) -> None:
        """The trace is over: SDO transfers still open count as unfinished; a node with
        fewer intervals than the period needs gets its period from them; a node silent at
        the end misses the beats of that silence."""
        end = 0.0 if self.start is None or self.end is None else self.end - self.start
        for rec in self.decoder.flush(end):
            self._record(rec)
        for stats in self._nodes.values():
            if stats.period is None and stats.first:
                self._period(stats)
            if stats.period and stats.last_beat is not None and not stats.last_boot:
                stats.missed += _missed(np.array([end - stats.last_beat]), stats.period)

    # ------------------------------------------------------------------ results

    @property
    def duration(self) -> float:
        """Seconds from the first frame to the last."""
        if self.start is None or self.end is None:
            return 0.0
        return self.end - self.start

    def _pdo_kind(self, cob: int) -> tuple[int, str, int] | None:
        """(node, "tpdo"/"rpdo", number) of a PDO COB-ID: the decoder's configuration (an
        EDS, the network file, a remap it saw), else the default connection set."""
        known = self.decoder.pdo_of(cob)
        if known is not None:
            return known[0], "tpdo" if known[2] else "rpdo", known[1]
        func, node = cob & 0x780, cob & 0x7F
        if node and func in _TPDO:
            return node, "tpdo", _TPDO[func]
        if node and func in _RPDO:
            return node, "rpdo", _RPDO[func]
        return None

    def result(self) -> dict[str, Any]:
        """The summary as data (what ``--summary --json`` prints)."""
        span = self.duration
        per_second = (lambda c: c / span) if span > 0 else (lambda c: float(c))
        loads = []
        for slot, slot_bits in sorted(self._bits.items()):
            begin = slot * self.window
            covered = min(self.window, span - begin) if span > begin else 0.0
            if covered >= self.window / 2:  # (a last window of a few frames says nothing)
                loads.append((round(begin, 9), slot_bits / (self.bitrate * covered)))
        peak = max(loads, key=lambda w: w[1]) if loads else None
        bits = sum(self._bits.values())
        cobs = []
        pdo_frames: dict[int, dict[str, int]] = {}
        for key, count in sorted(self._per_cob.items()):
            cob = key & 0x1FFFFFFF
            entry: dict[str, Any] = {
                "cob_id": cob,
                "extended": bool(key >> 31),
                "frames": count,
                "per_second": per_second(count),
            }
            pdo = None if key >> 31 else self._pdo_kind(cob)
            if pdo is not None:
                entry["pdo"] = f"{pdo[1].upper()}{pdo[2]} of node {pdo[0]}"
                counted = pdo_frames.setdefault(pdo[0], {"tpdo": 0, "rpdo": 0})
                counted[pdo[1]] += count
                age = self._age.get(cob)
                if age is not None and age.count:
                    entry["age_after_sync"] = age.as_dict()
            cobs.append(entry)
        nodes = {n: self._nodes.get(n) or _Node() for n in sorted({*self._nodes, *pdo_frames})}
        per_node: dict[int, int] = {}
        for key, count in self._per_cob.items():
            if not key >> 31 and key & 0x7F and key & 0x780 not in (0x000, 0x780):
                per_node[key & 0x7F] = per_node.get(key & 0x7F, 0) + count
        out_nodes = []
        for n, s in nodes.items():
            lat = sorted(s.latencies)
            latency = None
            if lat:
                latency = {
                    "count": s.answered,
                    "min": s.fastest,
                    "median": lat[len(lat) // 2],
                    "p99": lat[min(len(lat) - 1, math.ceil(0.99 * len(lat)) - 1)],
                    "max": s.slowest,
                }
            heartbeat = s.intervals.as_dict()
            if heartbeat is not None:
                heartbeat["missed"] = s.missed
            out_nodes.append(
                {
                    "node": n,
                    "frames": per_node.get(n, 0),
                    "per_second": per_second(per_node.get(n, 0)),
                    "heartbeats": s.heartbeats,
                    "heartbeat": heartbeat,
                    "bootups": s.bootups,
                    "reboots": s.reboots,
                    "guarding_replies": s.guarding,
                    "state": _STATE.get(s.state) if s.state else None,
                    "tpdos": pdo_frames.get(n, {}).get("tpdo", 0),
                    "rpdos": pdo_frames.get(n, {}).get("rpdo", 0),
                    "last_heartbeat": s.last_beat,
                    "sdo_transfers": s.transfers,
                    "sdo_latency": latency,
                    "sdo_aborts": dict(sorted(s.aborts.items())),
                    "sdo_unfinished": list(s.unfinished),
                    "emergencies": dict(sorted(s.emcy.items())),
                }
            )
        burst = self._burst
        return {
            "frames": self.frames,
            "error_frames": self.error_frames,
            "fd_frames": self.fd_frames,
            "duration": span,
            "bitrate": self.bitrate,
            "bus_load": {
                "mean": bits / (self.bitrate * span) if span > 0 else None,
                "peak": None if peak is None else peak[1],
                "peak_at": None if peak is None else peak[0],
                "window": self.window,
                "per_window": [{"start": start, "load": load} for start, load in loads],
            },
            "longest_burst": {
                "frames": burst[0],
                "start": burst[1],
                "duration": burst[2] - burst[1],
            },
            "sync": self._sync.as_dict(),
            "cob_ids": cobs,
            "nodes": out_nodes,
            "timeline": [{"time": t, "event": e} for t, e in self.timeline],
            "timeline_dropped": self.timeline_dropped,
            "lss": list(self.lss),
        }

    def lines(self) -> list[str]:
        """The summary as text, section by section."""
        r = self.result()
        ms = _ms
        out = [
            f"{r['frames']:,} frames in {r['duration']:.3f} s"
            + (f", {r['error_frames']} error frames" if r["error_frames"] else "")
            + (f", {r['fd_frames']} CAN FD frames (not counted)" if r["fd_frames"] else "")
        ]
        load = r["bus_load"]
        if load["mean"] is not None:
            out.append(
                f"bus load at {r['bitrate'] / 1000:g} kbit/s: mean {load['mean']:.1%}, peak "
                f"{load['peak']:.1%} (the {load['window']:g} s from {load['peak_at']:.3f} s)"
            )
            windows = [w["load"] for w in load["per_window"]]
            if 1 < len(windows) <= 60:
                out.append("  per window: " + " ".join(f"{w:.0%}" for w in windows))
        burst = r["longest_burst"]
        if burst["frames"] > 1:
            out.append(
                f"longest burst: {burst['frames']} frames back to back from {burst['start']:.6f} s "
                f"({ms(burst['duration'])})"
            )
        sync = r["sync"]
        if sync is not None:
            out.append(
                f"SYNC: {sync['count'] + 1} frames, period mean {ms(sync['mean'])} (min "
                f"{ms(sync['min'])}, max {ms(sync['max'])}), jitter {ms(sync['jitter'])}"
            )
        out.append("COB-IDs:")
        for c in r["cob_ids"]:
            ident = f"{c['cob_id']:08X}" if c["extended"] else f"{c['cob_id']:03X}"
            what = f"  {c['pdo']}" if "pdo" in c else ""
            age = c.get("age_after_sync")
            if age is not None:
                what += f", after SYNC {ms(age['min'])}..{ms(age['max'])} (mean {ms(age['mean'])})"
            out.append(f"  {ident}  {c['frames']:>9,} frames {c['per_second']:>10.1f}/s{what}")
        for n in r["nodes"]:
            out.append(f"node {n['node']}: {n['frames']:,} frames ({n['per_second']:.1f}/s)")
            hb = n["heartbeat"]
            if hb is not None:
                out.append(
                    f"  heartbeat: {n['heartbeats']} beats, period {ms(hb['min'])}/"
                    f"{ms(hb['mean'])}/{ms(hb['max'])} (min/mean/max), jitter {ms(hb['jitter'])}"
                    f", {hb['missed']} missed"
                )
            if n["bootups"] or n["reboots"]:
                out.append(f"  boot-ups: {n['bootups']} ({n['reboots']} re-boots)")
            if n["guarding_replies"]:
                out.append(f"  node guarding replies: {n['guarding_replies']}")
            if n["tpdos"] or n["rpdos"]:
                out.append(f"  PDOs: {n['tpdos']:,} TPDO, {n['rpdos']:,} RPDO frames")
            lat = n["sdo_latency"]
            if n["sdo_transfers"] or lat is not None:
                line = f"  SDO: {n['sdo_transfers']} transfers"
                if lat is not None:
                    line += (
                        f", answer after {ms(lat['min'])}/{ms(lat['median'])}/{ms(lat['p99'])}/"
                        f"{ms(lat['max'])} (min/median/p99/max)"
                    )
                out.append(line)
            for text, count in n["sdo_aborts"].items():
                out.append(f"  SDO abort {count}x: {text}")
            for text in n["sdo_unfinished"]:
                out.append(f"  unfinished: {text}")
            for text, count in n["emergencies"].items():
                out.append(f"  EMCY {count}x: {text}")
        if r["timeline"]:
            out.append("time line:")
            for entry in r["timeline"]:
                out.append(f"  {entry['time']:12.6f}  {entry['event']}")
            if r["timeline_dropped"]:
                out.append(f"  ... and {r['timeline_dropped']:,} more")
        return out


def _ms(seconds: float | None) -> str:
    return "-" if seconds is None else f"{seconds * 1000:.3f} ms"
