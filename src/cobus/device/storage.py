"""Non-volatile parameters of a device (1010h store / 1011h restore, CiA 301).

What is stored: the writable entries of the communication area (1000h-1FFFh, without the
objects a service declares never stored: the store and restore commands, the error history)
and of the application area (2000h-9FFFh), each as its
encoded bytes; an entry that holds its ``$NODEID`` default is stored relative to the node-ID
so that it follows a node-ID change. Apart from them, the node-ID and bit timing an LSS master
had the device store (CiA 305 ``store configuration``): 1011h restore leaves them.

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

from cobus.device._core import Core, abort
from cobus.device._entries import Entry, check_value, decode_download, zero_value
from cobus.device._objects import U8, U32, composite
from cobus.device.errors import StorageError
from cobus.device.events import ParametersRestored, ParametersStored, StorageProblem
from cobus.od import Array, ObjectDictionary, encode
from cobus.proto.lss import AUTO_BIT_RATE, BIT_RATES, UNCONFIGURED
from cobus.proto.sdo import SdoAbort, SdoAbortCode

__all__ = [
    "APPLICATION",
    "COMMUNICATION",
    "LOAD_SIGNATURE",
    "RESTORE",
    "SAVE_SIGNATURE",
    "STORE",
    "FileStorage",
    "MemoryStorage",
    "ParameterStorage",
    "StorageService",
    "StoredValue",
    "define_objects",
    "open_storage",
]

COMMUNICATION = "communication"
APPLICATION = "application"
#: The LSS configuration: ``{"node_id": {"value": n}, "bit_timing": {"value": i}}``.
LSS = "lss"
_GROUPS = (COMMUNICATION, APPLICATION)
_ALL_GROUPS = (*_GROUPS, LSS)
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
    out = {g: {k: dict(v) for k, v in parameters.get(g, {}).items()} for g in _GROUPS}
    lss = parameters.get(LSS)
    if lss:
        out[LSS] = {k: dict(v) for k, v in lss.items()}
    return out


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
        for group in _ALL_GROUPS:
            if group == LSS and LSS not in doc:
                continue
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
        if LSS in out and doc.get("lss_sha256") != _digest({LSS: out[LSS]}, (LSS,)):
            raise StorageError(
                f"{self.path}: the file is damaged (the SHA-256 of its LSS configuration does "
                "not match); delete it to start with the default values"
            )
        return out

    def save(self, parameters: Parameters) -> None:
        """Store ``values`` for the area; written to a temporary file and renamed, so a crash never
        leaves half a file."""
        self._clean()
        groups = _copy(parameters)
        doc = {"format": _FORMAT, "version": _VERSION, "sha256": _digest(groups), **groups}
        if LSS in groups:  # (its own digest: a cobus before LSS reads the file as it was)
            doc["lss_sha256"] = _digest(groups, (LSS,))
        data = json.dumps(doc, indent=1, sort_keys=True).encode("utf-8")
        try:
            atomic_write(self.path, data)
        except OSError as exc:
            raise StorageError(
                f"{self.path}: cannot store the parameters ({exc}); the previous file is unchanged"
            ) from None


def _digest(groups: Mapping[str, Any], names: tuple[str, ...] = _GROUPS) -> str:
    """The SHA-256 of the groups ``names`` (the parameters), over their canonical JSON."""
    canonical = json.dumps({g: groups.get(g, {}) for g in names}, sort_keys=True)
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


# ====================================================================== the service

#: The command objects: store parameters (1010h) and restore default parameters (1011h).
STORE, RESTORE = 0x1010, 0x1011
#: 1010h: "save" as a little-endian UNSIGNED32.
SAVE_SIGNATURE = 0x65766173
#: 1011h: "load" as a little-endian UNSIGNED32.
LOAD_SIGNATURE = 0x64616F6C

_ABORT = SdoAbortCode
_SUBINDEX_GROUPS = {1: (COMMUNICATION, APPLICATION), 2: (COMMUNICATION,), 3: (APPLICATION,)}


def _in_group(group: str, index: int) -> bool:
    return index < 0x2000 if group == COMMUNICATION else 0x2000 <= index < 0xA000


def define_objects(od: ObjectDictionary) -> None:
    """1010h and 1011h, each with all, communication and application parameters (sub 1-3),
    stored on command."""
    for index, name, verb in (
        (STORE, "Store parameters", "Save"),
        (RESTORE, "Restore default parameters", "Restore"),
    ):
        composite(
            od,
            Array(index, name),
            [
                (0, "Highest sub-index supported", U8, 3),
                (1, f"{verb} all parameters", U32, 1),
                (2, f"{verb} communication parameters", U32, 1),
                (3, f"{verb} application parameters", U32, 1),
            ],
        )


def open_storage(storage: str | Path | ParameterStorage | None) -> ParameterStorage:
    """The store a device's ``storage=`` option names: None kept in memory, a path a
    :class:`FileStorage`, anything else used as it is."""
    if storage is None:
        return MemoryStorage()
    if isinstance(storage, str | Path):
        return FileStorage(storage)
    return storage


class StorageService:
    """Parameters of one device: power-on values, 1010h store and 1011h restore."""

    def __init__(self, core: Core, storage: str | Path | ParameterStorage | None) -> None:
        self._core = core
        self._storage = open_storage(storage)
        self._failed = False
        core.handle(STORE, self._w_store)
        core.handle(RESTORE, self._w_restore)
        core.not_stored.update((STORE, RESTORE))
        if core.deviations.store_on_subindex_0 and STORE in core.indices:
            core.downloads[STORE << 8] = self._download_store_0

    def _download_store_0(self, entry: Entry, data: bytes) -> None:
        """1010h sub 0 of a device that saves there: the UNSIGNED8 count takes the
        UNSIGNED32 signature."""
        if len(data) != 4:
            raise abort(
                _ABORT.LENGTH_MISMATCH,
                f"1010h sub 0 takes the 4-byte signature 'save', got {len(data)} bytes",
            )
        self._core.write(entry, int.from_bytes(data, "little"), remote=True)

    def power_on(self, *, communication: bool, application: bool) -> None:
        """The values of a reset: the defaults, then what is stored, of the communication
        area (reset communication), the application area (reset node) or both (power-on).
        A store that cannot be read leaves the defaults: :class:`StorageProblem` now, and
        :meth:`take_failure` True once for the EMCY at boot."""
        core = self._core
        for entry in core.entries.values():
            index = entry.index
            if index < 0x2000:
                reset = communication
            elif index < 0xA000:
                reset = application
            else:  # A000h and above: network variables and reserved, set at power-on only
                reset = not core.started
            if reset:
                default = entry.var.value
                entry.value = zero_value(entry.data_type) if default is None else default
        try:
            stored = self._storage.load()
        except StorageError as exc:  # the defaults then; said by event here, by EMCY at boot
            core.emit(StorageProblem(core.node_id, str(exc)))
            self._failed = True
            stored = {}
        groups = []
        if communication:
            groups.append(COMMUNICATION)
        if application:
            groups.append(APPLICATION)
        for group in groups:
            for key, item in stored.get(group, {}).items():
                self._apply_stored(group, key, item)

    def take_failure(self) -> bool:
        """Whether the last power-on could not read the store (True once)."""
        failed, self._failed = self._failed, False
        return failed

    def store(self, subindex: int) -> None:
        """Store a parameter group as 1010h does: 1 all, 2 communication, 3 application."""
        groups = self._groups(subindex, "1010h")
        try:
            stored = self._storage.load()
        except StorageError as exc:
            if subindex != 1:
                raise abort(_ABORT.CANNOT_STORE, str(exc)) from None
            stored = {}
        for group in groups:
            stored[group] = self._collect(group)
        try:
            self._storage.save(stored)
        except StorageError as exc:
            raise abort(_ABORT.CANNOT_STORE, str(exc)) from None
        self._core.emit(ParametersStored(self._core.node_id, subindex))

    def restore(self, subindex: int) -> None:
        """Drop a stored parameter group as 1011h does (effective at the next reset)."""
        groups = self._groups(subindex, "1011h")
        try:
            stored = self._storage.load()
        except StorageError:
            stored = {}
        for group in groups:
            stored[group] = {}
        try:
            self._storage.save(stored)
        except StorageError as exc:
            raise abort(_ABORT.CANNOT_STORE, str(exc)) from None
        self._core.emit(ParametersRestored(self._core.node_id, subindex))

    def stored_lss(self) -> tuple[int | None, int | None]:
        """The node-ID and bit timing (table index) an LSS master had stored; None for each
        that was not, or when the store cannot be read (:meth:`power_on` tells why)."""
        try:
            lss = self._storage.load().get(LSS, {})
        except StorageError:
            return None, None
        found: list[int | None] = []
        for key, valid in (("node_id", _lss_node_id), ("bit_timing", _lss_bit_timing)):
            value = lss.get(key, {}).get("value")
            if value is not None and not valid(value):
                self._core.emit(
                    StorageProblem(self._core.node_id, f"stored LSS {key} {value!r} is not valid")
                )
                value = None
            found.append(value)
        return found[0], found[1]

    def store_lss(self, node_id: int, bit_timing: int | None) -> None:
        """Keep the node-ID and bit timing an LSS master configured (``store configuration``);
        a bit timing of None keeps the one stored before. :class:`StorageError` if the store
        cannot be read or written (the LSS answer says "storage media access error"): what
        it holds is never overwritten unread."""
        stored = self._storage.load()
        lss = dict(stored.get(LSS, {}))
        lss["node_id"] = {"value": node_id}
        if bit_timing is not None:
            lss["bit_timing"] = {"value": bit_timing}
        stored[LSS] = lss
        self._storage.save(stored)

    def apply_node_relative(self) -> None:
        """The device got its first node-ID: the stored application values that follow it."""
        try:
            stored = self._storage.load()
        except StorageError:
            return  # (said at the power-on)
        for key, item in stored.get(APPLICATION, {}).items():
            if "node_id_offset" in item:
                self._apply_stored(APPLICATION, key, item)

    def _apply_stored(self, group: str, key: str, item: StoredValue) -> None:
        core = self._core
        if core.unconfigured and "node_id_offset" in item:
            return  # nothing to add it to yet (:meth:`apply_node_relative`)
        try:
            index_text, _, sub_text = key.partition(":")
            index, subindex = int(index_text, 16), int(sub_text, 16)
            entry = core.entries[index << 8 | subindex]
            if (
                not _in_group(group, index)
                or not entry.var.access.writable
                or index in core.not_stored
            ):
                raise ValueError(f"0x{index:04X}:{subindex:02X} is no {group} parameter")
            if "node_id_offset" in item:
                value = check_value(entry, core.node_id + int(item["node_id_offset"]))
            else:
                value = decode_download(entry, bytes.fromhex(str(item["data"])))
        except (KeyError, ValueError, TypeError, OverflowError, SdoAbort) as exc:
            core.emit(StorageProblem(core.node_id, f"stored {group} entry {key}: {exc}"))
            return
        entry.value = value

    def _collect(self, group: str) -> dict[str, StoredValue]:
        core = self._core
        out: dict[str, StoredValue] = {}
        for entry in core.entries.values():
            index = entry.index
            if (
                not _in_group(group, index)
                or index in core.not_stored
                or not entry.var.access.writable
            ):
                continue
            key = f"{index:04X}:{entry.subindex:02X}"
            value = entry.value
            if entry.reader is not None:
                try:
                    value = check_value(entry, entry.reader())
                except Exception as exc:  # the application's value cannot be read: keep ours
                    core.failure(f"read callback of {key}", exc)
            offset = core.node_offset(entry, value)
            if offset is not None:
                out[key] = {"node_id_offset": offset}
            else:
                out[key] = {"data": encode(entry.data_type, value).hex()}
        return out

    @staticmethod
    def _groups(subindex: int, what: str) -> tuple[str, ...]:
        chosen = _SUBINDEX_GROUPS.get(subindex)
        if chosen is None:
            raise abort(
                _ABORT.CANNOT_STORE,
                f"{what} sub-index {subindex} names no parameter group (1 all, "
                "2 communication, 3 application)",
            )
        return chosen

    def _w_store(self, entry: Entry, value: Any) -> None:
        if entry.subindex == 0 and not self._core.deviations.store_on_subindex_0:
            raise abort(_ABORT.WRITE_READ_ONLY, "1010h sub 0 is read-only")
        if value != SAVE_SIGNATURE:
            raise abort(
                _ABORT.CANNOT_STORE,
                f"1010h expects the signature 'save' (0x{SAVE_SIGNATURE:08X}), got 0x{value:08X}",
            )
        self.store(entry.subindex or 1)

    def _w_restore(self, entry: Entry, value: Any) -> None:
        if entry.subindex == 0:
            raise abort(_ABORT.WRITE_READ_ONLY, "1011h sub 0 is read-only")
        if value != LOAD_SIGNATURE:
            raise abort(
                _ABORT.CANNOT_STORE,
                f"1011h expects the signature 'load' (0x{LOAD_SIGNATURE:08X}), got 0x{value:08X}",
            )
        self.restore(entry.subindex)


def _lss_node_id(value: object) -> bool:
    return type(value) is int and (1 <= value <= 127 or value == UNCONFIGURED)


def _lss_bit_timing(value: object) -> bool:
    return type(value) is int and (value in BIT_RATES or value == AUTO_BIT_RATE)
