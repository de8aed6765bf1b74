"""The device's PDOs: every TPDO and RPDO its dictionary configures, their communication
parameters (1400h-15FFh, 1800h-19FFh) and mapping parameters (1600h-17FFh, 1A00h-1BFFh).

A PDO is (re)built from its parameters whenever a master changes them; the machines
themselves (:class:`~cobus.device._pdo_machines.Tpdo`, ``Rpdo``) and the compiled mappings
live in :mod:`cobus.device._pdo_machines`. TPDOs transmit in operational (and, for the
numbers the deviations name, in pre-operational); RPDOs are taken in operational only.
Synchronous RPDOs take effect at the next SYNC, and only when they arrived within the
synchronous window; synchronous TPDOs count the SYNCs of :meth:`PdoService.on_sync`.

Choices where CiA 301 leaves one: the COB-ID, inhibit time and SYNC start value of a valid
PDO cannot change (set bit 31 of its COB-ID first); a mapping changes only while its PDO is
not valid and its sub 0 is 0; an RPDO that times out (event timer) is the communication error
``("rpdo", n)`` (EMCY 8250h) until it arrives again; a wrong length is the one-shot EMCY
8210h/8220h.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from functools import partial
from typing import Any

from cobus.device._core import INVALID, Core, abort
from cobus.device._entries import Entry, check_value
from cobus.device._objects import RW, U8, U16, U32, composite
from cobus.device._pdo_machines import Rpdo, Tpdo, check_mapping_entry, compile_mapping
from cobus.device.emcy import COMM_BIT, EmcyService
from cobus.device.errors import DeviceConfigError
from cobus.device.events import RpdoLost, RpdoReceived, RpdoRestored, WrongLengthRpdoReceived
from cobus.errors import CobusError
from cobus.od import Array, DataType, NodeRelative, ObjectDictionary, Record
from cobus.proto import NOTHING, Event, Frame
from cobus.proto.emcy import EmcyCode
from cobus.proto.nmt import NmtState
from cobus.proto.pdo import (
    MappingEntry,
    PdoCobId,
    PdoError,
    RpdoResumed,
    RpdoTimeout,
    RpdoTooLong,
    RpdoTooShort,
    TransmissionType,
    is_restricted_can_id,
    rpdo_default_can_id,
    tpdo_default_can_id,
)
from cobus.proto.sdo import SdoAbort, SdoAbortCode

__all__ = ["PdoService", "count_pdos", "define_default", "define_objects"]

_ABORT = SdoAbortCode


def define_objects(od: ObjectDictionary, *, rpdos: int, tpdos: int, entries: int) -> None:
    """The communication and mapping parameters of ``rpdos`` RPDOs and ``tpdos`` TPDOs: PDO
    1-4 on their pre-defined COB-IDs (``$NODEID`` + 180h ...), the others not valid;
    transmission type 255 and an empty mapping of ``entries`` entries each."""
    for kind, count, comm_base, map_base, id_base in (
        ("RPDO", rpdos, 0x1400, 0x1600, 0x200),
        ("TPDO", tpdos, 0x1800, 0x1A00, 0x180),
    ):
        tx = kind == "TPDO"
        for n in range(count):
            cob: int | NodeRelative = NodeRelative(id_base + 0x100 * n) if n < 4 else INVALID
            composite(
                od,
                Record(comm_base + n, f"{kind} communication parameter {n + 1}"),
                [
                    (0, "Highest sub-index supported", U8, 6 if tx else 5),
                    (1, f"COB-ID used by {kind}", U32, cob),
                    (2, "Transmission type", U8, 255),
                    (3, "Inhibit time", U16, 0),
                    (5, "Event timer", U16, 0),
                    *([(6, "SYNC start value", U8, 0)] if tx else []),
                ],
            )
            composite(
                od,
                Record(map_base + n, f"{kind} mapping parameter {n + 1}"),
                [
                    (0, "Number of mapped objects", U8, 0),
                    *((e, f"Mapped object {e}", U32, 0) for e in range(1, entries + 1)),
                ],
                first=RW,  # a master writes the count
            )


_BASES = {"RPDO": (0x1400, 0x1600), "TPDO": (0x1800, 0x1A00)}


def count_pdos(od: ObjectDictionary) -> tuple[int, int]:
    """How many RPDOs and TPDOs ``od`` has communication parameters for."""
    rx, tx = _BASES["RPDO"][0], _BASES["TPDO"][0]
    return sum(1 for n in range(512) if rx + n in od), sum(1 for n in range(512) if tx + n in od)


def define_default(
    od: ObjectDictionary,
    kind: str,
    number: int,
    entries: Iterable[tuple[int, int]],
    transmission_type: int,
) -> Record | Array:
    """Set the default mapping (``(index, sub)`` of each mapped variable, in order) and
    transmission type of ``kind`` (``"RPDO"``/``"TPDO"``) ``number`` (1-based) in ``od``;
    the communication parameter, for the caller's other defaults.
    Raises :class:`~cobus.device.DeviceConfigError` naming what does not fit."""
    comm_base, map_base = _BASES[kind]
    comm = od.get(comm_base + number - 1) if isinstance(number, int) else None
    mapping = od.get(map_base + number - 1) if isinstance(number, int) else None
    if not isinstance(comm, Record | Array) or not isinstance(mapping, Record | Array):
        raise DeviceConfigError(
            f"the dictionary has no {kind} {number}: ask minimal_od() for more PDOs"
        )
    values = []
    for index, sub in entries:
        var = od.get_variable(index, sub)
        if var is None:
            raise DeviceConfigError(
                f"{kind} {number} maps 0x{index:04X}:{sub:02X}, which is not in the "
                "dictionary yet: add the variable first"
            )
        if var.bit_length is None:
            raise DeviceConfigError(
                f"{kind} {number} maps 0x{index:04X}:{sub:02X} ({var.data_type.name}), "
                "which has no fixed bit length"
            )
        values.append(index << 16 | sub << 8 | var.bit_length)
    slots = len(mapping.subindices) - 1
    if len(values) > slots:
        raise DeviceConfigError(
            f"{kind} {number} maps {len(values)} objects but its mapping has {slots} "
            "entries: ask minimal_od(mapping_entries=...) for more"
        )
    for sub in range(1, slots + 1):
        mapping[sub].default = values[sub - 1] if sub <= len(values) else 0
    mapping[0].default = len(values)
    comm[2].default = transmission_type
    return comm


class PdoService:
    """The TPDOs and RPDOs of one device and their parameters 1400h-1BFFh."""

    def __init__(
        self, core: Core, emcy: EmcyService, *, in_sync_window: Callable[[float], bool]
    ) -> None:
        self._core = core
        self._emcy = emcy
        self._sync_window = in_sync_window
        self._operational = False
        self._tpdos: dict[int, Tpdo] = {}
        self._rpdos: dict[int, Rpdo] = {}
        self._sync_tpdos: list[Tpdo] = []
        self._sync_rpdos: list[Rpdo] = []
        for index in core.indices:
            if 0x1400 <= index <= 0x15FF or 0x1800 <= index <= 0x19FF:
                core.handle(index, self._w_comm)
            elif 0x1600 <= index <= 0x17FF or 0x1A00 <= index <= 0x1BFF:
                core.handle(index, self._w_mapping)
        for n in range(1, 5):  # PDO 1-4 of the pre-defined connection set
            core.follows_node_id(0x1400 + n - 1, 1, rpdo_default_can_id(n, 1) - 1)
            core.follows_node_id(0x1800 + n - 1, 1, tpdo_default_can_id(n, 1) - 1)

    def build(self) -> None:
        """Build every PDO the dictionary has (after a reset communication)."""
        indices = self._core.indices
        for n in range(1, 513):
            if 0x1400 + n - 1 in indices:
                self._build_rpdo(n)
            if 0x1800 + n - 1 in indices:
                self._build_tpdo(n)

    def close(self) -> None:
        """Drop every PDO."""
        for number in list(self._tpdos):
            self._drop_tpdo(number)
        for number in list(self._rpdos):
            self._drop_rpdo(number)
        self._operational = False

    def send_tpdo(self, number: int) -> bool:
        """An application event for TPDO ``number``; False when it is not configured."""
        tpdo = self._tpdos.get(number)
        if tpdo is None:
            return False
        self._apply(tpdo, tpdo.on_change(self._core.now()))
        return True

    def state_changed(self, old: NmtState, new: NmtState, now: float) -> None:
        """Start and stop the PDOs as the NMT state says."""
        early = self._core.deviations.tpdos_outside_operational
        if new is NmtState.OPERATIONAL:
            self._operational = True
            for tpdo in self._tpdos.values():
                if not tpdo.trigger.active:
                    tpdo.start(now)
                    self._apply(tpdo, NOTHING)
        elif old is NmtState.OPERATIONAL:
            self._operational = False
            for tpdo in self._tpdos.values():
                tpdo.stop()
                self._apply(tpdo, NOTHING)
            for rpdo in self._rpdos.values():
                rpdo.disarm()
                self._apply(rpdo, NOTHING)
            self._emcy.clear(self._emcy.keys("rpdo"))
        if early:
            for number, tpdo in self._tpdos.items():
                if number not in early:
                    continue
                if new is NmtState.PRE_OPERATIONAL and not tpdo.trigger.active:
                    tpdo.start(now)
                    self._apply(tpdo, NOTHING)
                elif new is not NmtState.OPERATIONAL and new is not NmtState.PRE_OPERATIONAL:
                    tpdo.stop()
                    self._apply(tpdo, NOTHING)

    def _tpdo_active(self, number: int) -> bool:
        """Whether TPDO ``number`` transmits in the current NMT state."""
        if self._operational:
            return True
        return (
            number in self._core.deviations.tpdos_outside_operational
            and self._core.nmt.state is NmtState.PRE_OPERATIONAL
        )

    def _mapping_values(self, index: int) -> list[int]:
        if self._core.deviations.direct_pdo_mapping:  # every entry counts; zero ones are unused
            return [
                int(self._core.value(index, sub, 0))
                for sub in range(1, 65)
                if (index << 8 | sub) in self._core.entries
            ]
        count = int(self._core.value(index, 0, 0))
        return [int(self._core.value(index, sub, 0)) for sub in range(1, count + 1)]

    def _drop_tpdo(self, number: int) -> None:
        tpdo = self._tpdos.pop(number, None)
        if tpdo is None:
            return
        for entry in tpdo.sources:
            if tpdo in entry.tpdos:
                entry.tpdos.remove(tpdo)
        if tpdo.subscription is not None:
            tpdo.subscription.cancel()
        if tpdo.host is not None:
            tpdo.host.close()
        tpdo.host = None
        self._sync_tpdos = [t for t in self._sync_tpdos if t is not tpdo]

    def _drop_rpdo(self, number: int) -> None:
        rpdo = self._rpdos.pop(number, None)
        if rpdo is None:
            return
        if rpdo.subscription is not None:
            rpdo.subscription.cancel()
        if rpdo.host is not None:
            rpdo.host.close()
        rpdo.host = None
        self._sync_rpdos = [r for r in self._sync_rpdos if r is not rpdo]
        self._emcy.clear([("rpdo", number)])

    def _build_tpdo(self, number: int) -> None:
        self._drop_tpdo(number)
        comm = 0x1800 + number - 1
        try:
            cob = PdoCobId.from_u32(self._cob_id(comm))
            if not cob.valid:
                return
            tt = TransmissionType(int(self._core.value(comm, 2, 255)))
            pdo_map, sources = compile_mapping(
                self._core.entries, self._mapping_values(0x1A00 + number - 1), receive=False
            )
            tpdo = Tpdo(
                number,
                cob,
                tt,
                pdo_map,
                sources,
                inhibit_time_100us=int(self._core.value(comm, 3, 0)),
                event_timer_ms=int(self._core.value(comm, 5, 0)),
                sync_start_value=int(self._core.value(comm, 6, 0)),
            )
        except (CobusError, SdoAbort) as exc:
            self._core.report(f"TPDO {number}", exc)
            return
        tpdo.host = self._core.network.attach(tpdo)
        if cob.rtr_allowed:
            tpdo.subscription = self._core.network.subscribe(
                cob.can_id, partial(self._on_tpdo_rtr, tpdo), extended=cob.extended
            )
        for entry in sources:
            if tpdo not in entry.tpdos:
                entry.tpdos.append(tpdo)
        self._tpdos[number] = tpdo
        if tt.synchronous:
            self._sync_tpdos.append(tpdo)
            self._sync_tpdos.sort(key=lambda t: t.number)
        if self._tpdo_active(number):
            tpdo.start(self._core.network.time())
            tpdo.host.apply(NOTHING)

    def _on_tpdo_rtr(self, tpdo: Tpdo, frame: Frame, now: float) -> None:
        if frame.rtr and self._tpdo_active(tpdo.number) and tpdo.host is not None:
            tpdo.host.feed(frame, now)

    def _build_rpdo(self, number: int) -> None:
        self._drop_rpdo(number)
        comm = 0x1400 + number - 1
        try:
            cob = PdoCobId.from_u32(self._cob_id(comm))
            if not cob.valid:
                return
            tt = TransmissionType(int(self._core.value(comm, 2, 255)))
            pdo_map, targets = compile_mapping(
                self._core.entries, self._mapping_values(0x1600 + number - 1), receive=True
            )
            rpdo = Rpdo(
                number, cob, tt, pdo_map, targets, event_timer_ms=int(self._core.value(comm, 5, 0))
            )
        except (CobusError, SdoAbort) as exc:
            self._core.report(f"RPDO {number}", exc)
            return
        if self._core.deviations.partial_rpdos:
            rpdo.watchdog.length = None  # no RPDO length is an error
        rpdo.host = self._core.network.attach(rpdo, (), partial(self._on_rpdo_event, rpdo))
        rpdo.subscription = self._core.network.subscribe(
            cob.can_id, partial(self._on_rpdo_frame, rpdo), extended=cob.extended
        )
        self._rpdos[number] = rpdo
        if rpdo.synchronous:
            self._sync_rpdos.append(rpdo)
            self._sync_rpdos.sort(key=lambda r: r.number)

    def _on_rpdo_frame(self, rpdo: Rpdo, frame: Frame, now: float) -> None:
        if not self._operational or frame.rtr:
            return
        host = rpdo.host
        if host is None:
            return
        watchdog = rpdo.watchdog
        out = watchdog.on_frame(frame, now)
        if out is not NOTHING or watchdog.event_timer_ms:
            # Without an event timer the watchdog never has a deadline, and its host no armed
            # timer (1400h sub 5 written rebuilds the RPDO and its host): with nothing to
            # report there is nothing to apply, two calls less per frame.
            host.apply(out)
        data = frame.data
        if len(data) < rpdo.map.length:
            if not self._core.deviations.partial_rpdos:
                return
            values = self._covered_values(rpdo, data)
        else:
            values = rpdo.map.unpack(data)
        if rpdo.synchronous:
            if not self._sync_window(now):
                return  # after the synchronous window (1007h): discarded until the next SYNC
            rpdo.pending = values
        else:
            self._apply_rpdo(rpdo, values)

    @staticmethod
    def _covered_values(rpdo: Rpdo, data: bytes) -> tuple[Any, ...]:
        """The values of the objects a short RPDO covers completely, in mapping order."""
        available = len(data) * 8
        covered = 0
        end = 0
        for mapped in rpdo.map.entries:
            end += mapped.bit_length
            if end > available:
                break
            if not mapped.is_dummy:
                covered += 1
        padded = data + bytes(rpdo.map.length - len(data))
        return rpdo.map.unpack(padded)[:covered]

    def _apply_rpdo(self, rpdo: Rpdo, values: tuple[Any, ...]) -> None:
        """Write ``values`` to the RPDO's targets (the first ``len(values)`` of them)."""
        core = self._core
        written: list[tuple[int, int]] = []
        applied: list[Any] = []
        for entry, value in zip(rpdo.targets[: len(values)], values, strict=True):
            try:
                if entry.limited:
                    value = check_value(entry, value)
                if entry.writer is not None:
                    core.call_writer(entry, value)
            except SdoAbort:
                continue
            if entry.tpdos:
                core.store(entry, value)
            else:  # store's work when no TPDO maps the entry, a call less per value
                entry.value = value
            written.append((entry.index, entry.subindex))
            applied.append(value)
        # asked after the writes: a write callback may have added a listener
        if core.listeners or core.heard_by_network:  # else no RpdoReceived is built
            core.emit(RpdoReceived(core.node_id, rpdo.number, tuple(written), tuple(applied)))

    def _on_rpdo_event(self, rpdo: Rpdo, event: Event) -> None:
        node = self._core.node_id
        if isinstance(event, RpdoTooShort):
            self._emcy.one_shot(EmcyCode.PDO_LENGTH_ERROR, COMM_BIT)
            self._core.emit(
                WrongLengthRpdoReceived(node, rpdo.number, event.expected, event.received)
            )
        elif isinstance(event, RpdoTooLong):
            self._emcy.one_shot(EmcyCode.PDO_LENGTH_EXCEEDED, COMM_BIT)
            self._core.emit(
                WrongLengthRpdoReceived(node, rpdo.number, event.expected, event.received)
            )
        elif isinstance(event, RpdoTimeout):
            self._emcy.raise_error(("rpdo", rpdo.number), EmcyCode.RPDO_TIMEOUT, COMM_BIT)
            self._core.emit(RpdoLost(node, rpdo.number, event.cob_id))
        elif isinstance(event, RpdoResumed):
            self._emcy.clear([("rpdo", rpdo.number)])
            self._core.emit(RpdoRestored(node, rpdo.number, event.cob_id))

    def on_sync(self, counter: int | None) -> None:
        """A SYNC: the synchronous RPDOs received since the last one take effect, the
        synchronous TPDOs count it and send when due."""
        if self._operational:
            for rpdo in self._sync_rpdos:
                pending = rpdo.pending
                if pending is not None:
                    rpdo.pending = None
                    self._apply_rpdo(rpdo, pending)
            tpdos = self._sync_tpdos
        else:
            tpdos = [t for t in self._sync_tpdos if self._tpdo_active(t.number)]
        if tpdos:
            now = self._core.now()  # after the RPDOs' callbacks, as the TPDOs sample then
            for tpdo in tpdos:
                self._apply(tpdo, tpdo.on_sync(counter, now))

    def _cob_id(self, comm_index: int, value: int | None = None) -> int:
        """The CiA 301 form of the COB-ID of the PDO with this communication index."""
        tx = comm_index >= 0x1800
        number = comm_index - (0x1800 if tx else 0x1400) + 1
        if value is None:
            value = int(self._core.value(comm_index, 1, INVALID))
        return self._core.cob_id("tpdo" if tx else "rpdo", number, value)

    def _valid(self, comm_index: int) -> bool:
        return not self._cob_id(comm_index) & INVALID

    def _w_comm(self, entry: Entry, value: Any) -> None:
        index, sub = entry.index, entry.subindex
        tx = index >= 0x1800
        number = index - (0x1800 if tx else 0x1400) + 1
        kind = "TPDO" if tx else "RPDO"
        deviations = self._core.deviations
        valid = self._valid(index) and not deviations.pdo_params_while_valid
        if sub == 0:
            raise abort(_ABORT.WRITE_READ_ONLY, f"0x{index:04X} sub 0 is read-only")
        if sub == 1:
            try:
                new = PdoCobId.from_u32(self._cob_id(index, value))
                old = PdoCobId.from_u32(self._cob_id(index, int(entry.value)))
            except PdoError as exc:
                raise abort(_ABORT.INVALID_VALUE, str(exc)) from None
            if valid and new.valid and (new.can_id, new.extended) != (old.can_id, old.extended):
                raise abort(
                    _ABORT.INVALID_VALUE,
                    f"{kind} {number}: the identifier cannot change while the PDO is valid; "
                    "write the COB-ID with bit 31 set first",
                )
            if new.valid:
                if not new.extended and is_restricted_can_id(new.can_id):
                    raise abort(
                        _ABORT.INVALID_VALUE,
                        f"{kind} {number}: identifier 0x{new.can_id:X} is restricted (CiA 301: "
                        "NMT, SYNC/EMCY, SDO, error control)",
                    )
                map_index = (0x1A00 if tx else 0x1600) + number - 1
                compile_mapping(self._core.entries, self._mapping_values(map_index), receive=not tx)
        elif sub == 2:
            try:
                tt = TransmissionType(value)
            except PdoError as exc:
                raise abort(_ABORT.INVALID_VALUE, str(exc)) from None
            if not tx and not tt.valid_for_rpdo:
                raise abort(
                    _ABORT.INVALID_VALUE,
                    f"RPDO {number}: transmission type {value} is for TPDOs only (RPDOs use "
                    "0-240, 254, 255)",
                )
            allowed = deviations.transmission_types
            if allowed is not None and value not in allowed:
                listing = ", ".join(str(t) for t in sorted(allowed))
                raise abort(
                    _ABORT.INVALID_VALUE,
                    f"{kind} {number}: this device does not support transmission type {value} "
                    f"(it accepts {listing})",
                )
        elif sub in (3, 6) and valid:
            what = "inhibit time" if sub == 3 else "SYNC start value"
            raise abort(
                _ABORT.INVALID_VALUE,
                f"{kind} {number}: the {what} cannot change while the PDO is valid; set bit 31 "
                "of its COB-ID first",
            )
        if sub == 6 and value > 240:
            raise abort(_ABORT.VALUE_TOO_HIGH, f"SYNC start value {value} is above 240")
        self._core.store(entry, value)
        if self._core.started and sub in (1, 2, 3, 5, 6):
            if tx:
                self._build_tpdo(number)
            else:
                self._build_rpdo(number)

    def _w_mapping(self, entry: Entry, value: Any) -> None:
        index, sub = entry.index, entry.subindex
        tx = index >= 0x1A00
        number = index - (0x1A00 if tx else 0x1600) + 1
        comm = (0x1800 if tx else 0x1400) + number - 1
        kind = "TPDO" if tx else "RPDO"
        if self._core.deviations.direct_pdo_mapping:
            self._w_direct_mapping(entry, value, tx, number)
            return
        if self._valid(comm):
            raise abort(
                _ABORT.PARAMETER_INCOMPATIBLE,
                f"{kind} {number} is valid: set bit 31 of its COB-ID (0x{comm:04X} sub 1) "
                "before changing its mapping",
            )
        if sub == 0:
            slots = sum(1 for s in range(1, 65) if (index << 8 | s) in self._core.entries)
            if value > slots:
                raise abort(
                    _ABORT.VALUE_TOO_HIGH,
                    f"{kind} {number} has {slots} mapping entries; it cannot count {value}",
                )
            values = [int(self._core.value(index, s, 0)) for s in range(1, value + 1)]
            compile_mapping(self._core.entries, values, receive=not tx)
        else:
            if self._core.value(index, 0, 0):
                raise abort(
                    _ABORT.PARAMETER_INCOMPATIBLE,
                    f"{kind} {number}: write sub-index 0 = 0 before changing mapping entries",
                )
            try:
                check_mapping_entry(self._core.entries, value, receive=not tx)
            except PdoError as exc:
                raise abort(_ABORT.INVALID_VALUE, str(exc)) from None
        self._core.store(entry, value)

    def _w_direct_mapping(self, entry: Entry, value: Any, tx: bool, number: int) -> None:
        """A mapping entry written the direct way (:attr:`Deviations.direct_pdo_mapping`)."""
        index, sub = entry.index, entry.subindex
        kind = "TPDO" if tx else "RPDO"
        if sub == 0:
            raise abort(
                _ABORT.WRITE_READ_ONLY,
                f"{kind} {number}: sub-index 0 counts the mapping entries; write the entries "
                "themselves (0 = unused)",
            )
        if value and not value & 0xFF:  # no bit length given: the device fills it in
            target = MappingEntry.from_u32(value)
            if target.is_dummy:
                bits = DataType(target.index).bit_length
            else:
                mapped = self._core.entries.get(target.index << 8 | target.subindex)
                bits = mapped.var.bit_length if mapped is not None else None
            if bits:
                value |= bits
        try:
            check_mapping_entry(self._core.entries, value, receive=not tx)
        except PdoError as exc:
            raise abort(_ABORT.INVALID_VALUE, str(exc)) from None
        values = [
            value if s == sub else int(self._core.value(index, s, 0))
            for s in range(1, 65)
            if (index << 8 | s) in self._core.entries
        ]
        compile_mapping(self._core.entries, values, receive=not tx)
        self._core.store(entry, value)
        if self._core.started:
            if tx:
                self._build_tpdo(number)
            else:
                self._build_rpdo(number)

    def _apply(self, pdo: Tpdo | Rpdo, out: Any) -> None:
        host = pdo.host
        if host is not None:
            host.apply(out)
