"""``cobus decode``'s lines from a decoded block: the bulk (SYNC, heartbeats, PDOs) from its
columns with one format string per PDO, everything else record by record — the same text
and the same JSON as a record's ``str`` and ``json.dumps`` give, character for character."""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from typing import Any

import numpy as np

from cobus.proto.connection_set import ERROR_CONTROL_BASE
from cobus.trace.batch import DecodedBlock, PdoColumns
from cobus.trace.decoder import _STATES, TraceRecord

__all__ = ["block_lines"]

_Emit = Callable[[TraceRecord], "str | None"]


def block_lines(
    decoded: DecodedBlock,
    emit: _Emit,
    *,
    as_json: bool,
    kinds: set[str] | None,
    node: int | None,
    error_frames: bool,
    stamp: Callable[[float], str] | None = None,
) -> list[str]:
    """The lines of ``decoded`` in the order of its frames. ``emit`` gives a record's line
    (None: filtered out), for the records the columns do not make; ``kinds`` and ``node``
    filter as ``--filter`` and ``--node``; ``error_frames``: a line per error frame.
    ``stamp``: the times of day (``--absolute``) of error frames, where every record goes
    through ``emit``."""
    if stamp is not None:
        return _by_record(decoded, emit, error_frames, stamp)
    slots: list[str | None] = [None] * decoded.size
    for row, records in decoded.records_at:
        texts = [line for line in map(emit, records) if line is not None]
        if texts:
            slots[row] = "\n".join(texts)
    times = decoded.time
    if error_frames:
        for row, t in zip(decoded.errors.tolist(), times[decoded.errors].tolist(), strict=True):
            slots[row] = f"{t:12.6f}  error frame"
    if (kinds is None or "sync" in kinds) and node is None:
        _syncs(decoded, slots, as_json)
    if kinds is None or "hb" in kinds:
        _heartbeats(decoded, slots, as_json, node)
    if kinds is None or "pdo" in kinds:
        for table in decoded.pdos:
            if node is None or table.node == node:
                _pdos(table, slots, as_json, emit)
    return [line for line in slots if line is not None]


def _by_record(
    decoded: DecodedBlock, emit: _Emit, error_frames: bool, stamp: Callable[[float], str]
) -> list[str]:
    out: list[str] = []
    errors = set(decoded.errors.tolist()) if error_frames else set()
    times = decoded.time
    for row, slot in enumerate(decoded.slots()):
        if slot is None:
            if row in errors:
                out.append(f"{stamp(float(times[row]))}  error frame")
            continue
        for rec in slot if type(slot) is list else [slot]:
            line = emit(rec)
            if line is not None:
                out.append(line)
    return out


def _syncs(decoded: DecodedBlock, slots: list[str | None], as_json: bool) -> None:
    rows = decoded.sync_index.tolist()
    times = decoded.sync_time.tolist()
    counters = decoded.sync_counter.tolist()
    if as_json:
        with_counter = (
            '{"kind": "sync", "text": "SYNC %d", "time": %r, "cob_id": 128, "counter": %d}'
        )
        without = '{"kind": "sync", "text": "SYNC", "time": %r, "cob_id": 128, "counter": null}'
        for row, t, counter in zip(rows, times, counters, strict=True):
            slots[row] = with_counter % (counter, t, counter) if counter >= 0 else without % t
        return
    for row, t, counter in zip(rows, times, counters, strict=True):
        slots[row] = f"{t:12.6f}  SYNC {counter}" if counter >= 0 else f"{t:12.6f}  SYNC"


def _heartbeats(
    decoded: DecodedBlock, slots: list[str | None], as_json: bool, node: int | None
) -> None:
    nodes = decoded.heartbeat_node
    chosen = slice(None) if node is None else nodes == node
    rows = decoded.heartbeat_index[chosen].tolist()
    times = decoded.heartbeat_time[chosen].tolist()
    states = [_STATES.get(s, f"state {s:02X}h") for s in decoded.heartbeat_state[chosen].tolist()]
    listed = nodes[chosen].tolist()
    if as_json:
        shape = (
            '{"kind": "hb", "text": "node %d heartbeat %s", "time": %r, "cob_id": %d, '
            '"node": %d, "state": "%s"}'
        )
        for row, t, n, state in zip(rows, times, listed, states, strict=True):
            slots[row] = shape % (n, state, t, ERROR_CONTROL_BASE + n, n, state)
        return
    for row, t, n, state in zip(rows, times, listed, states, strict=True):
        slots[row] = f"{t:12.6f}  node {n} heartbeat {state}"


def _pdos(table: PdoColumns, slots: list[str | None], as_json: bool, emit: _Emit) -> None:
    shapes = _Shapes.of(table, as_json)
    if shapes is None:  # values numpy has no column for: record by record
        for row, rec in zip(table.index.tolist(), table.records(), strict=True):
            slots[row] = emit(rec)
        return
    rows = table.index.tolist()
    times = table.time.tolist()
    dlcs = table.dlc.tolist()
    buf = table.data.tobytes()
    columns = [shapes.listed(table, name) for name in table.names]
    texts = [c if t is None else t for c, t in zip(columns, shapes.texts(table), strict=True)]
    present = [0] * len(rows) if table.present is None else table.present.tolist()
    full = len(table.names)
    for i, (row, t) in enumerate(zip(rows, times, strict=True)):
        k = present[i]
        if k == 0:  # no value (no mapping, or too short for the first): the bytes
            hexed = buf[8 * i : 8 * i + dlcs[i]].hex(" ")
            shown = hexed or "(no data)"
            slots[row] = shapes.shape(0) % ((shown, t, hexed) if as_json else (t, shown))
        elif as_json:
            hexed = buf[8 * i : 8 * i + dlcs[i]].hex(" ")
            slots[row] = shapes.shape(k) % (
                *[c[i] for c in texts[:k]],
                t,
                hexed,
                *[c[i] for c in columns[:k]],
            )
        elif k == full:
            slots[row] = shapes.shape(k) % (t, *[c[i] for c in texts])
        else:
            slots[row] = shapes.shape(k) % (t, *[c[i] for c in texts[:k]])


class _Shapes:
    """A PDO table's line shapes (%-format strings) by the number of values a frame has."""

    def __init__(self, table: PdoColumns, as_json: bool) -> None:
        self.table = table
        self.as_json = as_json
        self._made: dict[int, str] = {}
        kind = "TPDO" if table.tpdo else "RPDO"
        number = f"{kind}{table.number}" if table.number else "PDO"
        who = f"node {table.node} " if table.node is not None else ""
        self.head = f"{who}{number} "

    @classmethod
    def of(cls, table: PdoColumns, as_json: bool) -> _Shapes | None:
        """The shapes, or None where a value has no column of numbers (strings...)."""
        if table.rows is not None:
            return None
        for name in table.names:
            column = table.columns[name]
            if not isinstance(column, np.ndarray) or column.dtype.kind not in "uifb":
                return None
        return cls(table, as_json)

    def listed(self, table: PdoColumns, name: str) -> list[Any]:
        """A column as the line shows its values: JSON's numbers (true/false, NaN,
        Infinity) with --json, else the values themselves."""
        column = table.columns[name]
        if not self.as_json:
            return list(column.tolist())
        if column.dtype.kind == "b":
            return ["true" if v else "false" for v in column.tolist()]
        if column.dtype.kind == "f":
            return [_json_float(v) for v in column.tolist()]
        return [str(v) for v in column.tolist()]

    def texts(self, table: PdoColumns) -> list[list[str] | None]:
        """Per value, its text in the record's words (repr) where it differs from
        :meth:`listed` (JSON mode), else None."""
        if not self.as_json:
            return [None] * len(table.names)
        out: list[list[str] | None] = []
        for name in table.names:
            column = table.columns[name]
            if column.dtype.kind in "bf":
                out.append([_json_text(repr(v)) for v in column.tolist()])
            else:
                out.append(None)
        return out

    def shape(self, k: int) -> str:
        found = self._made.get(k)
        if found is None:
            found = self._made[k] = self._make(k)
        return found

    def _make(self, k: int) -> str:
        """The shape of a frame with the first ``k`` values (0: the bytes shown)."""
        names = self.table.names[:k]
        if not self.as_json:
            body = ", ".join(_pct(name) + "=%r" for name in names) if k else "%s"
            return "%12.6f  " + _pct(self.head) + body
        text = ", ".join(_pct(_json_text(name)) + "=%s" for name in names) if k else "%s"
        values = ", ".join(_pct(json.dumps(name)) + ": %s" for name in names)
        return (
            '{"kind": "pdo", "text": "'
            + _pct(_json_text(self.head))
            + text
            + '", "time": %r, '
            + _pct(_fixed(self.table))
            + ', "data": "%s", "values": {'
            + values
            + '}, "units": {}}'
        )


def _fixed(table: PdoColumns) -> str:
    """The record's fields between time and data, as json.dumps writes them."""
    return ", ".join(
        f"{json.dumps(k)}: {json.dumps(v)}"
        for k, v in (
            ("cob_id", table.cob_id),
            ("node", table.node),
            ("number", table.number),
            ("tpdo", table.tpdo),
        )
    )


def _pct(text: str) -> str:
    return text.replace("%", "%%")


def _json_text(text: str) -> str:
    """``text`` inside a JSON string, as json.dumps escapes it."""
    return json.dumps(text)[1:-1]


def _json_float(value: float) -> str:
    if math.isfinite(value):
        return repr(value)
    if math.isnan(value):
        return "NaN"
    return "Infinity" if value > 0 else "-Infinity"
