"""``cobus decode FILE --to parquet|csv DIR``: a table per kind of record and per PDO, its
values as typed columns by their EDS names, the same records as the decoder's (issue 45)."""

from __future__ import annotations

import csv
import json
import math
from collections import Counter
from pathlib import Path
from typing import Any

import can
import numpy as np
import pyarrow.parquet as pq
import pytest

from cobus.cli import main
from cobus.master import load_network
from cobus.trace.batch import BatchDecoder, PdoColumns
from cobus.trace.blocks import message_blocks
from cobus.trace.export import _TABLES, ExportError, TraceExport

from .test_trace_batch import (
    LINE,
    _decoders,
    _dictionaries,
    _frame_by_frame,
    _msg,
    _odd_eds,
    _random_trace,
    _servo_od,
    _session,
)

_TABLE_OF = {**_TABLES, "SyncRecord": "sync", "Heartbeat": "heartbeat"}


def _messages() -> list[can.Message]:
    return [m for m in _random_trace(3, 2_000) if not m.is_fd] + _session()


def _export(messages: list[can.Message], folder: Path, fmt: str, **options: Any) -> Any:
    export = TraceExport(folder, fmt, BatchDecoder(_dictionaries(), load_network(LINE)), **options)
    return export.write(message_blocks(messages, 700))


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a):
        return math.isnan(b)
    return bool(a == b)


@pytest.mark.parametrize("fmt", ["parquet", "csv"])
def test_every_record_lands_in_its_table(fmt: str, tmp_path: Path) -> None:
    messages = _messages()
    records = _frame_by_frame(_decoders()[0], messages)
    rows = _export(messages, tmp_path / "out", fmt)
    expected = Counter(_TABLE_OF.get(type(r).__name__, "?") for r in records if r.kind != "pdo")
    assert {k: v for k, v in rows.items() if k in expected} == dict(expected)
    pdo_rows = sum(v for k, v in rows.items() if k not in expected)
    assert pdo_rows == sum(1 for r in records if r.kind == "pdo")
    suffix = "." + fmt
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == sorted(
        [*(name + suffix for name in rows), "trace.json"]
    )


def test_parquet_columns_are_typed_and_hold_the_records_values(tmp_path: Path) -> None:
    messages = _messages()
    records = _frame_by_frame(_decoders()[0], messages)
    rows = _export(messages, tmp_path / "out", "parquet")
    # SYNC: the counter, null where the frame has none
    sync = pq.read_table(tmp_path / "out/sync.parquet").to_pylist()
    syncs = [r for r in records if type(r).__name__ == "SyncRecord"]
    assert [(s["time"], s["counter"]) for s in sync] == [(r.time, r.counter) for r in syncs]
    # heartbeats in the order of the frames, those after a guarding request among them
    beats = pq.read_table(tmp_path / "out/heartbeat.parquet").to_pylist()
    expected = [r for r in records if type(r).__name__ == "Heartbeat"]
    assert [(b["time"], b["node"], b["state"]) for b in beats] == [
        (r.time, r.node, r.state) for r in expected
    ]
    # the servo's PDOs: the values by their names, typed; a remap gives a second table
    assert {"node5_tpdo1", "node5_tpdo1_2", "node10_tpdo1"} <= set(rows)
    table = pq.read_table(tmp_path / "out/node10_tpdo1.parquet")
    names = [f.name for f in table.schema]
    assert names[:4] == ["time", "cob_id", "dlc", "data"]
    statusword = next(n for n in names if "tatusword" in n)
    assert str(table.schema.field(statusword).type) == "uint16"
    # every PDO row of every table is a record's, value for value (null: not in the frame)
    pdos: dict[tuple[float, int], list[Any]] = {}
    for r in records:
        if r.kind == "pdo":
            pdos.setdefault((r.time, r.cob_id), []).append(r)
    seen = 0
    for name in rows:
        if not (name.startswith("node") or name == "pdo"):
            continue
        for row in pq.read_table(tmp_path / f"out/{name}.parquet").to_pylist():
            same_time = pdos[(row["time"], row["cob_id"])]  # (frames of one time: in order)
            rec = same_time.pop(0)
            assert row["data"] == rec.data
            seen += 1
            if name == "pdo":  # (no mapping: the frame as it came)
                assert (row["node"], row["number"], row["tpdo"]) == (rec.node, rec.number, rec.tpdo)
                assert not rec.values
                continue
            for key, value in row.items():
                if key in ("time", "cob_id", "dlc", "data"):
                    continue
                if value is None:
                    assert key not in rec.values
                else:
                    assert _same(value, rec.values[key]), (name, key)
    assert seen == sum(1 for r in records if r.kind == "pdo")
    assert not any(pdos.values())
    # node 5's REAL32/REAL64/BOOLEAN values keep their types
    odd = pq.read_table(tmp_path / "out/node5_tpdo1.parquet").schema
    assert {str(f.type) for f in odd if f.name in ("ratio", "precise", "ready")} <= {
        "float",
        "double",
        "bool",
    }
    # the exact decoder's records: their fields and their text
    sdo = pq.read_table(tmp_path / "out/sdo.parquet").to_pylist()
    transfers = [r for r in records if type(r).__name__ == "SdoTransfer"]
    assert [s["text"] for s in sdo] == [str(r) for r in transfers]
    assert [s["index"] for s in sdo] == [r.index for r in transfers]


def test_filters_and_a_node(tmp_path: Path) -> None:
    messages = _messages()
    rows = _export(messages, tmp_path / "a", "csv", kinds={"hb", "emcy"})
    assert set(rows) <= {"heartbeat", "bootup", "guard_request", "guard_response", "emcy"}
    rows = _export(messages, tmp_path / "b", "csv", node=10)
    assert "sync" not in rows and "heartbeat" in rows
    with (tmp_path / "b/heartbeat.csv").open() as f:
        assert {row["node"] for row in csv.DictReader(f)} == {"10"}


def test_short_frames_leave_nulls_and_csv_reads_back(tmp_path: Path) -> None:
    messages = [
        _msg(5.0, 0x18A, bytes([0x37, 0x06, 0x10, 0x27, 0, 0, 0xFF, 0xFF])),
        _msg(5.001, 0x18A, bytes([0x37, 0x02])),
        _msg(5.002, 0x080, b""),
        _msg(5.003, 0x080, b"\x07"),
    ]
    rows = _export(messages, tmp_path / "out", "csv")
    assert rows == {"node10_tpdo1": 2, "sync": 2}
    with (tmp_path / "out/node10_tpdo1.csv").open() as f:
        table = list(csv.DictReader(f))
    assert table[0]["data"] == "3706102700 00ffff".replace(" ", "")
    values = [k for k in table[0] if k not in ("time", "cob_id", "dlc", "data")]
    assert table[0][values[0]] == str(0x0637) and table[1][values[0]] == str(0x0237)
    assert all(table[1][k] == "" for k in values[1:])
    with (tmp_path / "out/sync.csv").open() as f:
        assert [r["counter"] for r in csv.DictReader(f)] == ["", "7"]


def test_bad_requests_are_refused(tmp_path: Path) -> None:
    decoder = BatchDecoder()
    with pytest.raises(ExportError, match="choose parquet or csv"):
        TraceExport(tmp_path / "x", "xlsx", decoder)
    (tmp_path / "full").mkdir()
    (tmp_path / "full/keep.txt").write_text("mine")
    with pytest.raises(ExportError, match="not an empty folder"):
        TraceExport(tmp_path / "full", "csv", decoder)
    assert (tmp_path / "full/keep.txt").read_text() == "mine"


def test_cobus_decode_to(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    trace = tmp_path / "trace.blf"
    with can.Logger(str(trace)) as logger:
        for msg in _messages():
            logger(msg)
    eds = tmp_path / "servo.eds"
    from cobus.device import export_eds

    eds.write_text(export_eds(_servo_od()))
    odd = tmp_path / "odd.eds"
    odd.write_text(_odd_eds())
    base = ["decode", str(trace), "--eds", f"10={eds}", "--eds", f"5={odd}"]
    assert main([*base, "--to", "parquet", str(tmp_path / "p"), "--json"]) == 0
    listed = json.loads(capsys.readouterr().out)
    assert listed["sync"]["rows"] > 0 and Path(listed["sync"]["file"]).is_file()
    assert pq.read_table(listed["sync"]["file"]).num_rows == listed["sync"]["rows"]
    assert main([*base, "--to", "csv", str(tmp_path / "c"), "--filter", "sdo"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out == [f"{tmp_path / 'c' / 'sdo.csv'}  {listed['sdo']['rows']} rows"]
    # refused, one line each, exit code 2
    for extra in (
        ["--to", "xlsx", str(tmp_path / "x")],
        ["--to", "csv", str(tmp_path / "c")],  # (not empty now)
        ["--to", "csv", str(tmp_path / "y"), "--summary"],
        ["--to", "csv", str(tmp_path / "y"), "--absolute"],
    ):
        assert main([*base, *extra]) == 2
        err = capsys.readouterr().err
        assert err.startswith("cobus: ") and err.count("\n") == 1
    assert main(["decode", str(tmp_path / "none.blf"), "--to", "csv", str(tmp_path / "z")]) == 1


def test_what_the_review_of_the_export_found(tmp_path: Path) -> None:
    # a value named as a frame's column keeps both
    export = TraceExport(tmp_path / "a", "csv", BatchDecoder())
    data = np.zeros((2, 8), dtype=np.uint8)
    table = PdoColumns(
        0x181,
        1,
        1,
        True,
        np.array([0, 1]),
        np.array([0.5, 0.75]),
        np.array([8, 8], dtype=np.uint8),
        data,
        ("time", "data"),
        {"time": np.array([7, 8], dtype=np.uint8), "data": np.array([9, 10], dtype=np.uint16)},
        np.array([2, 2]),
    )
    export._pdo(table)
    export.close()
    with (tmp_path / "a/node1_tpdo1.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert rows[0]["time"] == "0.5" and rows[0]["time (value)"] == "7"
    assert rows[1]["data (value)"] == "10" and rows[1]["data"] == "00" * 8
    # stopped between blocks (Ctrl-C): every table ends at the same frame, counts true
    messages = _messages()
    export = TraceExport(tmp_path / "b", "csv", BatchDecoder(_dictionaries(), load_network(LINE)))
    rows_written = export.write(message_blocks(messages, 1_000), stop=lambda: True)
    assert export.stopped and export.frames == 1_000
    for name, count in rows_written.items():
        with (tmp_path / f"b/{name}.csv").open() as f:
            times = [float(r["time"]) for r in csv.DictReader(f)]
        assert len(times) == count and max(times) <= export.end
    # a network file's PDO: one table however the blocks fall (a short frame alone first)
    short = [_msg(1.0, 0x183, b"\x37"), *(_msg(1.0 + i, 0x183, bytes(6)) for i in range(1, 4))]
    export = TraceExport(tmp_path / "c", "csv", BatchDecoder(network=load_network(LINE)))
    assert export.write(message_blocks(short, 1)) == {"node3_tpdo1": 4}
    # the PDOs no mapping names, in the order of the frames (the decoder's among them)
    with (tmp_path / "b/pdo.csv").open() as f:
        times = [float(r["time"]) for r in csv.DictReader(f)]
    assert times == sorted(times)
    # a file where the folder should be
    (tmp_path / "file").write_text("")
    with pytest.raises(ExportError, match="a file, not a folder"):
        TraceExport(tmp_path / "file", "csv", BatchDecoder())


def test_a_damaged_trace_says_how_far_the_tables_go(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    lines = [f"({1_700_000_000 + i / 1000:.6f}) can0 080#{i % 256:02X}" for i in range(3_000)]
    lines[2_000] = "(garbage"
    trace = tmp_path / "cut.log"
    trace.write_text("\n".join(lines) + "\n")
    assert main(["decode", str(trace), "--to", "csv", str(tmp_path / "out")]) == 1
    captured = capsys.readouterr()
    assert captured.out.splitlines() == [f"{tmp_path / 'out' / 'sync.csv'}  2000 rows"]
    assert "(the 1 table written holds the trace's first 2000 frames, to 1.999" in captured.err
    assert "cut.log: line 2001: '(garbage' is no candump line (python-can" in captured.err
    about = json.loads((tmp_path / "out/trace.json").read_text())
    assert about["frames"] == 2000 and about["tables"] == {
        "sync": {"file": "sync.csv", "rows": 2000}
    }


def test_an_empty_trace_and_frames_no_table_holds(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    trace = tmp_path / "errors.log"
    trace.write_text(
        "(1700000000.000000) can0 20000080#0000000000000000\n"
        "(1700000000.000100) can0 080##1112233\n"
    )
    assert main(["decode", str(trace), "--to", "csv", str(tmp_path / "out")]) == 0
    captured = capsys.readouterr()
    assert "# not in the tables: 1 error frames, 1 CAN FD or longer frames" in captured.err
    assert "no records to write" in captured.err
    # a folder to point a query at: no table, what it holds says so
    assert [p.name for p in (tmp_path / "out").iterdir()] == ["trace.json"]
    about = json.loads((tmp_path / "out/trace.json").read_text())
    assert about["tables"] == {} and about["frames"] == 2 and about["error_frames"] == 1


def test_one_type_per_column_and_what_the_folder_holds(tmp_path: Path) -> None:
    """The review's remarks: cob_id and node of one type in every table, TIME as a UTC
    timestamp, the trace's absolute start written down."""
    messages = _messages()
    start = 1_700_000_000.25
    for i, m in enumerate(messages):
        m.timestamp = start + i * 1e-3
    messages.append(_msg(start + 99.0, 0x100, bytes.fromhex("10 27 00 00 2c 3a")))  # TIME
    export = TraceExport(
        tmp_path / "out",
        "parquet",
        BatchDecoder(_dictionaries(), load_network(LINE)),
        source="bench.blf",
    )
    rows = export.write(message_blocks(messages, 700))
    types: dict[str, set[str]] = {}
    for name in rows:
        schema = pq.read_schema(tmp_path / f"out/{name}.parquet")
        assert json.loads(schema.metadata[b"cobus.trace_start"]) == start
        assert schema.metadata[b"cobus.trace_start_utc"] == b"2023-11-14T22:13:20.250000Z"
        for f in schema:
            types.setdefault(f.name, set()).add(str(f.type))
    assert types["cob_id"] == {"uint32"} and types["node"] == {"uint8"}
    assert types["index"] == {"uint16"} and types["subindex"] == {"uint8"}
    (moment,) = pq.read_table(tmp_path / "out/time.parquet").column("moment").to_pylist()
    assert str(pq.read_schema(tmp_path / "out/time.parquet").field("moment").type) == (
        "timestamp[ms, tz=UTC]"
    )
    assert moment.isoformat() == "2024-10-09T00:00:10+00:00"  # (14,892 days and 10 s)
    about = json.loads((tmp_path / "out/trace.json").read_text())
    assert about["source"] == "bench.blf" and about["format"] == "parquet"
    assert about["start"] == start and about["start_utc"] == "2023-11-14T22:13:20.250000Z"
    assert about["frames"] == len(messages) and not about["stopped"]
    assert about["tables"] == {n: {"file": f"{n}.parquet", "rows": r} for n, r in rows.items()}
    # CSV: the TIME as ISO text; a trace whose times count from 0 has no UTC start
    csv_export = TraceExport(tmp_path / "csv", "csv", BatchDecoder())
    csv_export.write(message_blocks([_msg(5.0, 0x100, bytes.fromhex("10 27 00 00 2c 3a"))]))
    with (tmp_path / "csv/time.csv").open() as f:
        (row,) = list(csv.DictReader(f))
    assert row["moment"] == moment.isoformat(timespec="milliseconds")
    about = json.loads((tmp_path / "csv/trace.json").read_text())
    assert about["start"] == 5.0 and about["start_utc"] is None


def test_sigterm_finishes_every_parquet_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    import os
    import signal

    import cobus.trace.blocks as trace_blocks

    messages = _messages()

    def terminated_after_the_first(path: Any) -> Any:
        for n, block in enumerate(message_blocks(messages, 1_000)):
            yield block
            if n == 0:
                os.kill(os.getpid(), signal.SIGTERM)

    monkeypatch.setattr(trace_blocks, "blocks", terminated_after_the_first)
    trace = tmp_path / "trace.blf"
    trace.write_bytes(b"")
    assert main(["decode", str(trace), "--to", "parquet", str(tmp_path / "out")]) == 143
    err = capsys.readouterr().err
    # (the signal came while the second block was read: the tables end after it)
    assert "terminated: the " in err and "the trace's first 2000 frames" in err
    for table in (tmp_path / "out").glob("*.parquet"):
        assert pq.read_table(table).num_rows > 0  # (each file has its footer)
    assert json.loads((tmp_path / "out/trace.json").read_text())["stopped"] is True
    assert signal.getsignal(signal.SIGTERM) == signal.SIG_DFL
