"""The PDOs of a remote node, as the node's client sees them: ``node.tpdo`` and ``node.rpdo``.

A PDO's configuration (COB-ID, transmission type, inhibit time, event timer, mapping) comes
from the node itself over SDO (:meth:`AsyncPdoSet.read`), from its EDS
(:meth:`AsyncPdoSet.load_from_od`) or from code (:meth:`AsyncRemotePdo.clear` /
:meth:`AsyncRemotePdo.add`), and goes back to the node with the CiA 301 mapping procedure
(:meth:`AsyncPdoSet.save`). Mapped values are named after their
objects (``"Statusword"``; ``"Parent.Sub"`` for a sub-object of a record or array), looked up
with case and separators ignored, or addressed as ``(index, subindex)``.

A TPDO of the node (which this side receives) decodes every frame into named values:
``node.tpdo[1]["Statusword"]``, ``add_callback``, ``await wait_for_reception()``. An RPDO of
the node (which this side sends) holds values to send: ``node.rpdo[1]["Controlword"] = 6``,
``transmit()``, or ``start(period)`` for a periodic transmission.

Choices where CiA 301 leaves one: values of a PDO not yet received (or not yet set) are those
of all-zero data bytes; a TPDO frame shorter than its mapping is not decoded but reported as
:class:`PdoRejected` (longer frames are decoded, extra bytes ignored, as CiA 301 says).
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Final

from cobus._moved import renamed_names
from cobus.errors import CobusError
from cobus.od import (
    DataType,
    Record,
    Variable,
    decode,
    did_you_mean,
    encode,
    match_name,
)
from cobus.proto import Event, Frame
from cobus.proto.pdo import (
    MAX_PDO_ENTRIES,
    FieldCodec,
    Kind,
    MappingEntry,
    PdoCobId,
    PdoError,
    PdoLengthError,
    PdoMap,
    RemapStep,
    TransmissionType,
    in_remap_order,
    kind_of_type,
    rpdo_default_can_id,
    tpdo_default_can_id,
)
from cobus.proto.sdo import SdoAbortCode, SdoAbortedError, SdoError
from cobus.runtime._service import Callbacks, Waiters, check_not_bool, removed_error
from cobus.runtime.errors import PdoConfigurationError, PdoTimeoutError

if TYPE_CHECKING:
    from cobus.od import ObjectDictionary
    from cobus.runtime.network import AsyncNetwork, Subscription
    from cobus.runtime.remote import SdoChannel

__all__ = [
    "AsyncPdoSet",
    "AsyncRemotePdo",
    "PdoConfigurationError",
    "PdoField",
    "PdoReceived",
    "PdoRejected",
    "PdoTimeoutError",
    "field_kind",
]

MAX_PDOS = 512
_COMM = {True: 0x1800, False: 0x1400}  # by "the node transmits it"
_MAP = {True: 0x1A00, False: 0x1600}


@dataclass(frozen=True, slots=True)
class PdoReceived(Event):
    """A TPDO of ``node_id`` arrived and was decoded: ``values`` by name, at ``time``."""

    node_id: int
    number: int
    values: dict[str, Any]
    time: float


@dataclass(frozen=True, slots=True)
class PdoRejected(Event):
    """A frame on a TPDO's identifier that does not carry its mapping (too short)."""

    node_id: int
    number: int
    data: bytes
    reason: str


# --------------------------------------------------------------------------- field codecs


class _BytesOfType:
    """A :class:`FieldCodec` for types without a :class:`Kind` (strings, TIME_OF_DAY...)."""

    __slots__ = ("_dt",)

    def __init__(self, data_type: DataType) -> None:
        self._dt = data_type

    def encode(self, value: Any, bits: int) -> int:
        data = encode(self._dt, value)[: bits // 8]
        return int.from_bytes(data, "little")

    def decode(self, raw: int, bits: int) -> Any:
        data = raw.to_bytes(bits // 8, "little")
        return decode(self._dt, data)


def field_kind(data_type: DataType) -> Kind | FieldCodec:
    """How a mapped object of ``data_type`` is packed into a PDO: proto's rule
    (:func:`~cobus.proto.pdo.kind_of_type`), and a type without a Kind (a string, a time)
    decoded with its type."""
    kind = kind_of_type(data_type)
    return _BytesOfType(data_type) if kind is None else kind


# --------------------------------------------------------------------------- one PDO


@dataclass(frozen=True, slots=True)
class PdoField:
    """One mapped object of a PDO: its name, mapping entry and dictionary entry (None for a
    dummy entry or an object the dictionary does not describe)."""

    name: str
    entry: MappingEntry
    variable: Variable | None

    @property
    def dummy(self) -> bool:
        """Whether the entry is a dummy (a data type index 0001h..0007h that only takes room)."""
        return self.entry.is_dummy


def _field_name(var: Variable | None, entry: MappingEntry) -> str:
    if var is None:
        return f"0x{entry.index:04X}:{entry.subindex:02X}"
    parent = var.parent
    return var.name if parent is None else f"{parent.name}.{var.name}"


class AsyncRemotePdo:
    """One PDO of a remote node (see the module docstring).

    ``transmit_by_node`` is True for the node's TPDOs (this side receives them) and False for
    its RPDOs (this side sends them).
    """

    #: The node-ID of the node the PDO belongs to.
    node_id: Final[int]
    #: The PDO number, 1..512.
    number: Final[int]
    #: True for a TPDO of the node (received here), False for an RPDO (sent from here).
    transmit_by_node: Final[bool]
    #: Whether the node accepts remote requests for it (bit 30 clear).
    rtr_allowed: bool
    #: Sub 2: 0 acyclic sync, 1-240 every n-th SYNC, 252/253 RTR only, 254/255 event.
    transmission_type: int
    #: Sub 3 in 100 µs units (None: the node has none or it was not read).
    inhibit_time: int | None
    #: Sub 5 in ms (None: the node has none or it was not read).
    event_timer: int | None
    #: Sub 6, the SYNC start value (None: the node has none or it was not read).
    sync_start: int | None
    #: When the last frame of a TPDO arrived (None: none yet).
    timestamp: float | None
    #: How many frames were received (TPDO) or sent (RPDO).
    count: int
    #: Whether the configuration was read, loaded or edited (a PDO only looked at is not
    #: listed by its set, nor written by :meth:`AsyncPdoSet.save`).
    configured: bool

    def __init__(self, pdos: AsyncPdoSet, number: int) -> None:
        self._pdos = pdos
        self._network = pdos._network
        self.node_id = pdos.node_id
        self.number = number
        self.transmit_by_node = pdos.transmit_by_node
        default = _default_can_id(self.transmit_by_node, number, self.node_id)
        self._cob_id = default
        self._enabled = default != 0
        self._extended = False
        self.rtr_allowed = True
        self.transmission_type = 255
        self.inhibit_time = None
        self.event_timer = None
        self.sync_start = None
        self.timestamp = None
        self.count = 0
        self.configured = False
        self._fields: list[PdoField] = []
        self._names: list[str] = []  # of the fields that are not dummies, kept with them
        self._codec = PdoMap([])
        self._length = 0  # the mapping's bytes (a shorter frame is refused)
        self._values: dict[str, Any] = {}
        # The data of the last frame, not decoded until someone asks (see _current): set only
        # for a byte-aligned mapping, whose decoding cannot fail once the length is right.
        self._raw: bytes | None = None
        self._lazy = False
        self._callbacks: Callbacks[PdoReceived] = Callbacks(
            self._network,
            f"{'TPDO' if self.transmit_by_node else 'RPDO'} {number} of node {self.node_id}",
        )
        self._waiters: Waiters[PdoReceived] = Waiters(self._network)
        # who would see a PdoReceived, tested on every frame without a call: the lists of
        # the waiters, callbacks and network listeners (changed in place, never replaced)
        self._audience = (self._waiters._items, self._callbacks._callbacks)
        self._listeners = self._network._listeners
        self._subscription: Subscription | None = None
        self._periodic: asyncio.TimerHandle | None = None
        self._period = 0.0

    def __repr__(self) -> str:
        kind = "TPDO" if self.transmit_by_node else "RPDO"
        state = f"0x{self.cob_id:X}" if self.enabled else "disabled"
        names = ", ".join(f.name for f in self._fields if not f.dummy)
        return f"<{kind} {self.number} of node {self.node_id} {state}: {names or 'no mapping'}>"

    # ------------------------------------------------------------------ the identifier
    @property
    def cob_id(self) -> int:
        """The CAN identifier (1400h/1800h sub 1, without flags). Setting it changes it here
        (a TPDO is then received on it); :meth:`save` writes it to the node."""
        return self._cob_id

    @cob_id.setter
    def cob_id(self, value: int) -> None:
        limit = 0x1FFFFFFF if self._extended else 0x7FF
        if not isinstance(value, int) or not 1 <= value <= limit:
            raise PdoError(f"{self._label()}: COB-ID {value!r} is not 1..0x{limit:X}")
        self._cob_id = value
        self._resubscribe()

    @property
    def enabled(self) -> bool:
        """Whether the PDO exists (bit 31 of its COB-ID clear); settable like :attr:`cob_id`."""
        return self._enabled

    @enabled.setter
    def enabled(self, value: bool) -> None:
        self._enabled = bool(value)
        self._resubscribe()

    @property
    def extended(self) -> bool:
        """Whether the identifier is a 29-bit one (bit 29); settable like :attr:`cob_id`."""
        return self._extended

    @extended.setter
    def extended(self, value: bool) -> None:
        self._extended = bool(value)
        self._resubscribe()

    # ------------------------------------------------------------------ the mapping
    @property
    def fields(self) -> tuple[PdoField, ...]:
        """The mapped objects in mapping order, dummies included."""
        return tuple(self._fields)

    @property
    def names(self) -> list[str]:
        """The names of the mapped values (dummies excluded), in mapping order."""
        return list(self._names)

    @property
    def length(self) -> int:
        """The number of data bytes the mapping takes."""
        return self._codec.length

    @property
    def values(self) -> dict[str, Any]:
        """Every mapped value by name: the last received (TPDO) or the ones to send (RPDO)."""
        return dict(self._current())

    def _current(self) -> dict[str, Any]:
        """The values, decoding the last frame's data first if it has not been. Protocol
        code only (on the loop, or under a ``RealTimeLoop``'s protocol lock, where the
        blocking facade runs it too): it changes state, and a frame arriving in the middle
        of it from another thread would be lost."""
        raw = self._raw
        if raw is not None:
            self._raw = None
            # (names and values match by construction; strict= costs ~0.4 µs a frame)
            self._values = dict(zip(self._names, self._codec.unpack(raw)))  # noqa: B905
        return self._values

    def clear(self) -> None:
        """Remove every mapped object (locally; :meth:`AsyncPdoSet.save` writes it to the node)."""
        self._set_fields([])

    def add(self, key: int | str, subindex: int | str = 0, bits: int | None = None) -> PdoField:
        """Map one more object, named or numbered as in the node's dictionary (locally, until
        :meth:`AsyncPdoSet.save`). ``bits`` defaults to the object's size; a data type index
        0001h..0007h with ``bits`` maps a dummy."""
        od = self._pdos.od
        if isinstance(key, int) and 1 <= key <= 7:
            if bits is None:
                raise PdoError(f"a dummy entry of data type {key:04X}h needs its bit length")
            entry = MappingEntry(key, 0, bits)
            return self._append(PdoField(_field_name(None, entry), entry, None))
        if od is None:
            if not isinstance(key, int) or not isinstance(subindex, int) or bits is None:
                raise PdoError(
                    f"node {self.node_id} has no object dictionary: map objects by number "
                    "with their bit length (add(0x6041, 0, 16))"
                )
            entry = MappingEntry(key, subindex, bits)
            return self._append(PdoField(_field_name(None, entry), entry, None))
        var = self._pdos._sdo.variable(key, subindex)
        size = var.bit_length
        where = f"{self._label()}: {var.name!r} (0x{var.index:04X}:{var.subindex:02X})"
        if bits is None:
            if size is None:
                raise PdoError(f"{where} ({var.data_type.name}) has no fixed size: give its bits")
            bits = size
        elif size is not None and bits != size:
            raise PdoError(f"{where} is {var.data_type.name}: it maps with {size} bits, not {bits}")
        if not var.pdo_mappable:
            raise PdoError(f"{where} is not PDO-mappable in the node's EDS")
        if self.transmit_by_node and not var.readable:
            raise PdoError(f"{where} is {var.access}: a TPDO cannot send it")
        if not self.transmit_by_node and not var.writable:
            raise PdoError(f"{where} is {var.access}: an RPDO cannot write it")
        entry = MappingEntry(var.index, var.subindex, bits)
        return self._append(PdoField(_field_name(var, entry), entry, var))

    def _append(self, field: PdoField) -> PdoField:
        if len(self._fields) >= MAX_PDO_ENTRIES:
            raise PdoError(f"a PDO maps at most {MAX_PDO_ENTRIES} objects")
        self._set_fields([*self._fields, field])
        return field

    def _set_fields(self, fields: list[PdoField]) -> None:
        codec = PdoMap([(f.entry, _kind(f)) for f in fields])  # raises for > 64 bits
        names = [f.name for f in fields if not f.dummy]
        zeros = codec.unpack(bytes(codec.length)) if codec.value_count else ()  # may raise too
        # (nothing changed above: a mapping refused leaves the PDO as it was)
        self.configured = True
        self._fields = fields
        self._names = names
        self._codec = codec
        self._length = codec.length
        self._lazy = codec.byte_aligned
        self._raw = None  # (a frame of the old mapping)
        self._values = dict(zip(names, zeros, strict=True))
        self._resubscribe()

    def field(self, key: str | int | tuple[int, int]) -> PdoField:
        """The mapped object named ``key`` (case and separators ignored), or addressed by
        ``index`` / ``(index, subindex)``."""
        fields = [f for f in self._fields if not f.dummy]
        if isinstance(key, tuple | int):
            index, sub = key if isinstance(key, tuple) else (key, 0)
            for f in fields:
                if (f.entry.index, f.entry.subindex) == (index, sub):
                    return f
            raise KeyError(f"{self!r} maps no object 0x{index:04X}:{sub:02X}")
        by_name = {f.name: f for f in fields}
        name = match_name(key, by_name)
        if name is not None:
            return by_name[name]
        # a sub-object by its own name ("Vendor-ID"), when only one mapped object has it
        short: dict[str, list[PdoField]] = {}
        for f in fields:
            if f.variable is not None and f.variable.parent is not None:
                short.setdefault(f.variable.name, []).append(f)
        name = match_name(key, short)
        if name is not None and len(short[name]) == 1:
            return short[name][0]
        raise KeyError(f"{self!r} maps no value {key!r}{did_you_mean(key, by_name)}")

    def __getitem__(self, key: str | int | tuple[int, int]) -> Any:
        return self._current()[self.field(key).name]

    def __setitem__(self, key: str | int | tuple[int, int], value: Any) -> None:
        field = self.field(key)
        try:
            if field.variable is not None:
                check_not_bool(field.variable, value)
                field.variable.check(value)
            else:  # no dictionary: the mapping's bits are all there is to check against
                PdoMap([(field.entry, Kind.UNSIGNED)]).pack([value])
        except ValueError as exc:
            raise type(exc)(f"{self._label()}, {field.name!r}: {exc}") from None
        self._values = {**self._current(), field.name: value}  # events keep the values they had

    def __iter__(self) -> Iterator[str]:
        return iter(self.names)

    def __len__(self) -> int:
        return len(self.names)

    def __contains__(self, key: object) -> bool:
        if not isinstance(key, str | int | tuple):
            return False
        try:
            self.field(key)
        except KeyError:
            return False
        return True

    # ------------------------------------------------------------------ receiving (TPDO)
    def add_callback(self, callback: Callable[[PdoReceived], object]) -> None:
        """Call ``callback(event)`` with each :class:`PdoReceived` of this TPDO."""
        self._callbacks.add(callback)

    def remove_callback(self, callback: Callable[[PdoReceived], object]) -> None:
        """Stop calling ``callback`` (given to :meth:`add_callback`)."""
        self._callbacks.remove(callback)

    async def wait_for_reception(self, timeout: float = 1.0) -> dict[str, Any]:
        """Wait for the next frame of this TPDO and return its values by name;
        :class:`PdoTimeoutError` after ``timeout`` seconds (a frame that arrived before the
        call is in :attr:`values`; a callback sees every one)."""
        self._pdos._check_open()
        if not self.transmit_by_node:
            raise PdoError(f"{self!r} is sent by this side: nothing to receive")
        self._check_enabled()
        event = await self._waiters.wait(
            timeout,
            lambda: PdoTimeoutError(
                f"{self!r}: no frame within {timeout:g} s (is the node operational, the PDO "
                "enabled on it and, for a synchronous PDO, SYNC running?)"
            ),
        )
        return event.values

    def request(self) -> None:
        """Send a remote request (RTR) for this TPDO; the node answers with the PDO if its
        transmission type allows (252/253, or any when it accepts RTR)."""
        if not self.transmit_by_node:
            raise PdoError(f"{self!r} is sent by this side; only a TPDO can be requested")
        self._check_enabled()
        self._network.send(Frame(self.cob_id, rtr=True, dlc=self.length, extended=self.extended))

    def _on_frame(self, frame: Frame, now: float) -> None:
        if frame.rtr:
            return
        data = frame.data
        if len(data) < self._length:
            error = PdoLengthError(self._length, len(data))
            self._network.emit(PdoRejected(self.node_id, self.number, data, str(error)))
            return
        if self._lazy:
            self._raw = data  # decoded when asked for, if ever (a master watching 64 nodes)
        else:  # decoded now: a value out of its type's range is refused before it counts
            values = dict(zip(self._names, self._codec.unpack(data)))  # noqa: B905
            self._raw = None
            self._values = values
        self.timestamp = now
        self.count += 1
        waiting, called = self._audience
        if not (waiting or called or self._listeners):
            return  # nobody to tell: the event is not built (the values are kept above)
        event = PdoReceived(self.node_id, self.number, self._current(), now)
        self._waiters.resolve(event)
        self._callbacks(event)
        self._network.emit(event)

    def _resubscribe(self) -> None:
        if self._subscription is not None:
            self._subscription.cancel()
            self._subscription = None
        if self.transmit_by_node and self.enabled and self._pdos._active:
            self._subscription = self._network.subscribe(
                self.cob_id, self._on_frame, extended=self.extended
            )

    # ------------------------------------------------------------------ sending (RPDO)
    def transmit(self) -> None:
        """Send this RPDO now with its current values."""
        if self.transmit_by_node:
            raise PdoError(f"{self!r} is sent by the node; use request() to ask for it")
        self._pdos._check_open()
        self._check_enabled()
        try:
            values = self._current()
            data = self._codec.pack([values[n] for n in self.names])
        except PdoError as exc:
            raise PdoError(f"{self._label()}: {exc}") from None
        self._network.send(Frame(self.cob_id, data, extended=self.extended))
        self.count += 1

    def start(self, period: float) -> None:
        """Send this RPDO every ``period`` seconds from now on (the first one at once)."""
        if not period > 0:
            raise ValueError(f"PDO period {period!r} s must be > 0")
        self.stop()
        self.transmit()
        self._period = period
        self._schedule(self._network.time() + period)

    def stop(self) -> None:
        """Stop the periodic transmission started with :meth:`start`."""
        if self._periodic is not None:
            self._periodic.cancel()
            self._periodic = None

    @property
    def periodic(self) -> bool:
        """Whether :meth:`start` is sending it periodically."""
        return self._periodic is not None

    def _schedule(self, when: float) -> None:
        self._periodic = self._network.loop.call_at(when, self._tick, when)

    def _tick(self, when: float) -> None:
        self._periodic = None
        if not self._network.connected:
            return
        try:
            self.transmit()
        except CobusError as exc:
            self._network.report_failure(f"periodic {self!r}", exc)
        later = when + self._period
        now = self._network.time()
        # after a stall, go on one period from now instead of sending the missed ones at once
        self._schedule(later if later > now else now + self._period)

    def _check_enabled(self) -> None:
        if not self.enabled:
            raise PdoError(f"{self!r} is disabled (bit 31 of its COB-ID is set)")

    # ------------------------------------------------------------------ configuration
    def _comm(self) -> int:
        return _COMM[self.transmit_by_node] + self.number - 1

    def _map(self) -> int:
        return _MAP[self.transmit_by_node] + self.number - 1

    def _cob_u32(self, *, valid: bool) -> int:
        return PdoCobId(self.cob_id, valid, self.rtr_allowed, self.extended).to_u32()

    def _set_cob(self, value: int) -> None:
        cob = PdoCobId.from_u32(value)
        self._cob_id, self._enabled = cob.can_id, cob.valid
        self.rtr_allowed, self._extended = cob.rtr_allowed, cob.extended

    def _entry_field(self, value: int) -> PdoField:
        entry = MappingEntry.from_u32(value)
        od = self._pdos.od
        var = None if od is None or entry.is_dummy else od.get_variable(entry.index, entry.subindex)
        return PdoField(_field_name(var, entry), entry, var)

    async def read(self) -> None:
        """Read this PDO's communication and mapping parameters from the node over SDO."""
        sdo = self._pdos._sdo
        comm, mapping = self._comm(), self._map()
        step = f"reading {comm:04X}h sub 1"
        try:
            cob = _u(await sdo.upload(comm, 1))
            step = f"reading {comm:04X}h sub 2"
            tt = _u(await sdo.upload(comm, 2))
            inhibit = await _optional(sdo, comm, 3)
            timer = await _optional(sdo, comm, 5)
            start = await _optional(sdo, comm, 6) if self.transmit_by_node else None
            step = f"reading {mapping:04X}h sub 0"
            count = _u(await sdo.upload(mapping, 0))
            values: list[int] = []
            for sub in range(1, min(count, MAX_PDO_ENTRIES) + 1):
                step = f"reading {mapping:04X}h sub {sub}"
                values.append(_u(await sdo.upload(mapping, sub)))
        except SdoError as exc:
            raise PdoConfigurationError(f"{self._label()}: {step} failed: {exc}") from exc
        self._apply(cob, tt, inhibit, timer, start, values)

    def _apply(
        self,
        cob: int,
        tt: int,
        inhibit: int | None,
        timer: int | None,
        start: int | None,
        entries: list[int],
    ) -> None:
        try:
            fields = [self._entry_field(v) for v in entries if v]
            self._set_cob(cob)
            self.transmission_type = tt
            self.inhibit_time, self.event_timer, self.sync_start = inhibit, timer, start
            self._set_fields(fields)
        except PdoError as exc:
            raise PdoConfigurationError(f"{self._label()}: {exc}") from exc

    def _load(self, od: ObjectDictionary) -> bool:
        comm, mapping = od.get(self._comm()), od.get(self._map())
        if not isinstance(comm, Record) or not isinstance(mapping, Record):
            return False
        cob = _od_int(comm, 1)
        if cob is None:
            return False
        count = _od_int(mapping, 0)
        subs = range(1, (count or 0) + 1)
        entries = [v for v in (_od_int(mapping, s) for s in subs) if v is not None]
        tt = _od_int(comm, 2)
        self._apply(
            cob,
            255 if tt is None else tt,
            _od_int(comm, 3),
            _od_int(comm, 5),
            _od_int(comm, 6) if self.transmit_by_node else None,
            entries,
        )
        return True

    async def save(self) -> None:
        """Write this PDO's configuration to the node with the CiA 301 procedure
        (:data:`~cobus.proto.pdo.REMAP_ORDER`): disable it (COB-ID bit 31), set the mapping
        count to 0, write the entries, set the count, write the parameters, enable it
        again."""
        sdo = self._pdos._sdo
        comm, mapping = self._comm(), self._map()
        if not self.configured:
            raise PdoConfigurationError(
                f"{self._label()}: nothing to save: read() it from the node, load_from_od() "
                "or map objects with clear()/add() first (saving would clear its mapping)"
            )
        try:
            TransmissionType(self.transmission_type)
            for what, value, limit in (
                ("inhibit time", self.inhibit_time, 0xFFFF),
                ("event timer", self.event_timer, 0xFFFF),
                ("SYNC start value", self.sync_start, 0xF0),
            ):
                if value is not None and not (isinstance(value, int) and 0 <= value <= limit):
                    raise PdoError(f"{what} {value!r} is out of range: use 0..{limit}")
        except PdoError as exc:
            raise PdoConfigurationError(f"{self._label()}: {exc}") from None

        def u8(v: int) -> bytes:
            return v.to_bytes(1, "little")

        def u16(v: int) -> bytes:
            return v.to_bytes(2, "little")

        def u32(v: int) -> bytes:
            return v.to_bytes(4, "little")

        step = RemapStep
        tagged: list[tuple[RemapStep, tuple[str, int, int, bytes]]] = [
            (step.DISABLE, ("disabling the PDO", comm, 1, u32(self._cob_u32(valid=False)))),
            (
                step.COMMUNICATION,
                ("writing the transmission type", comm, 2, u8(self.transmission_type)),
            ),
        ]
        if self.inhibit_time is not None:
            tagged.append(
                (step.COMMUNICATION, ("writing the inhibit time", comm, 3, u16(self.inhibit_time)))
            )
        if self.event_timer is not None:
            tagged.append(
                (step.COMMUNICATION, ("writing the event timer", comm, 5, u16(self.event_timer)))
            )
        if self.sync_start is not None and self.transmit_by_node:
            tagged.append(
                (step.COMMUNICATION, ("writing the SYNC start value", comm, 6, u8(self.sync_start)))
            )
        tagged.append((step.CLEAR_MAPPING, ("clearing the mapping (sub 0 = 0)", mapping, 0, u8(0))))
        for n, f in enumerate(self._fields, 1):
            what = f"writing mapping entry {n} ({f.name})"
            tagged.append((step.MAP, (what, mapping, n, u32(f.entry.to_u32()))))
        count = len(self._fields)
        tagged.append(
            (step.COUNT, (f"setting the mapping count to {count}", mapping, 0, u8(count)))
        )
        if self.enabled:
            tagged.append(
                (step.ENABLE, ("enabling the PDO", comm, 1, u32(self._cob_u32(valid=True))))
            )
        steps = in_remap_order(tagged)  # (CiA 301's order, as the master's start-up list has it)
        for n, (what, index, sub, data) in enumerate(steps):
            try:
                await sdo.download(index, sub, data)
            except SdoError as exc:
                left = ""
                if n:  # the node may be left half-way: show what it has now
                    try:
                        await self.read()
                        left = f"; the node now has {self!r}"
                    except PdoConfigurationError:
                        left = "; the node may be left with the PDO disabled"
                raise PdoConfigurationError(
                    f"{self._label()}: {what} ({index:04X}h sub {sub}) failed: {exc}{left}"
                ) from exc
        self._resubscribe()

    def _label(self) -> str:
        kind = "TPDO" if self.transmit_by_node else "RPDO"
        return f"{kind} {self.number} of node {self.node_id}"

    def _close(self) -> None:
        self.stop()
        if self._subscription is not None:
            self._subscription.cancel()
            self._subscription = None
        self._waiters.fail(removed_error(self.node_id))


def _kind(field: PdoField) -> Kind | FieldCodec | None:
    if field.dummy:
        return None
    if field.variable is None:
        return Kind.UNSIGNED
    return field_kind(field.variable.data_type)


def _default_can_id(transmit: bool, number: int, node_id: int) -> int:
    if number > 4:
        return 0
    return (
        tpdo_default_can_id(number, node_id) if transmit else rpdo_default_can_id(number, node_id)
    )


def _u(data: bytes) -> int:
    return int.from_bytes(data, "little")


async def _optional(sdo: SdoChannel, index: int, sub: int) -> int | None:
    """A sub-object the node may lack (inhibit time, event timer, SYNC start)."""
    try:
        return _u(await sdo.upload(index, sub))
    except SdoAbortedError as exc:
        if exc.code in (SdoAbortCode.NO_SUBINDEX, SdoAbortCode.NO_OBJECT):
            return None
        raise


def _od_int(obj: Record, sub: int) -> int | None:
    var = obj.get(sub)
    value = None if var is None else var.value
    return value if isinstance(value, int) else None


# --------------------------------------------------------------------------- the set


class AsyncPdoSet:
    """The TPDOs or RPDOs of a remote node by number: ``node.tpdo[1]``.

    Numbers 1..512 can be used; iterating gives the PDOs read, loaded or used so far.
    """

    #: The node-ID of the node.
    node_id: Final[int]
    #: True for ``node.tpdo`` (the node transmits), False for ``node.rpdo``.
    transmit_by_node: Final[bool]

    def __init__(
        self,
        network: AsyncNetwork,
        sdo: SdoChannel,
        *,
        transmit_by_node: bool,
    ) -> None:
        self._network = network
        self._sdo = sdo
        self.node_id = sdo.node_id
        self.transmit_by_node = transmit_by_node
        self._active = True
        self._pdos: dict[int, AsyncRemotePdo] = {}

    @property
    def od(self) -> ObjectDictionary | None:
        """The node's object dictionary (None: the node was added without one)."""
        return self._sdo.od

    def __repr__(self) -> str:
        kind = "TPDOs" if self.transmit_by_node else "RPDOs"
        return f"<{kind} of node {self.node_id}: {[p.number for p in self]}>"

    def __getitem__(self, number: int) -> AsyncRemotePdo:
        if not isinstance(number, int) or not 1 <= number <= MAX_PDOS:
            raise KeyError(f"PDO number {number!r} is out of range: use 1..{MAX_PDOS}")
        pdo = self._pdos.get(number)
        if pdo is None:
            pdo = self._pdos[number] = AsyncRemotePdo(self, number)
        return pdo

    def __iter__(self) -> Iterator[AsyncRemotePdo]:
        """The PDOs read, loaded or edited so far, by number."""
        return iter([self._pdos[n] for n in sorted(self._pdos) if self._pdos[n].configured])

    def __len__(self) -> int:
        """How many PDOs were read, loaded or edited."""
        return sum(1 for pdo in self._pdos.values() if pdo.configured)

    def __contains__(self, number: object) -> bool:
        """Whether PDO ``number`` was read, loaded or edited."""
        pdo = self._pdos.get(number) if isinstance(number, int) else None
        return pdo is not None and pdo.configured

    def _check_open(self) -> None:
        if not self._active:
            raise removed_error(self.node_id)

    def _numbers(self) -> list[int]:
        od = self.od
        base = _COMM[self.transmit_by_node]
        if od is None:
            return [1, 2, 3, 4]
        return [i - base + 1 for i in range(base, base + MAX_PDOS) if i in od]

    def load_from_od(self) -> list[AsyncRemotePdo]:
        """Configure every PDO the node's EDS/DCF describes as the file says; returns them."""
        od = self.od
        if od is None:
            raise PdoConfigurationError(
                f"node {self.node_id} has no object dictionary: give one to add_remote() or "
                "read the PDOs from the node with read()"
            )
        return [self[n] for n in self._numbers() if self[n]._load(od)]

    async def read(self) -> list[AsyncRemotePdo]:
        """Read the configuration of the node's PDOs over SDO (those its dictionary lists;
        1..4 without one, skipping PDOs the node does not have); returns them."""
        found = []
        for number in self._numbers():
            pdo = self[number]
            try:
                await pdo.read()
            except PdoConfigurationError as exc:
                cause = exc.__cause__
                if (
                    isinstance(cause, SdoAbortedError)
                    and cause.code in (SdoAbortCode.NO_OBJECT, SdoAbortCode.NO_SUBINDEX)
                    and self.od is None
                ):
                    self._pdos.pop(number)._close()
                    continue
                raise
            found.append(pdo)
        return found

    async def save(self) -> None:
        """Write every PDO of this set to the node (see :meth:`AsyncRemotePdo.save`)."""
        for pdo in self:
            await pdo.save()

    def stop(self) -> None:
        """Stop every periodic transmission of this set."""
        for pdo in self:
            pdo.stop()

    def _close(self) -> None:
        self._active = False
        for pdo in self._pdos.values():
            pdo._close()


#: The async classes are AsyncX, their blocking twins X (see :mod:`cobus`).
__getattr__ = renamed_names(
    __name__,
    {"RemotePdo": ("AsyncRemotePdo", AsyncRemotePdo), "PdoSet": ("AsyncPdoSet", AsyncPdoSet)},
)
