"""Decoding a trace a block of frames at a time: the same records as
:class:`~cobus.trace.decoder.Decoder`, frame for frame, at the speed of arrays.

>>> batch = BatchDecoder({10: load("servo.eds")})
>>> for block in blocks("bench.blf"):
...     decoded = batch.decode(block, origin)
...     decoded.pdos[0].columns["Statusword"]      # a numpy column per PDO value
...     decoded.records()                          # or the records, as Decoder.feed gives
>>> batch.flush(end)                               # the SDO transfers the trace ended in

The bulk of a real trace — PDOs, SYNC and heartbeats, 95 % of its frames and more — is
decoded column by column with numpy: a table per PDO (its values by name as typed columns),
one of SYNCs and one of heartbeats. Every other frame (SDO, EMCY, NMT, LSS, TIME, guarding,
remote and extended frames) goes through the exact stateful decoder, in its place: a
heartbeat after a guarding request, the statuswords of a drive and a PDO mapping an SDO
writes mid-block are taken in the order the frames came, so the records, the node
statistics and the mappings learnt are the frame-by-frame path's, byte for byte.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from cobus.od import DataType, decode
from cobus.proto import Frame
from cobus.proto.connection_set import (
    ERROR_CONTROL_BASE,
    MAX_NODE_ID,
    SDO_RX_BASE,
    SDO_TX_BASE,
    SYNC_COB_ID,
    TPDO_BASE,
)
from cobus.trace.blocks import ERROR, EXTENDED, FD, REMOTE, FrameBlock
from cobus.trace.decoder import (
    _STATES,
    Decoder,
    Heartbeat,
    PdoRecord,
    SyncRecord,
    TraceRecord,
    _Pdo,
    pdo_values,
)

__all__ = ["BatchDecoder", "DecodedBlock", "PdoColumns"]

_Index = npt.NDArray[np.int64]

_new_frame = object.__new__


@dataclass
class PdoColumns:
    """The frames of one PDO in a block: ``index`` (row in the block), ``time``, ``dlc``,
    ``data`` (n x 8, zero-padded) and, by value name, a column: a numpy array (the
    narrowest integer type that holds the entry's bits, signed for INTEGERn; float32,
    float64, bool), or a list where numpy has no type (strings, times of day).
    ``present``: how many of ``names`` each frame carries (a frame shorter than its mapping
    carries the first few); None for a PDO no mapping names (node and number from its
    COB-ID, no values). ``rows``: values and units frame by frame instead, where a network
    file's signals scale them."""

    cob_id: int
    node: int | None
    number: int | None
    tpdo: bool
    index: _Index
    time: npt.NDArray[np.float64]
    dlc: npt.NDArray[np.uint8]
    data: npt.NDArray[np.uint8]
    names: tuple[str, ...] = ()
    columns: dict[str, Any] = field(default_factory=dict)
    present: npt.NDArray[np.int64] | None = None
    #: Values and units row by row, where a network file's signals scale them.
    rows: list[tuple[dict[str, Any], dict[str, str] | None]] | None = None

    def __len__(self) -> int:
        return len(self.index)

    def _cut(self, keep: int) -> PdoColumns:
        """The first ``keep`` rows."""
        return PdoColumns(
            self.cob_id,
            self.node,
            self.number,
            self.tpdo,
            self.index[:keep],
            self.time[:keep],
            self.dlc[:keep],
            self.data[:keep],
            self.names,
            {k: v[:keep] for k, v in self.columns.items()},
            None if self.present is None else self.present[:keep],
            None if self.rows is None else self.rows[:keep],
        )

    def records(self) -> list[PdoRecord]:
        """The table's frames as :class:`PdoRecord` (what the frame-by-frame path gives)."""
        buf = self.data.tobytes()
        times = self.time.tolist()
        dlcs = self.dlc.tolist()
        cob, node, number, tpdo = self.cob_id, self.node, self.number, self.tpdo
        out: list[PdoRecord] = []
        if self.rows is not None:
            for i, (values, units) in enumerate(self.rows):
                data = buf[8 * i : 8 * i + dlcs[i]]
                if units is None:
                    out.append(PdoRecord(times[i], cob, node, number, tpdo, data, values))
                else:
                    out.append(PdoRecord(times[i], cob, node, number, tpdo, data, values, units))
            return out
        if not self.names:
            return [
                PdoRecord(times[i], cob, node, number, tpdo, buf[8 * i : 8 * i + dlcs[i]])
                for i in range(len(times))
            ]
        names = self.names
        cols = [
            c.tolist() if isinstance(c, np.ndarray) else c for c in (self.columns[n] for n in names)
        ]
        present = self.present.tolist() if self.present is not None else []
        full = len(names)
        for i, t in enumerate(times):
            k = present[i]
            if k == full:
                values = dict(zip(names, [c[i] for c in cols], strict=True))
            else:
                values = {names[j]: cols[j][i] for j in range(k)}
            out.append(PdoRecord(t, cob, node, number, tpdo, buf[8 * i : 8 * i + dlcs[i]], values))
        return out


@dataclass
class DecodedBlock:
    """What a block of frames meant. Row ``index`` arrays point into the block.

    - ``records_at``: (row, records) of the frames the exact decoder took, in order;
    - ``sync_*``: the SYNC frames (``sync_counter`` -1 where the frame has none);
    - ``heartbeat_*``: heartbeats (``heartbeat_state``: the state byte, 04h, 05h, 7Fh...);
    - ``pdos``: a :class:`PdoColumns` per PDO (one per COB-ID, in order of first frame;
      two where an SDO remapped the PDO mid-block);
    - ``errors``: rows of error frames, ``skipped``: rows of CAN FD frames (no CANopen);
    - ``time``: every row's time from the origin.
    """

    size: int
    time: npt.NDArray[np.float64]
    records_at: list[tuple[int, list[TraceRecord]]]
    sync_index: _Index
    sync_time: npt.NDArray[np.float64]
    sync_counter: npt.NDArray[np.int16]
    heartbeat_index: _Index
    heartbeat_time: npt.NDArray[np.float64]
    heartbeat_node: npt.NDArray[np.uint8]
    heartbeat_state: npt.NDArray[np.uint8]
    pdos: list[PdoColumns]
    errors: _Index
    skipped: _Index

    def records(self) -> list[TraceRecord]:
        """Every record of the block in the order of its frames, as
        :meth:`Decoder.feed <cobus.trace.decoder.Decoder.feed>` gives them frame by frame
        (error frames and CAN FD frames give none)."""
        out: list[TraceRecord] = []
        for slot in self.slots():
            if slot is None:
                continue
            if type(slot) is list:
                out.extend(slot)
            else:
                out.append(slot)
        return out

    def slots(self) -> list[Any]:
        """Per row, what its frame gave: None, a record, or a list of records (those of
        the exact decoder: none, one, or several)."""
        slots: list[Any] = [None] * self.size
        for row, recs in self.records_at:
            slots[row] = recs
        for row, t, counter in zip(
            self.sync_index.tolist(),
            self.sync_time.tolist(),
            self.sync_counter.tolist(),
            strict=True,
        ):
            slots[row] = SyncRecord(t, SYNC_COB_ID, None if counter < 0 else counter)
        for row, t, node, state in zip(
            self.heartbeat_index.tolist(),
            self.heartbeat_time.tolist(),
            self.heartbeat_node.tolist(),
            self.heartbeat_state.tolist(),
            strict=True,
        ):
            name = _STATES.get(state, f"state {state:02X}h")
            slots[row] = Heartbeat(t, ERROR_CONTROL_BASE + node, node, name)
        for table in self.pdos:
            for row, rec in zip(table.index.tolist(), table.records(), strict=True):
                slots[row] = rec
        return slots


class BatchDecoder:
    """Decodes blocks of frames (:class:`~cobus.trace.blocks.FrameBlock`) into
    :class:`DecodedBlock`. ``dictionaries`` and ``network`` as for
    :class:`~cobus.trace.decoder.Decoder`; ``decoder``: the exact decoder it goes on with
    (its ``stats`` and ``lss`` fill as the frame-by-frame path fills them)."""

    def __init__(
        self,
        dictionaries: Any = None,
        network: Any = None,
        *,
        decoder: Decoder | None = None,
    ) -> None:
        self.decoder = decoder if decoder is not None else Decoder(dictionaries, network=network)

    def flush(self, now: float) -> list[TraceRecord]:
        """The SDO transfers still open at the trace's end (:meth:`Decoder.flush`)."""
        return self.decoder.flush(now)

    def decode(self, block: FrameBlock, origin: float = 0.0) -> DecodedBlock:
        """The records of ``block``, times counted from ``origin`` (the trace's first frame,
        as ``cobus decode`` shows them)."""
        now = block.time - origin
        parts = _Parts()
        start, n = 0, len(block)
        window = n
        while start < n:
            end = min(n, start + window)
            stop = self._segment(block, now, start, end, parts)
            # After a mapping changed, a short stretch, longer while none changes (a trace
            # of many PDO writes is not read again to its block's end at each one).
            window = max(64, 2 * (stop - start)) if stop < end else 2 * window
            start = stop
        errors = np.flatnonzero((block.flags & ERROR) != 0)
        skipped = np.flatnonzero(_skipped(block.flags, block.dlc) & ((block.flags & ERROR) == 0))
        return parts.done(now, errors, skipped)

    def _segment(
        self,
        block: FrameBlock,
        now: npt.NDArray[np.float64],
        start: int,
        end: int,
        parts: _Parts,
    ) -> int:
        """Decode rows ``start:end`` with the PDO mappings known now; where an SDO in them
        changes a mapping, stop after it and return where to go on (else ``end``)."""
        dec = self.decoder
        generation = dec._pdo_generation
        cob = block.cob_id[start:end]
        flags = block.flags[start:end]
        dlc = block.dlc[start:end]
        data = block.data[start:end]
        times = now[start:end]
        bad = _skipped(flags, dlc)
        plain = ((flags & (EXTENDED | REMOTE)) == 0) & ~bad
        if dec._pdos:
            keys = np.fromiter(dec._pdos, dtype=np.uint32, count=len(dec._pdos))
            # (a PDO moved onto an SDO COB-ID still counts in the SDO latencies: in order)
            sdo = ((cob > SDO_TX_BASE) & (cob <= SDO_TX_BASE + MAX_NODE_ID)) | (
                (cob > SDO_RX_BASE) & (cob <= SDO_RX_BASE + MAX_NODE_ID)
            )
            is_pdo = plain & np.isin(cob, keys) & ~sdo
            rest = plain & ~is_pdo & ~sdo
        else:
            is_pdo = np.zeros(len(cob), dtype=bool)
            rest = plain
        sync = rest & (cob == SYNC_COB_ID)
        state = data[:, 0] & 0x7F
        beat = (
            rest
            & (cob > ERROR_CONTROL_BASE)
            & (cob <= ERROR_CONTROL_BASE + MAX_NODE_ID)
            & (dlc == 1)
            & (state != 0)
        )
        raw_pdo = rest & (cob >= TPDO_BASE) & (cob < SDO_TX_BASE)
        slow = ~(is_pdo | sync | beat | raw_pdo | bad)

        slow_rows = np.flatnonzero(slow)
        beat_rows = np.flatnonzero(beat)
        tables = self._pdo_tables(start, cob, dlc, data, times, is_pdo, raw_pdo)
        sw_rows, sw_events = _statusword_events(tables, slow_rows, start)
        # The frames taken one by one, in order: those of the exact decoder (0), heartbeats
        # (1: their statistics) and statuswords that may change a drive's state (2).
        rows = [slow_rows, beat_rows, sw_rows]
        kinds = [np.full(len(r), k, np.int8) for k, r in enumerate(rows)]
        refs = [np.arange(len(r)) for r in rows]
        all_rows = np.concatenate(rows)
        order = np.argsort(all_rows, kind="stable")
        beat_nodes = (cob[beat_rows] - ERROR_CONTROL_BASE).tolist()
        beat_states = state[beat_rows].tolist()
        demoted: list[int] = []
        time_list = times.tolist()
        stop = end
        guard_asked, toggle = dec._guard_asked, dec._toggle
        for row, kind, ref in zip(
            all_rows[order].tolist(),
            np.concatenate(kinds)[order].tolist(),
            np.concatenate(refs)[order].tolist(),
            strict=True,
        ):
            t = time_list[row]
            if kind == 1:
                node = beat_nodes[ref]
                if node not in guard_asked:
                    toggle.pop(node, None)
                    name = _STATES.get(beat_states[ref], f"state {beat_states[ref]:02X}h")
                    dec.node_stats(node)._heartbeat(t, name)
                    continue
                demoted.append(ref)  # (it may answer the guarding request: in order)
            elif kind == 2:
                pdo, axis, value = sw_events[ref]
                if pdo.stats is None:
                    pdo.stats = dec.node_stats(pdo.node)
                pdo.stats._statusword(t, value, axis)
                continue
            parts.records_at.append((start + row, dec.feed(_frame(block, start + row), t)))
            if dec._pdo_generation != generation:  # a mapping changed: go on with the new
                stop = start + row + 1
                break

        kept = stop - start
        beats = np.delete(beat_rows, demoted) if demoted else beat_rows
        beats = beats[beats < kept]
        parts.heartbeats.append(
            (beats + start, times[beats], cob[beats] - ERROR_CONTROL_BASE, state[beats])
        )
        syncs = np.flatnonzero(sync[:kept])
        counter = np.where(dlc[syncs] > 0, data[syncs, 0].astype(np.int16), -1).astype(np.int16)
        parts.syncs.append((syncs + start, times[syncs], counter))
        for table, _ in tables:
            cut = int(np.searchsorted(table.index, stop))
            if cut:
                parts.pdos.append(table if cut == len(table) else table._cut(cut))
        return stop

    def _pdo_tables(
        self,
        start: int,
        cob: npt.NDArray[np.uint32],
        dlc: npt.NDArray[np.uint8],
        data: npt.NDArray[np.uint8],
        times: npt.NDArray[np.float64],
        is_pdo: npt.NDArray[np.bool_],
        raw_pdo: npt.NDArray[np.bool_],
    ) -> list[tuple[PdoColumns, _Pdo | None]]:
        """A table per COB-ID of the PDO frames of the segment from row ``start``, in the
        order of their first frame."""
        rows = np.flatnonzero(is_pdo | raw_pdo)
        if not len(rows):
            return []
        ids = cob[rows]
        order = np.argsort(ids, kind="stable")
        sorted_ids = ids[order]
        bounds = np.flatnonzero(np.diff(sorted_ids)) + 1
        groups = np.split(order, bounds)
        out: list[tuple[PdoColumns, _Pdo | None]] = []
        for group in groups:
            at = rows[group]
            key = int(cob[at[0]])
            pdo = self.decoder._pdos.get(key) if is_pdo[at[0]] else None
            out.append((_table(key, pdo, at + start, times[at], dlc[at], data[at]), pdo))
        out.sort(key=lambda item: int(item[0].index[0]))
        return out


class _Parts:
    """A block's tables as its segments make them."""

    def __init__(self) -> None:
        self.records_at: list[tuple[int, list[TraceRecord]]] = []
        self.syncs: list[tuple[Any, Any, Any]] = []
        self.heartbeats: list[tuple[Any, Any, Any, Any]] = []
        self.pdos: list[PdoColumns] = []

    def done(self, now: npt.NDArray[np.float64], errors: _Index, skipped: _Index) -> DecodedBlock:
        def cat(items: list[Any], dtype: Any) -> Any:
            return np.concatenate(items).astype(dtype) if items else np.zeros(0, dtype)

        return DecodedBlock(
            len(now),
            now,
            self.records_at,
            cat([s[0] for s in self.syncs], np.int64),
            cat([s[1] for s in self.syncs], np.float64),
            cat([s[2] for s in self.syncs], np.int16),
            cat([h[0] for h in self.heartbeats], np.int64),
            cat([h[1] for h in self.heartbeats], np.float64),
            cat([h[2] for h in self.heartbeats], np.uint8),
            cat([h[3] for h in self.heartbeats], np.uint8),
            self.pdos,
            errors,
            skipped,
        )


def _skipped(flags: npt.NDArray[np.uint8], dlc: npt.NDArray[np.uint8]) -> Any:
    """Rows the decoder never sees: error frames, CAN FD frames, data frames of more than
    8 bytes (:func:`cobus.runtime.bus.message_to_frame` gives no frame for them)."""
    return ((flags & (ERROR | FD)) != 0) | ((dlc > 8) & ((flags & REMOTE) == 0))


def _statusword_events(
    tables: list[tuple[PdoColumns, _Pdo | None]], slow_rows: _Index, start: int
) -> tuple[_Index, list[tuple[Any, int, Any]]]:
    """The statuswords the PDOs of a segment carry where one may change a drive's state,
    as (row in the segment, (pdo, axis, value)): per drive and axis (its statusword may come
    in several PDOs), the first after any frame the exact decoder takes, and each new
    value."""
    series: dict[tuple[int, int], list[tuple[PdoColumns, _Pdo]]] = {}
    for table, pdo in tables:
        if pdo is not None and pdo.statusword is not None:
            series.setdefault((pdo.node, pdo.axis), []).append((table, pdo))
    found: list[_Index] = []
    events: list[tuple[Any, int, Any]] = []
    for (_, axis), parts in series.items():
        numeric = _numeric(parts)
        if numeric is not None:  # (the usual: integer columns)
            rows, column, has, part = numeric
            order = np.argsort(rows, kind="stable")
            rows, column, has, part = rows[order] - start, column[order], has[order], part[order]
            keep = _kept(rows, (column[1:] != column[:-1]) | (has[1:] != has[:-1]), slow_rows)
            found.append(rows[keep])
            kept = zip(part[keep].tolist(), column[keep].tolist(), has[keep].tolist(), strict=True)
            events.extend((parts[p][1], axis, v if h else None) for p, v, h in kept)
            continue
        rows_of: list[_Index] = []
        values: list[Any] = []
        pdos: list[_Pdo] = []
        for table, pdo in parts:
            column, has = _statuswords(table, pdo.statusword)  # type: ignore[arg-type]
            if isinstance(column, np.ndarray):
                pairs = zip(column.tolist(), has.tolist(), strict=True)
                column = [v if h else None for v, h in pairs]
            if table.rows is not None:  # (a frame too short for the file's mapping: none)
                ok = [bool(values_of) for values_of, _ in table.rows]
                rows_of.append(table.index[np.array(ok, dtype=bool)] - start)
                column = [v for v, good in zip(column, ok, strict=True) if good]
            else:
                rows_of.append(table.index - start)
            values += column
            pdos += [pdo] * len(column)
        rows = np.concatenate(rows_of)
        order = np.argsort(rows, kind="stable")
        rows = rows[order]
        ordered = np.empty(len(values), dtype=object)
        ordered[:] = values
        ordered = ordered[order]
        kinds = np.array([type(v).__name__ for v in ordered], dtype=object)
        keep = _kept(rows, (ordered[1:] != ordered[:-1]) | (kinds[1:] != kinds[:-1]), slow_rows)
        found.append(rows[keep])
        picked = [pdos[i] for i in order[keep].tolist()]
        events.extend((pdo, axis, v) for pdo, v in zip(picked, ordered[keep].tolist(), strict=True))
    if not found:
        return np.zeros(0, dtype=np.int64), events
    rows = np.concatenate(found)
    return rows, events


def _kept(rows: _Index, differs: Any, slow_rows: _Index) -> _Index:
    """Which of a drive's statuswords (at ``rows``, each ``differs`` from the one before)
    may change its state: the first, each new one, the first after a frame the exact
    decoder took (it may have read the statusword by SDO)."""
    changed = np.ones(len(rows), dtype=bool)
    changed[1:] = differs
    before = np.searchsorted(slow_rows, rows)
    changed[1:] |= before[1:] != before[:-1]
    return np.flatnonzero(changed)


def _numeric(parts: list[tuple[PdoColumns, _Pdo]]) -> tuple[Any, Any, Any, Any] | None:
    """The statuswords of a drive's PDOs as one column (rows, values, whether each frame
    carries it, which PDO), where each is an integer column (of at most 32 bits, when
    several PDOs are put together as int64)."""
    rows, columns, hases, which = [], [], [], []
    for n, (table, pdo) in enumerate(parts):
        if table.rows is not None:
            return None
        column, has = _statuswords(table, pdo.statusword)  # type: ignore[arg-type]
        if not isinstance(column, np.ndarray) or column.dtype.kind not in "iu":
            return None
        if len(parts) > 1 and column.dtype.itemsize > 4:
            return None
        rows.append(table.index)
        columns.append(column if len(parts) == 1 else column.astype(np.int64))
        hases.append(has)
        which.append(np.full(len(table), n, dtype=np.int64))
    return (
        np.concatenate(rows),
        np.concatenate(columns),
        np.concatenate(hases),
        np.concatenate(which),
    )


def _statuswords(table: PdoColumns, name: str) -> tuple[Any, Any]:
    """The statusword ``name`` of each frame of ``table``: a numpy column and whether each
    frame carries it, or a list (None where a frame does not carry it) and None."""
    if table.rows is not None:
        return [values.get(name) for values, _ in table.rows], None
    column = table.columns[name]
    assert table.present is not None
    has = table.present > table.names.index(name)
    if isinstance(column, np.ndarray):
        return column, has
    return [v if h else None for v, h in zip(column, has.tolist(), strict=True)], None


def _frame(block: FrameBlock, row: int) -> Frame:
    """Row ``row`` of ``block`` as the frame python-can's message gives
    (:func:`cobus.runtime.bus.message_to_frame`)."""
    frame: Frame = _new_frame(Frame)
    flags = int(block.flags[row])
    frame.cob_id = int(block.cob_id[row])
    frame.extended = bool(flags & EXTENDED)
    dlc = int(block.dlc[row])
    if flags & REMOTE:
        frame.rtr = True
        frame.data = b""
        frame.dlc = min(dlc, 8)
    else:
        frame.rtr = False
        frame.data = block.data[row, :dlc].tobytes()
        frame.dlc = dlc
    return frame


def _table(
    cob: int,
    pdo: _Pdo | None,
    rows: _Index,
    times: npt.NDArray[np.float64],
    dlc: npt.NDArray[np.uint8],
    data: npt.NDArray[np.uint8],
) -> PdoColumns:
    if pdo is None:  # no mapping names it: node and number from the COB-ID
        k = (cob - TPDO_BASE) >> 7
        return PdoColumns(cob, cob & 0x7F, k // 2 + 1, k % 2 == 0, rows, times, dlc, data)
    table = PdoColumns(cob, pdo.node, pdo.number, pdo.tpdo, rows, times, dlc, data)
    if pdo.layout is not None:  # a network file's signals: scaled row by row
        table.names = tuple(name for name, _ in pdo.named)
        buf = data.tobytes()
        sizes = dlc.tolist()
        table.rows = [pdo_values(pdo, buf[8 * i : 8 * i + sizes[i]]) for i in range(len(sizes))]
        return table
    words = np.ascontiguousarray(data).view("<u8").ravel()
    have = dlc.astype(np.int64) * 8
    names: list[str] = []
    bit = 0
    for name, data_type, bits in pdo.entries:
        if bit + bits > 64:  # (never in a frame: it and those after it are never values)
            break
        if name is None:  # a dummy entry: a gap
            bit += bits
            continue
        chunk = (words >> np.uint64(bit)) & np.uint64((1 << bits) - 1)
        names.append(name)
        table.columns[name] = _column(data_type, bits, chunk)
        bit += bits
    table.names = tuple(names)
    # (an entry past the frame's end ends the values: the ones after it are not counted)
    table.present = _present(pdo, have)
    return table


def _present(pdo: _Pdo, have: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
    """How many named values each row carries: the named entries before the first entry
    (dummy or not) that reaches past the frame's end."""
    count = np.zeros(len(have), dtype=np.int64)
    alive = np.ones(len(have), dtype=bool)
    bit = 0
    for name, _, bits in pdo.entries:
        if bit + bits > 64:
            break
        alive &= have >= bit + bits
        if name is not None:
            count += alive
        bit += bits
    return count


def _narrowest(bits: int, *, signed: bool) -> Any:
    """The numpy integer type of the fewest bytes that holds ``bits`` bits."""
    for size, (s, u) in ((8, (np.int8, np.uint8)), (16, (np.int16, np.uint16))):
        if bits <= size:
            return s if signed else u
    if bits <= 32:
        return np.int32 if signed else np.uint32
    return np.int64 if signed else np.uint64


def _column(data_type: DataType, bits: int, chunk: npt.NDArray[np.uint64]) -> Any:
    """The values of an entry of ``bits`` bits of ``data_type`` (as the frame path's
    :func:`~cobus.trace.decoder.pdo_values` gives them)."""
    size = data_type.size or (bits + 7) // 8
    integer = data_type.is_integer
    if bits != 8 * size or (integer and not data_type.is_signed):  # (part of a byte: bits)
        return chunk.astype(_narrowest(bits, signed=False))
    if integer:
        if bits == 64:
            return chunk.view(np.int64)
        signed = chunk.astype(np.int64)
        signed -= ((signed >> (bits - 1)) & 1) * (1 << bits)
        return signed.astype(_narrowest(bits, signed=True))
    if data_type == DataType.REAL32:
        return chunk.astype(np.uint32).view(np.float32)
    if data_type == DataType.REAL64:
        return chunk.view(np.float64)
    if data_type == DataType.BOOLEAN:
        return chunk != 0
    out: list[Any] = []  # (strings, times of day...: as the frame path, value by value)
    for raw in chunk.tolist():
        try:
            out.append(decode(data_type, raw.to_bytes(size, "little")))
        except ValueError:
            out.append(raw)
    return out
