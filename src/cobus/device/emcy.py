"""The device's emergencies: the EMCY producer, the active errors and what they show in the
error register 1001h, the pre-defined error field 1003h, the EMCY COB-ID 1014h and inhibit
time 1015h.

Errors are kept by key: ``("app", code)`` for the application's (:meth:`Device.send_emergency
<cobus.device.Device.send_emergency>`), and a key of the service that found it for the
device's own communication errors (``("rpdo", n)``, ``("sync",)``, ``("hb", node)``,
``("guard",)``). An error raised sends its emergency and stays in 1001h until it is cleared;
the last one cleared sends the "error reset" emergency 0000h.

Choices where CiA 301 leaves one: the generic bit 0 of 1001h is set while any error is active
(unless the device's deviations say otherwise); in stopped an emergency is only recorded in
1003h, not sent; 1003h holds at most 254 errors, newest first, as many as the dictionary has
sub-indexes for.
"""

from __future__ import annotations

from functools import partial
from typing import TYPE_CHECKING, Any

from cobus.device._core import Core, abort
from cobus.device._entries import Entry
from cobus.device._objects import RO, RW, U8, U16, U32, composite, var
from cobus.device.events import EmergencySent
from cobus.errors import CobusError
from cobus.od import Array, NodeRelative, ObjectDictionary, Record
from cobus.proto import NOTHING
from cobus.proto import emcy as _emcy
from cobus.proto.emcy import EmcyProducer, ErrorRegister
from cobus.proto.nmt import NmtState
from cobus.proto.sdo import SdoAbort, SdoAbortCode

if TYPE_CHECKING:
    from cobus.runtime.network import MachineHost

__all__ = ["COMM_BIT", "ERROR_REGISTER", "EmcyService", "class_bits", "define_objects"]

_ABORT = SdoAbortCode
_GENERIC = int(ErrorRegister.GENERIC)
#: The error register object (mandatory in every CiA 301 device).
ERROR_REGISTER = 0x1001
#: The error register's communication bit, set by the device's own communication errors.
COMM_BIT = int(ErrorRegister.COMMUNICATION)


def class_bits(code: int) -> int:
    """The error register bits an emergency code stands for (CiA 301 error register)."""
    high = code >> 12
    if high == 0x2:
        return int(ErrorRegister.CURRENT)
    if high == 0x3:
        return int(ErrorRegister.VOLTAGE)
    if high == 0x4:
        return int(ErrorRegister.TEMPERATURE)
    if code >> 8 in (0x81, 0x82):
        return COMM_BIT
    if code >> 8 == 0xFF:
        return int(ErrorRegister.MANUFACTURER)
    return 0


def _history_depth(od: ObjectDictionary) -> int:
    obj = od.get(0x1003)
    if isinstance(obj, Record | Array):
        return min(max((s for s in obj.subindices if s), default=0), 254)
    return 0


def define_objects(od: ObjectDictionary, *, history: int) -> None:
    """1001h, 1003h with ``history`` entries (none: no 1003h), 1014h on 80h + node-ID and
    1015h (no inhibit time)."""
    od.add(var(ERROR_REGISTER, 0, "Error register", U8, RO, 0, mappable=True))
    if history:
        composite(
            od,
            Array(0x1003, "Pre-defined error field"),
            [
                (0, "Number of errors", U8, 0),
                *((n, f"Standard error field {n}", U32, 0) for n in range(1, history + 1)),
            ],
            first=RW,  # a master writes 0 to clear the history
            rest=RO,
        )
    od.add(var(0x1014, 0, "COB-ID EMCY", U32, RW, NodeRelative(0x80)))
    od.add(var(0x1015, 0, "Inhibit time EMCY", U16, RW, 0))


class EmcyService:
    """EMCY of one device: producer, active errors, 1001h, 1003h, 1014h, 1015h."""

    def __init__(self, core: Core, *, queue_size: int) -> None:
        self._core = core
        self.producer = EmcyProducer(
            core.machine_node_id, depth=_history_depth(core.od), queue_size=queue_size
        )
        self._errors: dict[object, int] = {}
        self._host: MachineHost | None = None
        core.handle(ERROR_REGISTER, self._w_error_register)
        core.handle(0x1003, self._w_error_field)
        core.handle(0x1014, self._w_cob_id)
        core.handle(0x1015, self._w_inhibit)
        core.follows_node_id(0x1014, 0, _emcy.EMCY_BASE)
        core.not_stored.add(0x1003)  # the history is the device's record, not a parameter
        for sub in range(0, 255):
            entry = core.entries.get(0x1003 << 8 | sub)
            if entry is not None:
                entry.reader = partial(self._read_error_field, sub)

    # ------------------------------------------------------------------ state

    @property
    def history(self) -> tuple[int, ...]:
        """1003h sub 1..: the errors recorded, newest first (code | info << 16)."""
        return self.producer.history

    def register(self) -> int:
        """1001h: the bits of the active errors (and the generic bit with any)."""
        bits = 0
        for value in self._errors.values():
            bits |= value
        if self._errors and self._core.deviations.generic_error_bit:
            bits |= _GENERIC
        return bits

    def keys(self, kind: str) -> list[Any]:
        """The keys of the active errors of one kind (``"app"``, ``"rpdo"``, ``"hb"`` …)."""
        return [k for k in self._errors if isinstance(k, tuple) and k[0] == kind]

    # ------------------------------------------------------------------ life cycle

    def build(self, now: float) -> None:
        """Start producing with the COB-ID 1014h and inhibit time 1015h (reset communication)."""
        core = self._core
        node = core.node_id
        emcy = self.producer
        try:
            emcy.set_cob_id(
                core.cob_id("emcy", 1, int(core.value(0x1014, 0, _emcy.EMCY_BASE + node)))
            )
        except (CobusError, SdoAbort) as exc:
            core.report("1014h", exc)
            emcy.set_cob_id(_emcy.EMCY_BASE + node)
        emcy.set_inhibit_time(int(core.value(0x1015, 0)), now)
        self._host = core.network.attach(emcy, ())

    def close(self) -> None:
        """Stop producing (before a reset communication or when the device closes)."""
        if self._host is not None:
            self._host.close()
            self._host = None

    def set_node_id(self, node_id: int) -> None:
        """Produce under ``node_id`` from the next build on."""
        self.producer.node_id = node_id if node_id <= 127 else 1  # (FFh: not built)

    def power_on(self, *, communication: bool, application: bool) -> None:
        """A reset: communication clears the device's own errors, reset node all of them and
        the history."""
        if communication:
            self._errors = {
                k: v for k, v in self._errors.items() if isinstance(k, tuple) and k[0] == "app"
            }
        if application:
            self._errors.clear()
            self.producer = EmcyProducer(
                self._core.machine_node_id,
                depth=_history_depth(self._core.od),
                queue_size=self.producer.queue_size,
            )
        self._sync_error_objects()

    # ------------------------------------------------------------------ errors

    def raise_error(
        self, key: object, code: int, bits: int, manufacturer: bytes = b"", info: int = 0
    ) -> None:
        """Raise an error; keys other than ("app", code) are the device's own communication
        errors, left to the application when the deviations say so."""
        if not self._core.deviations.comm_error_emcy and not (
            isinstance(key, tuple) and key[0] == "app"
        ):
            return
        self._errors[key] = bits
        self._emergency(code, self.register(), manufacturer, info)

    def one_shot(self, code: int, bits: int) -> None:
        """A communication error that is over as it happens (PDO and SYNC lengths)."""
        deviations = self._core.deviations
        if not deviations.comm_error_emcy:
            return
        generic = _GENERIC if deviations.generic_error_bit else 0
        self._emergency(code, self.register() | bits | generic, b"", 0)

    def clear(self, keys: list[Any], manufacturer: bytes = b"") -> None:
        """End the errors of ``keys``; when any was active, the 'error reset' emergency."""
        removed = False
        for key in keys:
            if self._errors.pop(key, None) is not None:
                removed = True
        if not removed:
            return
        core = self._core
        register = self.register()
        host = self._host
        if host is not None and self._allowed():
            host.apply(self.producer.reset(core.now(), register, manufacturer))
        self._sync_error_objects()
        core.emit(EmergencySent(core.node_id, 0, register, manufacturer))

    def _allowed(self) -> bool:
        nmt = self._core.nmt
        if nmt.emcy_allowed:
            return True
        return self._core.deviations.emcy_in_stopped and nmt.state is NmtState.STOPPED

    def _sync_error_objects(self) -> None:
        core = self._core
        entry = core.entries.get(ERROR_REGISTER << 8)
        if entry is not None:
            core.store(entry, self.register())
        self.producer.error_register = ErrorRegister(self.register())

    def _emergency(self, code: int, register: int, manufacturer: bytes, info: int) -> None:
        core = self._core
        host = self._host
        if host is not None and self._allowed():
            host.apply(self.producer.send(code, register, manufacturer, core.now(), info=info))
        else:
            self.producer.record(code, info)
        self._sync_error_objects()
        core.emit(EmergencySent(core.node_id, code, register, manufacturer))

    # ------------------------------------------------------------------ objects

    def _read_error_field(self, sub: int) -> int:
        history = self.producer.history
        if sub == 0:
            return len(history)
        if sub > len(history):
            raise abort(_ABORT.NO_DATA, f"1003h sub {sub} holds no error ({len(history)} recorded)")
        return history[sub - 1]

    def _w_error_register(self, entry: Entry, value: Any) -> None:
        raise abort(
            _ABORT.UNSUPPORTED_ACCESS,
            "the error register follows the active errors: use send_emergency() and "
            "clear_emergency()",
        )

    def _w_error_field(self, entry: Entry, value: Any) -> None:
        if entry.subindex != 0:
            raise abort(_ABORT.UNSUPPORTED_ACCESS, "1003h entries are recorded by the device")
        if value != 0:
            raise abort(_ABORT.INVALID_VALUE, "1003h sub 0 accepts only 0 (clear the history)")
        self.producer.write_error_count(0)
        entry.value = 0

    def _w_cob_id(self, entry: Entry, value: Any) -> None:
        core = self._core
        try:
            new = _emcy.EmcyCobId.from_u32(core.cob_id("emcy", 1, value))
            old = _emcy.EmcyCobId.from_u32(core.cob_id("emcy", 1, int(entry.value)))
        except CobusError as exc:
            raise abort(_ABORT.INVALID_VALUE, str(exc)) from None
        if old.valid and new.valid and (old.can_id, old.extended) != (new.can_id, new.extended):
            raise abort(
                _ABORT.INVALID_VALUE,
                "1014h: the EMCY identifier cannot change while it is valid; write it with "
                "bit 31 set first",
            )
        core.store(entry, value)
        self.producer.set_cob_id(new.to_u32())

    def _w_inhibit(self, entry: Entry, value: Any) -> None:
        self._core.store(entry, value)
        self.producer.set_inhibit_time(value, self._core.now())
        if self._host is not None:  # a queued EMCY's time moved: its timer follows
            self._host.apply(NOTHING)
