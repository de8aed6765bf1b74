"""The machines of the device's PDOs, driven by :mod:`cobus.device.pdo`: one :class:`Tpdo`
or :class:`Rpdo` per configured PDO, compiled from its communication and mapping parameters
whenever they change.

A TPDO is a machine (``deadline``/``on_frame``/``on_timer``) around the protocol's
:class:`~cobus.proto.pdo.TpdoTrigger`: it turns the trigger's "due" into the frame, whose data
is one :meth:`PdoMap.pack` of the mapped entries' values. An RPDO unpacks a frame with one
:meth:`PdoMap.unpack`; its :class:`~cobus.proto.pdo.RpdoWatchdog` watches arrival and length.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from cobus.device._entries import Entry
from cobus.od import DataType
from cobus.proto import NOTHING, Frame, Out
from cobus.proto.pdo import (
    MAX_PDO_BITS,
    FieldCodec,
    Kind,
    MappingEntry,
    PdoCobId,
    PdoMap,
    RpdoWatchdog,
    TpdoDue,
    TpdoReason,
    TpdoSample,
    TpdoTrigger,
    TransmissionType,
)
from cobus.proto.sdo import SdoAbort, SdoAbortCode
from cobus.runtime.pdo import field_kind

if TYPE_CHECKING:
    from cobus.runtime.network import MachineHost, Subscription

__all__ = ["Rpdo", "Tpdo", "check_mapping_entry", "compile_mapping", "field_kind"]


def check_mapping_entry(
    entries: dict[int, Entry],
    value: int,
    *,
    receive: bool,
) -> None:
    """Refuse (:class:`SdoAbort`) a mapping entry a PDO of this direction cannot carry."""
    if value == 0:
        return
    entry = MappingEntry.from_u32(value)
    index, sub, bits = entry.index, entry.subindex, entry.bit_length
    kind = "RPDO" if receive else "TPDO"
    where = f"0x{index:04X}:{sub:02X}"
    if entry.is_dummy:  # the device skips the bits of any basic type 0001h..0007h
        expected = DataType(index).bit_length
        if bits != expected:
            raise SdoAbort(
                SdoAbortCode.NOT_MAPPABLE,
                f"a dummy of data type {index:04X}h takes {expected} bits, not {bits}",
            )
        return
    target = entries.get(index << 8 | sub)
    if target is None:
        raise SdoAbort(
            SdoAbortCode.NO_OBJECT, f"{kind} mapping names {where}, which does not exist"
        )
    var = target.var
    if not var.pdo_mappable:
        raise SdoAbort(SdoAbortCode.NOT_MAPPABLE, f"{where} ({var.name!r}) is not PDO-mappable")
    if receive and not var.access.writable:
        raise SdoAbort(
            SdoAbortCode.NOT_MAPPABLE,
            f"{where} ({var.name!r}) is {var.access} and cannot be written by an RPDO",
        )
    if not receive and not var.access.readable:
        raise SdoAbort(
            SdoAbortCode.NOT_MAPPABLE,
            f"{where} ({var.name!r}) is {var.access} and cannot be sent by a TPDO",
        )
    expected_bits = var.bit_length
    if expected_bits is not None:
        ok = bits == expected_bits
    else:  # strings and domains: whole bytes that fit a PDO
        ok = bits % 8 == 0 and 0 < bits <= MAX_PDO_BITS
    if not ok:
        raise SdoAbort(
            SdoAbortCode.NOT_MAPPABLE,
            f"{where} ({var.name!r}) is {var.data_type.name}; it cannot be mapped with {bits} bits",
        )


def compile_mapping(
    entries: dict[int, Entry],
    values: list[int],
    *,
    receive: bool,
) -> tuple[PdoMap, tuple[Entry, ...]]:
    """The compiled mapping of ``values`` (the mapping's entries 1..n) and the entries it maps
    (dummies excluded); :class:`SdoAbort` 06040041/06040042/06020000 when it cannot be."""
    fields: list[tuple[MappingEntry, Kind | FieldCodec | None]] = []
    targets: list[Entry] = []
    total = 0
    for value in values:
        check_mapping_entry(entries, value, receive=receive)
        if value == 0:
            continue
        entry = MappingEntry.from_u32(value)
        total += entry.bit_length
        if entry.is_dummy:
            fields.append((entry, None))
            continue
        target = entries[entry.index << 8 | entry.subindex]
        fields.append((entry, field_kind(target.data_type)))
        targets.append(target)
    if total > MAX_PDO_BITS:
        raise SdoAbort(
            SdoAbortCode.MAPPING_TOO_LONG,
            f"the mapping takes {total} bits; a PDO carries at most {MAX_PDO_BITS}",
        )
    return PdoMap(fields), tuple(targets)


class Tpdo:
    """One transmit PDO: its trigger, compiled mapping and the entries it samples."""

    __slots__ = (
        "_frame_args",
        "_sample",
        "cob",
        "comm_index",
        "host",
        "map",
        "number",
        "sources",
        "subscription",
        "trigger",
    )

    def __init__(
        self,
        number: int,
        cob: PdoCobId,
        transmission_type: TransmissionType,
        pdo_map: PdoMap,
        sources: tuple[Entry, ...],
        *,
        inhibit_time_100us: int,
        event_timer_ms: int,
        sync_start_value: int,
    ) -> None:
        self.number = number
        self.comm_index = 0x1800 + number - 1
        self.cob = cob
        self.map = pdo_map
        self.sources = sources
        self.trigger = TpdoTrigger(
            transmission_type,
            inhibit_time_100us=inhibit_time_100us,
            event_timer_ms=event_timer_ms,
            sync_start_value=sync_start_value,
        )
        self._sample: bytes | None = None
        self._frame_args = (cob.can_id, cob.extended)
        self.host: MachineHost | None = None
        self.subscription: Subscription | None = None

    @property
    def transmission_type(self) -> TransmissionType:
        """The TPDO's transmission type (1800h+ sub 2)."""
        return self.trigger.transmission_type

    @property
    def synchronous(self) -> bool:
        """Whether the TPDO is sent on SYNC (types 0..240 and 252)."""
        return self.trigger.transmission_type.synchronous

    @property
    def deadline(self) -> float | None:
        return self.trigger.deadline

    def pack(self) -> bytes:
        """The PDO data of the mapped entries' current values."""
        return self.map.pack([e.value if e.reader is None else e.reader() for e in self.sources])

    def frame(self) -> Frame:
        """The TPDO's frame with the mapped objects' current values."""
        can_id, extended = self._frame_args
        return Frame(can_id, self.pack(), extended=extended)

    def _out(self, out: Out) -> Out:
        if not out.events:
            return NOTHING
        frames: list[Frame] = []
        can_id, extended = self._frame_args
        for event in out.events:
            if isinstance(event, TpdoDue):
                if event.reason is TpdoReason.RTR and self._sample is not None:
                    data = self._sample
                else:
                    data = self.pack()
                frames.append(Frame(can_id, data, extended=extended))
            elif isinstance(event, TpdoSample):
                self._sample = self.pack()
        return Out(tuple(frames), ())

    def start(self, now: float) -> None:
        """Start the triggers (the device entered OPERATIONAL)."""
        self._sample = None
        self.trigger.start(now)

    def stop(self) -> None:
        """Stop the triggers (the device left OPERATIONAL)."""
        self._sample = None
        self.trigger.stop()

    def on_frame(self, frame: Frame, now: float) -> Out:
        if not frame.rtr or frame.cob_id != self.cob.can_id or frame.extended != self.cob.extended:
            return NOTHING
        return self._out(self.trigger.on_rtr(now))

    def on_timer(self, now: float) -> Out:
        return self._out(self.trigger.on_timer(now))

    def on_sync(self, counter: int | None, now: float) -> Out:
        """A SYNC arrived (``counter``: its counter, if any): the frame if the TPDO is due."""
        return self._out(self.trigger.on_sync(counter, now))

    def on_change(self, now: float) -> Out:
        """A mapped object changed: the frame if an event-driven TPDO is due."""
        return self._out(self.trigger.on_change(now))


class Rpdo:
    """One receive PDO: compiled mapping, the entries it writes, arrival watchdog."""

    __slots__ = (
        "cob",
        "comm_index",
        "host",
        "map",
        "number",
        "pending",
        "subscription",
        "synchronous",
        "targets",
        "watchdog",
    )

    def __init__(
        self,
        number: int,
        cob: PdoCobId,
        transmission_type: TransmissionType,
        pdo_map: PdoMap,
        targets: tuple[Entry, ...],
        *,
        event_timer_ms: int,
    ) -> None:
        self.number = number
        self.comm_index = 0x1400 + number - 1
        self.cob = cob
        self.map = pdo_map
        self.targets = targets
        self.synchronous = transmission_type.synchronous
        self.watchdog = RpdoWatchdog(
            cob.can_id, event_timer_ms, extended=cob.extended, length=pdo_map.length
        )
        #: Values received for a synchronous RPDO, applied at the next SYNC.
        self.pending: tuple[Any, ...] | None = None
        self.host: MachineHost | None = None
        self.subscription: Subscription | None = None

    @property
    def deadline(self) -> float | None:
        return self.watchdog.deadline

    def on_frame(self, frame: Frame, now: float) -> Out:
        return self.watchdog.on_frame(frame, now)

    def on_timer(self, now: float) -> Out:
        return self.watchdog.on_timer(now)

    def disarm(self) -> None:
        """Leaving operational: the watchdog waits for the first RPDO again."""
        ms = self.watchdog.event_timer_ms
        self.watchdog.set_event_timer(0, 0.0)
        self.watchdog.set_event_timer(ms, 0.0)
        self.pending = None
