"""A trace as tables for analysis: ``cobus decode FILE --to parquet DIR`` (or ``csv``).

One table per kind of record, one file each in ``DIR``, what pandas, polars and DuckDB read
directly::

    sync          time, counter
    heartbeat     time, cob_id, node, state
    node10_tpdo1  time, cob_id, dlc, data, then a typed column per value by its EDS name
                  (null where a frame was too short for it)
    sdo           time, cob_id, node, write, index, subindex, data, mode, duration, ...
    emcy, nmt, bootup, guard_request, guard_response, time, lss, lss_session,
    sdo_block_frame, other (frames no service claims)

A PDO whose mapping changes in the trace gets a table per mapping (``node10_tpdo1_2``...);
the PDOs no dictionary maps share the table ``pdo`` (time, cob_id, node, number, tpdo,
dlc, data). Times count from the trace's first frame; ``trace.json`` beside the tables
says when that was (the file's own time of it, and in UTC where it is one), how far the
tables go and their rows (Parquet files carry the start in their metadata too). Columns
have one type whatever the table: ``cob_id`` uint32, ``node`` uint8, ``index`` uint16,
``subindex`` uint8, times of day (TIME) UTC timestamps. The frames stream through
:class:`~cobus.trace.batch.BatchDecoder` a block at a time, so memory stays bounded
whatever the trace's length. Parquet needs pyarrow (``pip install 'cobus[parquet]'``); CSV
does not.
"""

from __future__ import annotations

import csv
import dataclasses
import datetime as dt
import json
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import IO, Any

import numpy as np

from cobus.errors import CobusError
from cobus.proto.connection_set import ERROR_CONTROL_BASE
from cobus.trace.batch import BatchDecoder, DecodedBlock, PdoColumns
from cobus.trace.blocks import FrameBlock
from cobus.trace.decoder import _STATES, Heartbeat, PdoRecord, SyncRecord, TraceRecord

__all__ = ["DESCRIPTION", "FORMATS", "ExportError", "TraceExport"]

#: What ``--to`` writes.
FORMATS = ("parquet", "csv")

#: The file beside the tables that says what they hold.
DESCRIPTION = "trace.json"

#: Record fields of one column type in every table, whatever their annotations say.
_FIELD_TYPES = {
    "cob_id": "uint32",
    "node": "uint8",
    "target": "uint8",
    "index": "uint16",
    "subindex": "uint8",
    "code": "uint16",
    "register": "uint8",
    "abort_code": "uint32",
    "command": "uint8",
}

_TABLES = {
    "SdoTransfer": "sdo",
    "SdoBlockFrame": "sdo_block_frame",
    "EmergencyRecord": "emcy",
    "NmtCommandRecord": "nmt",
    "Bootup": "bootup",
    "GuardRequest": "guard_request",
    "GuardResponse": "guard_response",
    "TimeRecord": "time",
    "LssFrame": "lss",
    "LssSession": "lss_session",
    "Unknown": "other",
}


class ExportError(CobusError, ValueError):
    """A trace that cannot be written as tables (the format, the folder)."""


class TraceExport:
    """Writes decoded blocks as tables in ``folder``, as ``fmt`` ("parquet" or "csv").
    ``kinds`` and ``node`` keep only those records (as ``--filter`` and ``--node``).

    >>> export = TraceExport(Path("out"), "parquet", BatchDecoder({10: od}))
    >>> export.write(blocks("bench.blf"))
    {'sync': 60000, 'heartbeat': 6000, 'node10_tpdo1': 60000, 'sdo': 12}
    """

    def __init__(
        self,
        folder: Path,
        fmt: str,
        decoder: BatchDecoder,
        *,
        kinds: set[str] | None = None,
        node: int | None = None,
        source: str | None = None,
    ) -> None:
        if fmt not in FORMATS:
            raise ExportError(f"--to {fmt}: choose {' or '.join(FORMATS)}")
        if fmt == "parquet":
            try:
                import pyarrow  # noqa: F401
            except ImportError:
                raise ExportError(
                    "--to parquet needs pyarrow: pip install 'cobus[parquet]' (or use --to csv)"
                ) from None
        if folder.exists() and not folder.is_dir():
            raise ExportError(f"{folder}: a file, not a folder (the tables go into a folder)")
        if folder.is_dir() and any(folder.iterdir()):
            raise ExportError(f"{folder}: not an empty folder (the tables go into one)")
        self.folder = folder
        self.fmt = fmt
        self.decoder = decoder
        self.kinds = kinds
        self.node = node
        self.source = source
        #: The trace's first frame's time as the file gives it (None: no frame yet).
        self.start: float | None = None
        #: Table name -> rows written.
        self.rows: dict[str, int] = {}
        self._writers: dict[str, _Writer] = {}
        self._pdo_names: dict[tuple[Any, ...], str] = {}
        #: Frames read and written so far, the time of the last (from the first), and
        #: whether ``stop`` ended the writing early.
        self.frames = 0
        self.end = 0.0
        self.stopped = False
        #: Frames that are in no table: error frames, and CAN FD frames (CiA 301 has none).
        self.error_frames = 0
        self.fd_frames = 0
        _more_files()

    def write(
        self, blocks: Iterable[FrameBlock], stop: Callable[[], bool] | None = None
    ) -> dict[str, int]:
        """Decode and write ``blocks`` (a trace's), then close the files; the rows written
        per table. ``stop()`` is asked between blocks (Ctrl-C): when true, the tables end
        there, all at the same frame (:attr:`frames`, :attr:`stopped`)."""
        first: float | None = None
        end = 0.0
        try:
            self.folder.mkdir(parents=True, exist_ok=True)  # (an empty trace: an empty folder)
            for block in blocks:
                if not len(block):
                    continue
                if first is None:
                    first = self.start = float(block.time[0])
                end = float(block.time[-1]) - first
                self.add(self.decoder.decode(block, first))
                self.frames += len(block)
                self.end = end
                if stop is not None and stop():
                    self.stopped = True
                    break
            else:
                self._records([(0, rec) for rec in self.decoder.flush(end)])
        finally:
            try:
                self.close()
            finally:
                self._describe()
        return dict(self.rows)

    def _describe(self) -> None:
        """``trace.json``: what the folder holds, from where and when."""
        suffix = ".parquet" if self.fmt == "parquet" else ".csv"
        about = {
            "source": self.source,
            "format": self.fmt,
            "start": self.start,
            "start_utc": _utc(self.start),
            "frames": self.frames,
            "end": self.end,
            "stopped": self.stopped,
            "tables": {n: {"file": n + suffix, "rows": r} for n, r in self.rows.items()},
            "error_frames": self.error_frames,
            "fd_frames": self.fd_frames,
        }
        path = self.folder / DESCRIPTION
        try:
            path.write_text(json.dumps(about, indent=2) + "\n", encoding="utf-8")
        except OSError as exc:
            raise ExportError(f"cannot write {path}: {_why(exc)}") from None

    def add(self, decoded: DecodedBlock) -> None:
        """Write the tables of one decoded block."""
        self.error_frames += len(decoded.errors)
        self.fd_frames += len(decoded.skipped)
        wanted = self.kinds
        node = self.node
        slow = self._records([(row, r) for row, recs in decoded.records_at for r in recs])
        if (wanted is None or "sync" in wanted) and node is None:
            counters = decoded.sync_counter.tolist()
            rows = decoded.sync_index.tolist()
            merged = sorted(
                [
                    *zip(rows, decoded.sync_time.tolist(), counters, strict=True),
                    *((row, r.time, r.counter) for row, r in slow.get("sync", [])),
                ]
            )
            self._put(
                "sync",
                merged,
                {
                    "time": [m[1] for m in merged],
                    "counter": [None if m[2] is None or m[2] < 0 else m[2] for m in merged],
                },
                _SYNC,
            )
        if wanted is None or "hb" in wanted:
            chosen = slice(None) if node is None else decoded.heartbeat_node == node
            states = [
                _STATES.get(s, f"state {s:02X}h") for s in decoded.heartbeat_state[chosen].tolist()
            ]
            beats = sorted(
                [
                    *zip(
                        decoded.heartbeat_index[chosen].tolist(),
                        decoded.heartbeat_time[chosen].tolist(),
                        decoded.heartbeat_node[chosen].tolist(),
                        states,
                        strict=True,
                    ),
                    *((row, r.time, r.node, r.state) for row, r in slow.get("heartbeat", [])),
                ]
            )
            self._put(
                "heartbeat",
                beats,
                {
                    "time": [b[1] for b in beats],
                    "cob_id": [ERROR_CONTROL_BASE + b[2] for b in beats],
                    "node": [b[2] for b in beats],
                    "state": [b[3] for b in beats],
                },
                _HEARTBEAT,
            )
        if wanted is None or "pdo" in wanted:
            unmapped: list[PdoColumns] = []
            pdos = [*decoded.pdos, *(_one_pdo(row, rec) for row, rec in slow.get("pdo", []))]
            pdos.sort(key=lambda t: int(t.index[0]))  # (a name goes to the first mapping)
            for table in pdos:
                if node is not None and table.node != node:
                    continue
                if table.present is None and table.rows is None:  # no mapping names it
                    unmapped.append(table)
                else:
                    self._pdo(table)
            if unmapped:
                self._unmapped(unmapped)

    def close(self) -> None:
        """Finish every file (a Parquet file is unreadable before); every one, even where
        one fails (then :class:`ExportError` naming it)."""
        failed: ExportError | None = None
        for writer in self._writers.values():
            try:
                writer.close()
            except OSError as exc:
                failed = failed or ExportError(f"cannot write {writer.path}: {_why(exc)}")
        self._writers.clear()
        if failed is not None:
            raise failed

    # ------------------------------------------------------------------ tables

    def _records(self, pairs: list[tuple[int, TraceRecord]]) -> dict[str, list[Any]]:
        """Write the exact decoder's records (row, record), a table per kind; return the
        heartbeats and SYNCs among them, which go with the block's others."""
        by_table: dict[str, list[Any]] = {}
        for row, rec in pairs:
            if self.kinds is not None and rec.kind not in self.kinds:
                continue
            if self.node is not None and not rec.concerns(self.node):
                continue
            if isinstance(rec, Heartbeat):
                name = "heartbeat"
            elif isinstance(rec, SyncRecord):
                name = "sync"
            elif isinstance(rec, PdoRecord):  # (one the decoder took: on an SDO COB-ID)
                name = "pdo"
            else:
                name = _TABLES.get(type(rec).__name__, "other")
            by_table.setdefault(name, []).append((row, rec))
        for name, found in by_table.items():
            if name not in ("heartbeat", "sync", "pdo"):
                columns, types = _record_columns([rec for _, rec in found])
                self._put(name, found, columns, types)
        return by_table

    def _unmapped(self, tables: list[PdoColumns]) -> None:
        """The PDOs no mapping names, in one table ``pdo`` in the order of the frames."""
        index = np.concatenate([t.index for t in tables])
        order = np.argsort(index, kind="stable")
        data = np.concatenate([t.data for t in tables])[order]
        dlcs = np.concatenate([t.dlc for t in tables])[order]
        sizes = dlcs.tolist()
        buf = data.tobytes()

        def each(values: list[Any], dtype: Any) -> Any:
            return np.concatenate(
                [np.full(len(t), v, dtype=dtype) for t, v in zip(tables, values, strict=True)]
            )[order]

        self._put(
            "pdo",
            index,
            {
                "time": np.concatenate([t.time for t in tables])[order],
                "cob_id": each([t.cob_id for t in tables], np.uint32),
                "node": each([t.node for t in tables], np.uint8),
                "number": each([t.number for t in tables], np.uint16),
                "tpdo": each([t.tpdo for t in tables], np.bool_),
                "dlc": dlcs,
                "data": [buf[8 * i : 8 * i + n] for i, n in enumerate(sizes)],
            },
            {
                "time": "float64",
                "cob_id": "uint32",
                "node": "uint8",
                "number": "uint16",
                "tpdo": "bool",
                "dlc": "uint8",
                "data": "binary",
            },
        )

    def _pdo(self, table: PdoColumns) -> None:
        types: dict[str, str] = {
            "time": "float64",
            "cob_id": "uint32",
            "dlc": "uint8",
            "data": "binary",
        }
        buf = table.data.tobytes()
        dlcs = table.dlc.tolist()
        columns: dict[str, Any] = {
            "time": table.time,
            "cob_id": np.full(len(table), table.cob_id, dtype=np.uint32),
            "dlc": table.dlc,
            "data": [buf[8 * i : 8 * i + n] for i, n in enumerate(dlcs)],
        }
        frame_columns = set(columns)
        if table.rows is not None:  # a network file's signals, row by row
            names: list[str] = list(table.names)
            for values, _ in table.rows:
                names += [n for n in values if n not in names]
            for name in names:
                listed = [values.get(name) for values, _ in table.rows]
                column_name = _unique(name, frame_columns)
                # (engineering values: float64 whatever a block holds, so every block of a
                # PDO has one table)
                types[column_name] = _signal_type(listed)
                columns[column_name] = _typed(listed, types[column_name])
        else:
            present = table.present.tolist() if table.present is not None else []
            for k, name in enumerate(table.names):
                column = table.columns[name]
                has = [p > k for p in present]
                column_name = _unique(name, frame_columns)
                if isinstance(column, np.ndarray) and all(has):
                    columns[column_name] = column
                    types[column_name] = column.dtype.name if column.dtype.kind != "b" else "bool"
                elif isinstance(column, np.ndarray):
                    columns[column_name] = _nullable(column.tolist(), has)
                    types[column_name] = column.dtype.name if column.dtype.kind != "b" else "bool"
                else:  # (strings, times of day...)
                    listed = _nullable(column, has)
                    types[column_name] = _type_of(listed)
                    columns[column_name] = _typed(listed, types[column_name])
        key = (table.cob_id, table.node, table.number, table.tpdo, tuple(types.items()))
        found = self._pdo_names.get(key)
        if found is None:
            kind = "tpdo" if table.tpdo else "rpdo"
            base = f"node{table.node}_{kind}{table.number}"
            found = base
            taken = set(self._pdo_names.values())
            n = 2
            while found in taken:
                found, n = f"{base}_{n}", n + 1
            self._pdo_names[key] = found
        self._put(found, table.index, columns, types)

    def _put(self, name: str, rows: Any, columns: dict[str, Any], types: dict[str, str]) -> None:
        """Append rows to table ``name`` (its file opened at the first)."""
        count = len(rows)
        if not count:
            return
        writer = self._writers.get(name)
        suffix = ".parquet" if self.fmt == "parquet" else ".csv"
        path = self.folder / f"{name}{suffix}"
        try:
            if writer is None:
                self.folder.mkdir(parents=True, exist_ok=True)
                writer = self._writers[name] = (
                    _ParquetWriter(path, types, self.start)
                    if self.fmt == "parquet"
                    else _CsvWriter(path, types)
                )
            writer.write(columns)
        except OSError as exc:
            raise ExportError(f"cannot write {path}: {_why(exc)}") from None
        self.rows[name] = self.rows.get(name, 0) + count


_HEARTBEAT = {"time": "float64", "cob_id": "uint32", "node": "uint8", "state": "string"}
_SYNC = {"time": "float64", "counter": "int16"}


def _one_pdo(row: int, rec: PdoRecord) -> PdoColumns:
    """A PDO record of the exact decoder as a table of one row."""
    data = np.frombuffer(rec.data.ljust(8, b"\0")[:8], dtype=np.uint8).reshape(1, 8)
    table = PdoColumns(
        rec.cob_id,
        rec.node,
        rec.number,
        rec.tpdo,
        np.array([row], dtype=np.int64),
        np.array([rec.time]),
        np.array([len(rec.data)], dtype=np.uint8),
        data,
    )
    if rec.values:
        table.rows = [(dict(rec.values), dict(rec.units))]
    return table


def _more_files() -> None:
    """As many open files as the system lets this process have: a table is a file, open
    until the end, and a network has hundreds of PDOs."""
    try:
        import resource

        soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
        if hard == resource.RLIM_INFINITY or hard > soft:
            wanted = 1 << 16 if hard == resource.RLIM_INFINITY else hard
            resource.setrlimit(resource.RLIMIT_NOFILE, (max(soft, wanted), hard))
    except (ImportError, ValueError, OSError):  # (not on this system, or not allowed)
        pass


def _why(exc: OSError) -> str:
    return exc.strerror or str(exc)


def _nullable(values: list[Any], has: list[bool]) -> list[Any]:
    return [v if h else None for v, h in zip(values, has, strict=True)]


def _unique(name: str, taken: set[str]) -> str:
    """``name`` as a column beside ``taken`` (a value named "time" or "data" does not
    overwrite the frame's): ``time (value)``, ``time (value 2)``..."""
    found, n = name, 1
    while found in taken:
        found = f"{name} (value)" if n == 1 else f"{name} (value {n})"
        n += 1
    taken.add(found)
    return found


def _signal_type(values: list[Any]) -> str:
    """A network-file signal's column: float64 for numbers (engineering values), else as
    the values are."""
    kinds = {type(v) for v in values if v is not None}
    if not kinds or kinds <= {int, float}:
        return "float64"
    return _type_of(values)


def _typed(values: list[Any], kind: str) -> list[Any]:
    """``values`` as a column of ``kind`` holds them (text where they are of several kinds)."""
    if kind != "string":
        return list(values)
    return [None if v is None else _text(v) for v in values]


def _type_of(values: list[Any]) -> str:
    """The column type of Python values (None: null)."""
    kinds = {type(v) for v in values if v is not None}
    if kinds == {bool}:
        return "bool"
    if kinds and kinds <= {int}:
        return "int64"
    if kinds and kinds <= {int, float}:
        return "float64"
    if kinds == {bytes}:
        return "binary"
    return "string"


def _record_columns(records: list[TraceRecord]) -> tuple[dict[str, Any], dict[str, str]]:
    """The fields of records of one kind as columns (and a ``text`` column: the record in
    words), typed by the fields' annotations."""
    fields = dataclasses.fields(records[0])
    columns: dict[str, Any] = {}
    types: dict[str, str] = {}
    for f in fields:
        values = [getattr(r, f.name) for r in records]
        kind = _annotated(str(f.type))
        if kind == "int64":
            kind = _FIELD_TYPES.get(f.name, kind)
        if kind == "string":
            values = [None if v is None else _text(v) for v in values]
        columns[f.name] = values
        types[f.name] = kind
    columns["text"] = [str(r) for r in records]
    types["text"] = "string"
    return columns, types


def _annotated(annotation: str) -> str:
    parts = {p.strip() for p in annotation.split("|")} - {"None"}
    if parts == {"int"}:
        return "int64"
    if parts == {"float"}:
        return "float64"
    if parts == {"bool"}:
        return "bool"
    if parts == {"bytes"}:
        return "binary"
    if parts == {"dt.datetime"}:
        return "timestamp"
    return "string"


def _text(value: Any) -> str:
    if isinstance(value, str):
        return value
    if isinstance(value, bytes):
        return value.hex(" ")
    if isinstance(value, dict):
        return json.dumps(value, default=str)
    return str(value)


class _Writer:
    path: Path

    def write(self, columns: dict[str, Any]) -> None:
        raise NotImplementedError

    def close(self) -> None:
        raise NotImplementedError


class _ParquetWriter(_Writer):
    def __init__(self, path: Path, types: dict[str, str], start: float | None) -> None:
        import pyarrow as pa
        import pyarrow.parquet as pq

        self._pa = pa
        self.path = path
        about = {"cobus.trace_start": json.dumps(start), "cobus.trace_start_utc": _utc(start) or ""}
        self.schema = pa.schema(
            [(name, _arrow(pa, kind)) for name, kind in types.items()], metadata=about
        )
        self.file = pq.ParquetWriter(str(path), self.schema)

    def write(self, columns: dict[str, Any]) -> None:
        pa = self._pa
        arrays = [pa.array(columns[f.name], type=f.type, from_pandas=False) for f in self.schema]
        self.file.write_table(pa.Table.from_arrays(arrays, schema=self.schema))

    def close(self) -> None:
        self.file.close()


def _arrow(pa: Any, kind: str) -> Any:
    if kind == "string":
        return pa.string()
    if kind == "binary":
        return pa.binary()
    if kind == "bool":
        return pa.bool_()
    if kind == "timestamp":
        return pa.timestamp("ms", tz="UTC")  # (CiA 301's TIME counts milliseconds)
    return pa.from_numpy_dtype(np.dtype(kind))


class _CsvWriter(_Writer):
    def __init__(self, path: Path, types: dict[str, str]) -> None:
        self.types = types
        self.path = path
        self.handle: IO[str] = path.open("w", newline="", encoding="utf-8")
        self.csv = csv.writer(self.handle)
        self.csv.writerow(list(types))

    def write(self, columns: dict[str, Any]) -> None:
        listed = [_csv_column(columns[name], kind) for name, kind in self.types.items()]
        self.csv.writerows(zip(*listed, strict=True))

    def close(self) -> None:
        self.handle.close()


def _csv_column(values: Any, kind: str) -> list[Any]:
    if isinstance(values, np.ndarray):
        values = values.tolist()
    if kind == "binary":
        return ["" if v is None else v.hex() for v in values]
    if kind == "float64" or kind == "float32":
        return ["" if v is None else repr(v) for v in values]
    if kind == "timestamp":
        return ["" if v is None else v.isoformat(timespec="milliseconds") for v in values]
    return list(values)


def _utc(when: float | None) -> str | None:
    """``when`` as a UTC date and time, where it is one (a time since 1970 between 2000 and
    2100: what loggers write); None for a trace whose times count from its start."""
    if when is None or not 946_684_800 <= when < 4_102_444_800:
        return None
    moment = dt.datetime.fromtimestamp(when, tz=dt.UTC)
    return moment.isoformat(timespec="microseconds").replace("+00:00", "Z")
