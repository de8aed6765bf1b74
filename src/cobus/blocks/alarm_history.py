"""The alarm history: every activation and every clearing, once, in an SQLite file.

One row per activation (raised at, node, source, code, text, severity), completed by its
clearing and its acknowledgement. The database runs in WAL mode with full synchronisation and
writes each change in one transaction, so a restart keeps the history and a crash (of the
process or of the machine) never leaves a half-written row. Queries by time range, node,
source and code; CSV export; a retention limit (rows and/or age) that never removes an alarm
still active.
"""

from __future__ import annotations

import contextlib
import csv
import datetime as _dt
import os
import sqlite3
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

from cobus.errors import CobusError, clip

__all__ = ["AlarmHistory", "AlarmHistoryDamagedError", "AlarmHistoryError", "AlarmRecord"]

_VERSION = 1
_SCHEMA = """
CREATE TABLE IF NOT EXISTS alarms (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    raised_at REAL NOT NULL,
    cleared_at REAL,
    node INTEGER,
    source TEXT NOT NULL,
    code INTEGER NOT NULL,
    text TEXT NOT NULL,
    severity TEXT NOT NULL,
    acknowledged_at REAL,
    acknowledged_by TEXT
);
CREATE INDEX IF NOT EXISTS alarms_raised ON alarms (raised_at);
CREATE INDEX IF NOT EXISTS alarms_node_code ON alarms (node, code);
CREATE INDEX IF NOT EXISTS alarms_cleared ON alarms (cleared_at);
"""
_COLUMNS = (
    "id",
    "raised_at",
    "cleared_at",
    "node",
    "source",
    "code",
    "text",
    "severity",
    "acknowledged_at",
    "acknowledged_by",
)


class AlarmHistoryError(CobusError):
    """The history file cannot be used (not a database, another program's, unreadable)."""


class AlarmHistoryDamagedError(AlarmHistoryError):
    """The history file is damaged: SQLite finds it malformed, or its integrity check fails
    (:class:`~cobus.blocks.AlarmHandler` then moves it aside and starts a new one).
    ``reason`` is SQLite's word for the damage."""

    def __init__(self, path: str, reason: str, what: str | None = None) -> None:
        self.path = path
        self.reason = reason
        doing = "" if what is None else f" and cannot {what}"
        super().__init__(
            f"the alarm history {path} is damaged ({reason}){doing}: move it aside (an "
            "AlarmHandler does) or name another file"
        )


class _NotOurs(sqlite3.DatabaseError):
    """A sound database that is no alarm history of this cobus (not damaged)."""


def _text(raw: bytes) -> str:
    return raw.decode("utf-8", "replace")


def _sqlite_file(path: str) -> bool:
    """Whether ``path`` starts as an SQLite database does (a damaged one still does; a text
    file named by mistake does not, and is not taken for a damaged history): its 16-byte
    magic, or - a byte of that damaged - the three payload fractions every SQLite 3 file
    holds at bytes 21-23 (64, 32, 32)."""
    try:
        with open(path, "rb") as f:
            head = f.read(24)
    except OSError:
        return False
    return head[:16] == b"SQLite format 3\x00" or (
        len(head) == 24 and head[21:24] == b"\x40\x20\x20"
    )


@contextlib.contextmanager
def _guarded(path: str, what: str) -> Iterator[None]:
    """Every SQLite error of ``what`` as an :class:`AlarmHistoryError` that names the file."""
    try:
        try:
            yield
        except UnicodeDecodeError as exc:  # (SQLite's message quotes a damaged schema)
            raise sqlite3.DatabaseError(f"a damaged text: {exc.reason}") from None
    except sqlite3.OperationalError as exc:  # locked, read-only, no room, I/O
        raise AlarmHistoryError(f"cannot {what} the alarm history {path}: {exc}") from None
    except sqlite3.DatabaseError as exc:
        raise AlarmHistoryDamagedError(path, str(exc), what) from None
    except sqlite3.Error as exc:
        raise AlarmHistoryError(f"cannot {what} the alarm history {path}: {exc}") from None


@dataclass(frozen=True)
class AlarmRecord:
    """One activation as the history keeps it (times in seconds since the epoch)."""

    id: int
    raised_at: float
    cleared_at: float | None
    node: int | None
    source: str
    code: int
    text: str
    severity: str
    acknowledged_at: float | None
    acknowledged_by: str | None

    @property
    def active(self) -> bool:
        """Whether it was not cleared (yet)."""
        return self.cleared_at is None

    @property
    def raised(self) -> _dt.datetime:
        """``raised_at`` as a local date and time."""
        return _dt.datetime.fromtimestamp(self.raised_at)

    def __str__(self) -> str:
        when = self.raised.strftime("%Y-%m-%d %H:%M:%S")
        node = f"node {self.node} " if self.node is not None else ""
        state = "active" if self.active else "cleared"
        return f"{when} {node}{self.source} {self.code}: {self.text} ({self.severity}, {state})"


def _iso(seconds: float | None) -> str:
    if seconds is None:
        return ""
    return _dt.datetime.fromtimestamp(seconds, _dt.UTC).isoformat(timespec="milliseconds")


class AlarmHistory:
    """The history in the SQLite file ``path`` (created when missing; ``":memory:"`` for
    none). ``max_rows``: cleared activations kept at most (oldest go first); ``max_age``:
    seconds a cleared activation is kept (None: no limit)."""

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        max_rows: int | None = 100_000,
        max_age: float | None = None,
    ) -> None:
        if max_rows is not None and (isinstance(max_rows, bool) or not max_rows >= 1):
            raise ValueError(f"max_rows={max_rows!r}: at least 1, or None for no limit")
        if max_age is not None and not max_age > 0:
            raise ValueError(f"max_age={max_age!r}: seconds above 0, or None for no limit")
        self.path = os.fspath(path)
        self.max_rows = max_rows
        self.max_age = max_age
        self._lock = threading.Lock()
        try:
            # a writer of another process holds the file at most this long (not SQLite's 5 s)
            self._db = sqlite3.connect(
                self.path, check_same_thread=False, isolation_level=None, timeout=1.0
            )
        except sqlite3.Error as exc:
            raise AlarmHistoryError(f"cannot open the alarm history {self.path}: {exc}") from None
        # A damaged text reads with U+FFFD in its place: the rest of the history stays
        # readable (sqlite3's own decoding raised UnicodeDecodeError at the first one).
        self._db.text_factory = _text
        try:
            try:
                self._set_up()
            except UnicodeDecodeError as exc:  # (SQLite's message quotes a damaged schema)
                raise sqlite3.DatabaseError(f"a damaged text: {exc.reason}") from None
        except sqlite3.OperationalError as exc:  # locked, read-only, no room, I/O
            self._db.close()
            raise AlarmHistoryError(f"cannot use the alarm history {self.path}: {exc}") from None
        except sqlite3.DatabaseError as exc:  # malformed, not a database, integrity
            self._db.close()
            if isinstance(exc, _NotOurs) or not _sqlite_file(self.path):
                raise AlarmHistoryError(
                    f"{self.path} is not an alarm history database ({exc}): name another file"
                ) from None
            raise AlarmHistoryDamagedError(self.path, str(exc)) from None

    def _set_up(self) -> None:
        db = self._db
        # Whose file it is first (the header and the schema): another program's database,
        # damaged or not, is refused as such - never moved aside as a damaged history.
        version = db.execute("PRAGMA user_version").fetchone()[0]
        tables = {row[0] for row in db.execute("SELECT name FROM sqlite_master")}
        if version == 0 and tables - {"sqlite_sequence"}:
            raise _NotOurs("it holds tables of another program")
        if version > _VERSION:
            raise _NotOurs(f"written by a newer cobus (format {version})")
        # A damaged file shows here, not at the first query of a running application
        # (quick_check: every page and row, in time linear in the file; check() runs the
        # full integrity check, indexes against their tables too).
        verdict = [row[0] for row in db.execute("PRAGMA quick_check(5)")]
        if verdict != ["ok"]:
            found = " ".join("; ".join(map(str, verdict)).split())  # (one line)
            raise sqlite3.DatabaseError(f"integrity check: {clip(found, 200)}")
        db.execute("PRAGMA journal_mode=WAL")
        db.execute("PRAGMA synchronous=FULL")
        if version == 0:  # new: the schema and its version in one transaction
            db.executescript(f"BEGIN IMMEDIATE;{_SCHEMA}PRAGMA user_version={_VERSION};COMMIT;")
        else:
            db.executescript(f"BEGIN IMMEDIATE;{_SCHEMA}COMMIT;")  # (indexes added later)

    def _transaction(self) -> Any:
        return _Transaction(self._db)

    # ------------------------------------------------------------------ writing

    def opened(
        self,
        *,
        source: str,
        node: int | None,
        code: int,
        text: str,
        severity: str,
        at: float,
    ) -> int:
        """Log an activation; its row id."""
        with self._lock, _guarded(self.path, "log an alarm in"), self._transaction():
            cursor = self._db.execute(
                "INSERT INTO alarms (raised_at, node, source, code, text, severity) "
                "VALUES (?, ?, ?, ?, ?, ?)",
                (at, node, source, code, text, severity),
            )
            row = cursor.lastrowid
            self._prune(at)
        assert row is not None
        return row

    def cleared(self, row: int, at: float) -> None:
        """Log the clearing of activation ``row`` (once: a second call changes nothing)."""
        with self._lock, _guarded(self.path, "log a clearing in"), self._transaction():
            self._db.execute(
                "UPDATE alarms SET cleared_at = ? WHERE id = ? AND cleared_at IS NULL", (at, row)
            )

    def acknowledged(self, row: int, at: float, by: str) -> None:
        """Log who acknowledged activation ``row`` (the first acknowledgement counts)."""
        with self._lock, _guarded(self.path, "log an acknowledgement in"), self._transaction():
            self._db.execute(
                "UPDATE alarms SET acknowledged_at = ?, acknowledged_by = ? "
                "WHERE id = ? AND acknowledged_at IS NULL",
                (at, by, row),
            )

    def _prune(self, now: float) -> None:
        if self.max_age is not None:
            self._db.execute(
                "DELETE FROM alarms WHERE cleared_at IS NOT NULL AND cleared_at < ?",
                (now - self.max_age,),
            )
        if self.max_rows is not None:  # (ids only grow: the newest max_rows ids stay)
            self._db.execute(
                "DELETE FROM alarms WHERE cleared_at IS NOT NULL AND "
                "id <= (SELECT MAX(id) FROM alarms) - ?",
                (self.max_rows,),
            )

    # ------------------------------------------------------------------ reading

    def query(
        self,
        *,
        since: float | _dt.datetime | None = None,
        until: float | _dt.datetime | None = None,
        node: int | None = None,
        source: str | None = None,
        code: int | None = None,
        active: bool | None = None,
        limit: int | None = None,
        newest_first: bool = True,
    ) -> list[AlarmRecord]:
        """The activations raised in [since, until) of ``node``/``source``/``code`` (None:
        any), only active or cleared ones (``active``), newest first."""
        where: list[str] = []
        args: list[Any] = []
        for column, op, moment in (("raised_at", ">=", since), ("raised_at", "<", until)):
            if moment is not None:
                where.append(f"{column} {op} ?")
                args.append(moment.timestamp() if isinstance(moment, _dt.datetime) else moment)
        for column, value in (("node", node), ("source", source), ("code", code)):
            if value is not None:
                where.append(f"{column} = ?")
                args.append(value)
        if active is not None:
            where.append("cleared_at IS NULL" if active else "cleared_at IS NOT NULL")
        sql = f"SELECT {', '.join(_COLUMNS)} FROM alarms"
        if where:
            sql += " WHERE " + " AND ".join(where)
        sql += " ORDER BY id " + ("DESC" if newest_first else "ASC")
        if limit is not None:
            sql += " LIMIT ?"
            args.append(int(limit))
        with self._lock, _guarded(self.path, "read"):
            rows = self._db.execute(sql, args).fetchall()
        return [AlarmRecord(*row) for row in rows]

    def __iter__(self) -> Iterator[AlarmRecord]:
        return iter(self.query(newest_first=False))

    def __len__(self) -> int:
        with self._lock, _guarded(self.path, "count the rows of"):
            return int(self._db.execute("SELECT COUNT(*) FROM alarms").fetchone()[0])

    def export_csv(self, target: str | os.PathLike[str] | IO[str], **filters: Any) -> int:
        """Write the activations :meth:`query` selects (oldest first) as CSV, times in ISO
        8601 (UTC); the number of rows."""
        filters.setdefault("newest_first", False)
        records = self.query(**filters)
        if isinstance(target, str | os.PathLike):
            with Path(target).open("w", newline="", encoding="utf-8") as f:
                return self._write_csv(f, records)
        return self._write_csv(target, records)

    @staticmethod
    def _write_csv(f: IO[str], records: list[AlarmRecord]) -> int:
        writer = csv.writer(f)
        writer.writerow(["raised", "cleared", "node", "source", "code", "text", "severity",
                         "acknowledged", "acknowledged_by"])  # fmt: skip
        for r in records:
            writer.writerow(
                [
                    _iso(r.raised_at),
                    _iso(r.cleared_at),
                    "" if r.node is None else r.node,
                    r.source,
                    r.code,
                    r.text,
                    r.severity,
                    _iso(r.acknowledged_at),
                    r.acknowledged_by or "",
                ]
            )
        return len(records)

    def check(self) -> str:
        """SQLite's integrity check: ``"ok"`` for an undamaged file."""
        with self._lock, _guarded(self.path, "check"):
            return str(self._db.execute("PRAGMA integrity_check").fetchone()[0])

    def close(self) -> None:
        """Close the file (writes were committed already)."""
        with self._lock, _guarded(self.path, "close"):
            self._db.close()

    def __enter__(self) -> AlarmHistory:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class _Transaction:
    """BEGIN IMMEDIATE ... COMMIT (ROLLBACK on an error) on an autocommit connection."""

    def __init__(self, db: sqlite3.Connection) -> None:
        self.db = db

    def __enter__(self) -> None:
        self.db.execute("BEGIN IMMEDIATE")

    def __exit__(self, kind: object, *rest: object) -> None:
        self.db.execute("COMMIT" if kind is None else "ROLLBACK")
