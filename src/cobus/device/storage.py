"""Non-volatile parameters of a device (1010h store / 1011h restore, CiA 301).

What is stored: the writable entries of the communication area (1000h-1FFFh, without the
command objects 1003h, 1010h, 1011h) and of the application area (2000h-9FFFh), each as its
encoded bytes; an entry that holds its ``$NODEID`` default is stored relative to the node-ID
so that it follows a node-ID change.

:class:`FileStorage` writes the file atomically: a temporary file in the same directory is
written, flushed and synced, then renamed over the old file, and the directory is synced. A
crash at any point leaves either the old or the new file, never a mix; temporary files a
crash left behind are removed at the next load or save. The file carries a SHA-256 of its
parameters: a damaged file (a flipped bit that still parses) is refused as a whole with a
:class:`StorageError` instead of being half applied.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Protocol

from cobus.device.errors import StorageError

__all__ = [
    "APPLICATION",
    "COMMUNICATION",
    "FileStorage",
    "MemoryStorage",
    "ParameterStorage",
    "StoredValue",
]

COMMUNICATION = "communication"
APPLICATION = "application"
_GROUPS = (COMMUNICATION, APPLICATION)
_FORMAT = "cobus device parameters"
_VERSION = 1

#: One stored entry: ``{"data": "<hex>"}`` or ``{"node_id_offset": n}``.
StoredValue = dict[str, Any]
#: Group name -> ``"IIII:SS"`` -> stored value.
Parameters = dict[str, dict[str, StoredValue]]


class ParameterStorage(Protocol):
    """Where a device keeps its stored parameters."""

    def load(self) -> Parameters:
        """The stored groups (missing groups: nothing stored)."""
        ...

    def save(self, parameters: Parameters) -> None:
        """Replace everything stored with ``parameters``; all or nothing."""
        ...


def _copy(parameters: Mapping[str, Mapping[str, StoredValue]]) -> Parameters:
    return {g: {k: dict(v) for k, v in parameters.get(g, {}).items()} for g in _GROUPS}


class MemoryStorage:
    """Parameters kept in memory: they survive resets of the device, not the process."""

    def __init__(self) -> None:
        self._data: Parameters = {g: {} for g in _GROUPS}

    def load(self) -> Parameters:
        """The stored parameters by area."""
        return _copy(self._data)

    def save(self, parameters: Parameters) -> None:
        """Store ``values`` for the area (in memory, for tests)."""
        self._data = _copy(parameters)


class FileStorage:
    """Parameters in a JSON file, replaced atomically on every save."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)

    def _clean(self) -> None:
        """Remove the temporary files a crash during a save left behind."""
        directory = self.path.parent if str(self.path.parent) else Path(".")
        for stale in directory.glob(f".{self.path.name}.*.tmp"):
            with contextlib.suppress(OSError):
                stale.unlink()

    def load(self) -> Parameters:
        """The stored parameters by area (empty when nothing was saved yet)."""
        self._clean()
        try:
            text = self.path.read_text(encoding="utf-8")
        except FileNotFoundError:
            return {g: {} for g in _GROUPS}
        except OSError as exc:
            raise StorageError(
                f"{self.path}: cannot read the stored parameters: {exc.strerror}"
            ) from None
        except UnicodeDecodeError as exc:
            raise StorageError(
                f"{self.path}: not a parameter file (byte {exc.start} is not UTF-8); delete it "
                "to start with the default values"
            ) from None
        try:
            doc = json.loads(text)
        except (ValueError, RecursionError) as exc:
            why = "nested too deeply" if isinstance(exc, RecursionError) else str(exc)
            raise StorageError(
                f"{self.path}: not a parameter file ({why}); delete it to start with the "
                "default values"
            ) from None
        if not isinstance(doc, dict) or doc.get("format") != _FORMAT:
            raise StorageError(
                f"{self.path}: not a cobus parameter file (no 'format': {_FORMAT!r}); delete "
                "it or point the device to another file"
            )
        if doc.get("version") != _VERSION:
            raise StorageError(
                f"{self.path}: parameter file version {doc.get('version')!r} is not supported "
                f"(this cobus writes version {_VERSION})"
            )
        out: Parameters = {}
        for group in _GROUPS:
            items = doc.get(group, {})
            if not isinstance(items, dict) or not all(isinstance(v, dict) for v in items.values()):
                raise StorageError(f"{self.path}: group {group!r} is not a table of entries")
            out[group] = items
        stored = doc.get("sha256")
        if stored is not None and stored != _digest(out):
            raise StorageError(
                f"{self.path}: the file is damaged (its SHA-256 does not match the parameters "
                "it holds); delete it to start with the default values"
            )
        return out

    def save(self, parameters: Parameters) -> None:
        """Store ``values`` for the area; written to a temporary file and renamed, so a crash never
        leaves half a file."""
        self._clean()
        groups = _copy(parameters)
        doc = {"format": _FORMAT, "version": _VERSION, "sha256": _digest(groups), **groups}
        data = json.dumps(doc, indent=1, sort_keys=True).encode("utf-8")
        try:
            atomic_write(self.path, data)
        except OSError as exc:
            raise StorageError(
                f"{self.path}: cannot store the parameters ({exc}); the previous file is unchanged"
            ) from None


def _digest(groups: Mapping[str, Any]) -> str:
    """The SHA-256 of the parameters, over their canonical JSON."""
    canonical = json.dumps({g: groups.get(g, {}) for g in _GROUPS}, sort_keys=True)
    return hashlib.sha256(canonical.encode("utf-8")).hexdigest()


def atomic_write(path: Path, data: bytes) -> None:
    """Replace ``path`` by ``data`` so that a crash leaves the old or the new content."""
    directory = path.parent if str(path.parent) else Path(".")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=directory)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    _sync_directory(directory)


def _sync_directory(directory: Path) -> None:
    flags = os.O_RDONLY | getattr(os, "O_DIRECTORY", 0)
    try:
        dir_fd = os.open(directory, flags)
    except OSError:  # a platform that cannot open directories (Windows): rename is durable
        return
    try:
        os.fsync(dir_fd)
    except OSError:
        pass
    finally:
        os.close(dir_fd)
