"""A CANopen device (slave) run by a network: the public face that assembles the device's
services (one module each: ``sdo_server``, ``pdo``, ``sync``, ``timestamp``, ``emcy``,
``heartbeat``, ``guarding``, ``nmt``, ``storage``) around the device's object dictionary and
routes the NMT state to them.

The device serves its dictionary on every configured SDO channel, follows NMT, produces
heartbeat and answers node guarding, sends emergencies, consumes SYNC and TIME, and sends and
receives PDOs of every transmission type by itself. Communication objects written by a master
take effect at once; each refusal is the CiA 301 abort code of its cause. Everything runs on
the network's event loop: call the device's methods from there (or through
:class:`~cobus.device.BlockingDevice`).
"""

from __future__ import annotations

import weakref
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from cobus._moved import Moved, warn_renamed
from cobus.device._core import Core, Listener
from cobus.device._entries import Entry, check_value, zero_value
from cobus.device.eds_export import export_eds
from cobus.device.emcy import ERROR_REGISTER, EmcyService, class_bits
from cobus.device.errors import (
    DeviceConfigError,
    EntryNotFoundError,
    EntryRefusedError,
    NodeIdInUseError,
)
from cobus.device.events import (
    Booted,
    ConfigurationProblem,
    NodeIdChanged,
    StateChanged,
)
from cobus.device.guarding import GuardingService
from cobus.device.heartbeat import HeartbeatService
from cobus.device.lss import LssService
from cobus.device.nmt import NmtService
from cobus.device.pdo import PdoService
from cobus.device.sdo_server import SdoServerService
from cobus.device.simulation import CobIdRule, Deviations, Simulation
from cobus.device.storage import (
    LOAD_SIGNATURE,
    RESTORE,
    SAVE_SIGNATURE,
    STORE,
    ParameterStorage,
    StorageService,
)
from cobus.device.sync import SyncService
from cobus.device.timestamp import TimeService
from cobus.od import NameLookupError, ObjectDictionary, resolve
from cobus.proto import emcy as _emcy
from cobus.proto import nmt as _nmt
from cobus.proto.emcy import ErrorRegister
from cobus.proto.lss import BIT_RATES, UNCONFIGURED, LssSlave
from cobus.proto.nmt import NmtCommand, NmtSlave, NmtState
from cobus.proto.sdo import SdoAbort, SdoAbortCode, SdoServerBackend
from cobus.runtime.periodic import check_interface_timing

if TYPE_CHECKING:
    from cobus.runtime.network import AsyncNetwork

__all__ = [
    "LOAD_SIGNATURE",
    "SAVE_SIGNATURE",
    "UNCONFIGURED",
    "CobIdRule",
    "Deviations",
    "Device",
    "Listener",
]


Key = int | str

_ABORT = SdoAbortCode
_MANDATORY = (0x1000, ERROR_REGISTER, 0x1018)
_COMMANDS = {int(c): c for c in NmtCommand}
#: Dictionaries served by a running device (by id): a dictionary holds one node's defaults.
_SERVED: dict[int, weakref.ref[Device]] = {}


class _ObjectView:
    """``device[index]``: the sub-entries of one object, by sub-index or name."""

    __slots__ = ("_device", "_index")

    def __init__(self, device: Device, index: int) -> None:
        self._device = device
        self._index = index

    def __getitem__(self, subindex: Key) -> Any:
        return self._device.get(self._index, subindex)

    def __setitem__(self, subindex: Key, value: Any) -> None:
        self._device.set(self._index, subindex, value)

    @property
    def value(self) -> Any:
        """The value of a VAR object (sub-index 0)."""
        return self._device.get(self._index, 0)

    @value.setter
    def value(self, value: Any) -> None:
        self._device.set(self._index, 0, value)


def _renamed_keyword(method: str, manufacturer_data: bytes, manufacturer: bytes | None) -> bytes:
    """The EMCY bytes given under their name, or under the old one with a warning."""
    if manufacturer is None:
        return manufacturer_data
    if manufacturer_data:
        raise TypeError(f"{method}: give manufacturer_data only (manufacturer is its old name)")
    warn_renamed(f"Device.{method}(manufacturer=...) is now manufacturer_data=...")
    return manufacturer


class Device:
    """A CANopen device on ``network`` with node-ID ``node_id`` serving ``od``.

    Options: ``storage`` — a path (parameters of 1010h in that file, written atomically) or a
    :class:`~cobus.device.ParameterStorage`; default: kept in memory, across resets only.
    ``sdo_timeout`` — seconds the SDO servers wait within a segmented or block transfer.
    ``sdo_max_download`` — the most bytes an SDO download may bring into an entry of no
    fixed size (1 MiB; :meth:`limit_download` sets it per entry): more is refused.
    ``emcy_queue_size`` — emergencies held back by the inhibit time 1015h.
    ``deviations`` — a :class:`Deviations` for a model of a device that departs from
    CiA 301. ``sync_by_interface`` — when 1005h has it produce SYNC, the CAN interface
    times it (SocketCAN: the kernel; see :mod:`cobus.runtime.periodic`); an interface that
    cannot raises :class:`~cobus.runtime.InterfaceTimingError` here.

    ``lss`` — the device is an LSS slave (CiA 305) found by its identity 1018h sub 1-4
    (:attr:`lss`). A ``node_id`` of :data:`UNCONFIGURED` (FFh) makes one that starts without
    a node-ID: no boot-up, no SDO, no PDO, LSS only, until an LSS master gives it one; then it
    boots. ``None`` (the default): LSS when the device starts unconfigured or its storage holds
    a node-ID an LSS master had it store — that node-ID is the one it starts with.

    The device attaches itself to ``network`` (it holds ``node_id`` in ``network.devices``
    until :meth:`close`); :meth:`start` boots it (boot-up message, pre-operational).
    :func:`~cobus.device.add_device` does both. Each device needs a dictionary of its own.
    """

    # moved to device.simulation (issue 19): say so instead of growing a useless attribute
    sdo_response_delay = Moved("device.simulation.sdo_response_delay")
    heartbeat_muted = Moved("device.simulation.heartbeat_muted")
    deviations = Moved("device.simulation.deviations")

    def __init__(
        self,
        network: AsyncNetwork,
        node_id: int,
        od: ObjectDictionary,
        *,
        storage: str | Path | ParameterStorage | None = None,
        sdo_timeout: float = 1.0,
        sdo_max_download: int = 1 << 20,
        emcy_queue_size: int = 16,
        deviations: Deviations | None = None,
        sync_by_interface: bool = False,
        lss: bool | None = None,
    ) -> None:
        if node_id != UNCONFIGURED or isinstance(node_id, bool):
            try:
                _nmt.check_node_id(node_id)
            except _nmt.NmtError:
                raise DeviceConfigError(
                    f"node-ID {node_id!r}: give 1..127, or UNCONFIGURED (FFh) for a device that "
                    "waits for an LSS master to give it one"
                ) from None
        if lss is not None and not isinstance(lss, bool):
            raise DeviceConfigError(f"lss={lss!r}: give True, False or None (automatic)")
        if lss is False and node_id == UNCONFIGURED:
            raise DeviceConfigError(
                "a device without a node-ID (UNCONFIGURED) is reached by LSS only: lss=False "
                "would leave it unreachable; give it a node-ID or leave lss out"
            )
        if sync_by_interface:
            check_interface_timing(network)
        #: What a simulation changes in this device (late answers, a muted heartbeat, the
        #: deviations from CiA 301): see :class:`~cobus.device.Simulation`.
        self.simulation = Simulation(deviations, on_delay=self._sdo_delay_changed)
        missing = [f"{i:04X}h" for i in _MANDATORY if i not in od]
        if missing:
            raise DeviceConfigError(
                f"the dictionary lacks the mandatory objects {', '.join(missing)} (CiA 301); "
                "build it on cobus.device.minimal_od()"
            )
        if not sdo_timeout > 0:
            raise DeviceConfigError(f"SDO timeout {sdo_timeout!r} must be a positive number")
        if (
            isinstance(sdo_max_download, bool)
            or not isinstance(sdo_max_download, int)
            or sdo_max_download < 0
        ):
            raise DeviceConfigError(f"sdo_max_download {sdo_max_download!r}: a number of bytes")
        holder = _SERVED.get(id(od))
        other = holder() if holder is not None else None
        if other is not None and other.serves(od):
            raise DeviceConfigError(
                f"this dictionary is already served by device {other.node_id}: give each device "
                "a dictionary of its own (load the EDS again, or build another one)"
            )
        self.network = network
        self.od = od
        self._core = Core(network, od, node_id, self.simulation)
        self._sdo = SdoServerService(
            self._core, timeout=float(sdo_timeout), max_download=sdo_max_download
        )
        self._storage = StorageService(self._core, storage)
        self._lss: LssService | None = None
        if lss is not False:
            node_id = self._make_lss(node_id, force=bool(lss))
        self._closed = False
        # communication state, rebuilt by every reset communication
        self._nmt = NmtService(
            self._core, on_state_changed=self._state_changed, on_reset=self._on_reset
        )
        self._emcy = EmcyService(self._core, queue_size=emcy_queue_size)
        self._heartbeat = HeartbeatService(self._core, self._emcy, self._nmt.communication_error)
        self._guarding = GuardingService(self._core, self._emcy, self._nmt.communication_error)
        self._pdo = PdoService(self._core, self._emcy, in_sync_window=self._in_sync_window)
        self._sync = SyncService(
            self._core, self._emcy, self._pdo.on_sync, by_interface=sync_by_interface
        )
        self._time = TimeService(self._core)
        self._install_handlers()
        if node_id != UNCONFIGURED:
            self._check_free(node_id)
            network.devices.claim(node_id, self)
        _SERVED[id(od)] = weakref.ref(self)
        self._sync.attach()  # (last: a device that failed to be made leaves nothing behind)

    # ================================================================== public API

    @property
    def node_id(self) -> int:
        """The node-ID the device answers to (:data:`UNCONFIGURED`, FFh: none yet, it answers
        LSS only); setting it changes it at run time."""
        return self._core.node_id

    @node_id.setter
    def node_id(self, node_id: int) -> None:
        self.set_node_id(node_id)

    @property
    def lss(self) -> LssSlave | None:
        """The device's LSS slave (None: the device has none): its ``answer_delay`` (seconds
        every answer is held back, for slow masters), ``bit_rates`` (the table-0 indices it
        takes) may be set; ``pending_node_id``, ``state`` and ``identity`` read."""
        return None if self._lss is None else self._lss.slave

    @property
    def bit_rate(self) -> int | None:
        """The bit rate in kbit/s an LSS master switched the device to, or stored for it
        (None: the one it was started at)."""
        if self._lss is None or self._lss.bit_timing is None:
            return None
        return BIT_RATES.get(self._lss.bit_timing)

    @property
    def nmt(self) -> NmtSlave:
        """The NMT slave machine of the current communication."""
        return self._core.nmt

    @property
    def state(self) -> NmtState:
        """The NMT state."""
        return self._core.nmt.state

    @property
    def error_register(self) -> ErrorRegister:
        """1001h: the error register (generic bit set while any error is active)."""
        return ErrorRegister(self._emcy.register())

    @property
    def error_history(self) -> tuple[int, ...]:
        """1003h sub 1..: the errors recorded, newest first (code | info << 16)."""
        return self._emcy.history

    def __repr__(self) -> str:
        if self._core.unconfigured:
            return (
                "Device(unconfigured)"
                if self._lss is None
                else (f"Device(unconfigured, serial 0x{self._lss.slave.identity.serial:08X})")
            )
        return f"Device({self._core.node_id}, {self._core.nmt.state.name})"

    def __getitem__(self, index: Key) -> _ObjectView:
        obj = self.od.get(index)
        if obj is None or obj.index < 0x1000:
            shown = f"0x{index:04X}" if isinstance(index, int) else repr(index)
            raise EntryNotFoundError(
                index if isinstance(index, int) else 0, 0, _ABORT.NO_OBJECT, f"no object {shown}"
            )
        return _ObjectView(self, obj.index)

    @property
    def sdo_backend(self) -> SdoServerBackend:
        """What the device's SDO server channels serve (its entries, with every check), for
        an owner that serves SDO on channels of its own (``Deviations(serve_sdo=False)``)."""
        return self._sdo.backend

    def serves(self, od: ObjectDictionary) -> bool:
        """Whether this device runs (not closed) on the dictionary ``od``."""
        closed: bool = self._closed
        mine: ObjectDictionary = self.od
        return not closed and mine is od

    def add_listener(self, listener: Listener) -> None:
        """Call ``listener(event)`` for every event of this device (on the event loop)."""
        self._core.listeners.append(listener)

    def remove_listener(self, listener: Listener) -> None:
        """Stop calling ``listener`` (given to :meth:`add_listener`)."""
        if listener in self._core.listeners:
            self._core.listeners.remove(listener)

    def get(self, index: Key, subindex: Key = 0) -> Any:
        """The current value of an entry (through its read callback when one is bound)."""
        entry = self._resolve(index, subindex)
        try:
            return entry.current()
        except SdoAbort as refusal:
            raise EntryRefusedError(
                entry.index, entry.subindex, refusal.code, refusal.reason
            ) from None

    def set(self, index: Key, subindex: Key, value: Any) -> None:
        """Write an entry as the application: type and limits are checked, communication
        objects take effect as if written by SDO, mapped values trigger their TPDOs."""
        entry = self._resolve(index, subindex)
        try:
            value = check_value(entry, value)
            self._core.write(entry, value, remote=False)
        except SdoAbort as refusal:
            raise EntryRefusedError(
                entry.index, entry.subindex, refusal.code, refusal.reason
            ) from None

    def on_read(self, index: Key, subindex: Key, fn: Callable[[], Any] | None) -> None:
        """Bind reads of an application entry (SDO upload, TPDO, :meth:`get`) to ``fn()``;
        ``fn`` may raise :class:`~cobus.proto.sdo.SdoAbort` to refuse. None unbinds."""
        entry = self._app_entry(index, subindex)
        entry.reader = fn

    def limit_download(self, index: Key, subindex: Key, max_bytes: int) -> None:
        """The most bytes an SDO download may bring into an entry of no fixed size (a DOMAIN,
        a string): the device's ``sdo_max_download`` (1 MiB) unless set here. A download
        announcing more is refused at once with 05040005 (out of memory), one bringing more
        without announcing it with 06070012."""
        entry = self._resolve(index, subindex)
        if isinstance(max_bytes, bool) or not isinstance(max_bytes, int) or max_bytes < 0:
            raise ValueError(f"download limit {max_bytes!r} is not a number of bytes (>= 0)")
        if entry.size is not None:
            raise ValueError(
                f"0x{entry.index:04X}:{entry.subindex:02X} is a {entry.data_type.name} of "
                f"{entry.size} bytes: a download brings exactly that, no limit to set"
            )
        entry.download_limit = max_bytes

    def on_write(self, index: Key, subindex: Key, fn: Callable[[Any], object] | None) -> None:
        """Call ``fn(value)`` when a master writes an application entry (SDO or RPDO), before
        the value is stored; ``fn`` may raise :class:`~cobus.proto.sdo.SdoAbort` to refuse
        (an SDO write is then aborted with its code, an RPDO value dropped). None unbinds."""
        entry = self._app_entry(index, subindex)
        entry.writer = fn

    def send_emergency(
        self,
        code: int,
        register: int | None = None,
        manufacturer_data: bytes = b"",
        *,
        info: int = 0,
        manufacturer: bytes | None = None,
    ) -> None:
        """Report an application error: EMCY frame, 1003h history, error register.

        ``register`` None derives the register bits from the code's class (2xxxh current,
        3xxxh voltage, 4xxxh temperature, 81xxh/82xxh communication, FFxxh manufacturer);
        the generic bit is set while any error is active. The error stays active (and in
        1001h) until :meth:`clear_emergency`. Code 0000h clears every application error.
        ``manufacturer_data``: up to 5 bytes, the frame's manufacturer-specific field
        (``manufacturer=``, its old name, still works for one release).
        """
        manufacturer = _renamed_keyword("send_emergency", manufacturer_data, manufacturer)
        _emcy.emcy_frame_data(code, 0 if register is None else register, manufacturer)
        if not isinstance(info, int) or not 0 <= info <= 0xFFFF:
            raise _emcy.EmcyError(f"1003h additional information {info!r} is not a UNSIGNED16")
        if code >> 8 == 0:
            self.clear_emergency()
            return
        bits = class_bits(code) if register is None else register
        self._emcy.raise_error(("app", code), code, bits, bytes(manufacturer), info)

    def clear_emergency(
        self,
        code: int | None = None,
        *,
        manufacturer_data: bytes = b"",
        manufacturer: bytes | None = None,
    ) -> None:
        """End application error ``code`` (None: all of them): the error register is updated
        and the 'error reset' emergency (0000h) is sent, with ``manufacturer_data`` (up to 5
        bytes) as its manufacturer-specific field (``manufacturer=`` for one release)."""
        manufacturer = _renamed_keyword("clear_emergency", manufacturer_data, manufacturer)
        _emcy.emcy_frame_data(0, 0, manufacturer)
        keys = self._emcy.keys("app")
        if code is not None:
            keys = [k for k in keys if k == ("app", code)]
        self._emcy.clear(keys, bytes(manufacturer))

    def send_tpdo(self, number: int) -> None:
        """An application event for TPDO ``number``: event-driven types send now (or at the
        end of the inhibit time), acyclic synchronous ones at the next SYNC."""
        self._check_configured("send a TPDO")
        if not self._pdo.send_tpdo(number):
            raise DeviceConfigError(f"TPDO {number} is not configured (or not valid)")

    def apply_nmt(self, command: NmtCommand | int) -> None:
        """Apply an NMT command locally, as if the master had sent it (e.g. a device that
        starts on its own: ``device.apply_nmt(NmtCommand.START)``)."""
        cmd = _COMMANDS.get(int(command))
        if cmd is None:
            raise _nmt.NmtError(f"unknown NMT command {command!r}: use an NmtCommand member")
        self._check_configured("apply an NMT command")
        self._nmt.apply(cmd)

    def to_eds(self) -> str:
        """The device's EDS (CiA 306): its dictionary, with complete DeviceInfo."""
        return export_eds(self.od)

    def save_eds(self, path: str | Path) -> None:
        """Write :meth:`to_eds` to ``path`` (CRLF line ends, as CiA 306 wants)."""
        with Path(path).open("w", encoding="utf-8", newline="\r\n") as fh:
            fh.write(self.to_eds())

    def store_parameters(self, subindex: int = 1) -> None:
        """Store parameters as a master does with 1010h: 1 all, 2 communication,
        3 application."""
        try:
            self._storage.store(subindex)
        except SdoAbort as refusal:
            raise EntryRefusedError(STORE, subindex, refusal.code, refusal.reason) from None

    def restore_defaults(self, subindex: int = 1) -> None:
        """Drop stored parameters as a master does with 1011h (effective at the next reset)."""
        try:
            self._storage.restore(subindex)
        except SdoAbort as refusal:
            raise EntryRefusedError(RESTORE, subindex, refusal.code, refusal.reason) from None

    def set_node_id(self, node_id: int) -> None:
        """Change the node-ID at run time.

        The values that follow ``$NODEID`` (SDO COB-IDs, EMCY, the pre-defined PDO COB-IDs
        1-4, and every entry whose default is a ``$NODEID`` expression) move with it when they
        still hold their default; the rest of the configuration is kept. The communication
        is rebuilt and the device boots again under the new node-ID (boot-up message,
        pre-operational).
        """
        _nmt.check_node_id(node_id)
        if self._closed:
            raise DeviceConfigError(
                f"device {self._core.node_id} was closed: it takes no new node-ID; create a new one"
            )
        old = self._core.node_id
        if node_id == old:
            return
        self._check_free(node_id)
        if self._lss is not None:
            self._lss.node_id_changed(node_id)
        if self._core.unconfigured and self._core.started:
            self._take_node_id(node_id)
            return
        self.network.devices.move(old, node_id, self)
        if not self._core.started:
            self._set_core_node_id(node_id)
            return
        self._teardown_comm()
        self._nmt.close()
        self._set_core_node_id(node_id)
        self._nmt.open()
        self._boot()
        self._core.emit(NodeIdChanged(node_id, old))

    def start(self) -> None:
        """Power on: power-on values, stored parameters, boot-up message, pre-operational.

        A parameter file that cannot be read never keeps the device from starting: it
        starts on its default values, emits :class:`StorageProblem` with the reason and
        sends EMCY 6300h "data set" (active until the application clears it)."""
        if self._core.started:
            raise DeviceConfigError(f"device {self._core.node_id} is already started")
        if self._closed:
            raise DeviceConfigError(f"device {self._core.node_id} was closed; create a new one")
        self._power_on(communication=True, application=True)
        self._core.started = True
        if self._lss is not None:
            self._lss.open()
        if self._core.unconfigured:
            return  # LSS only, until a master gives it a node-ID (:meth:`_assigned`)
        self._nmt.open()
        self._boot()
        self._report_storage()

    def _check_configured(self, what: str) -> None:
        if self._core.unconfigured:
            raise DeviceConfigError(
                f"{self!r} has no node-ID (it waits for an LSS master to give it one): it "
                f"cannot {what} yet"
            )

    def _check_free(self, node_id: int) -> None:
        other = self.network.devices.get(node_id)
        if other is not None and other is not self:
            raise NodeIdInUseError(
                f"node-ID {node_id} is used by another device of this network ({other!r}); "
                "pick a free one"
            )

    def _report_storage(self) -> None:
        """After a boot on a parameter file that could not be read: EMCY 6300h."""
        if self._storage.take_failure():
            self.send_emergency(0x6300)

    def close(self) -> None:
        """Take the device off the network (it falls silent, as if unplugged)."""
        if self._closed:
            return
        self._closed = True
        if self._lss is not None:
            self._lss.close()
        self._teardown_comm()
        self._sync.detach()
        self._nmt.close()
        holder = _SERVED.get(id(self.od))
        if holder is not None and holder() is self:
            del _SERVED[id(self.od)]
        self.network.devices.release(self._core.node_id, self)

    # ================================================================== lookups

    def _resolve(self, index: Key, subindex: Key) -> Entry:
        """The entry ``index``/``subindex`` name, in every form :func:`cobus.od.resolve`
        takes (names with case and separators ignored, ``"Record.Sub"``, ``"0x1018:01"``)."""
        try:
            var = resolve(self.od, index, None if subindex == 0 else subindex)
        except NameLookupError as exc:
            obj, key = exc.found, exc.key
            if obj is None:
                raise EntryNotFoundError(
                    index if isinstance(index, int) and not isinstance(index, bool) else 0,
                    0,
                    _ABORT.NO_OBJECT,
                    f"device {self._core.node_id}: {exc}",
                ) from None
            raise EntryNotFoundError(
                obj.index,
                key if isinstance(key, int) and not isinstance(key, bool) else 0,
                _ABORT.NO_OBJECT if obj.index < 0x1000 else _ABORT.NO_SUBINDEX,
                f"device {self._core.node_id}: {exc}",
            ) from None
        if var.index < 0x1000:
            raise EntryNotFoundError(
                var.index,
                0,
                _ABORT.NO_OBJECT,
                f"no object 0x{var.index:04X} in the dictionary of device {self._core.node_id} "
                "(below 1000h: data type definitions)",
            )
        entry = self._core.entries.get(var.index << 8 | var.subindex)
        if entry is None:
            raise EntryNotFoundError(
                var.index,
                var.subindex,
                _ABORT.NO_OBJECT,
                f"{var.qualname} was added to the dictionary after device {self._core.node_id} was "
                "created; complete the dictionary first",
            )
        return entry

    def _app_entry(self, index: Key, subindex: Key) -> Entry:
        entry = self._resolve(index, subindex)
        if entry.index < 0x2000:
            raise DeviceConfigError(
                f"0x{entry.index:04X} is a communication object: the device serves it itself; "
                "bind application objects (2000h and above) only"
            )
        return entry

    # ================================================================== power-on and resets

    def _power_on(self, *, communication: bool, application: bool) -> None:
        if not self._core.unconfigured:
            self.od.node_id = self._core.node_id
        self._storage.power_on(communication=communication, application=application)
        self._emcy.power_on(communication=communication, application=application)

    def _reset(self, *, application: bool) -> None:
        self._teardown_comm()
        old = self._core.node_id
        pending = None if self._lss is None else self._lss.take_pending()
        if pending == UNCONFIGURED:  # an LSS master took the node-ID away: LSS only now
            self._nmt.close()
            self.network.devices.release(old, self)
            self._set_core_node_id(UNCONFIGURED)
            self._power_on(communication=True, application=application)
            self._core.emit(NodeIdChanged(UNCONFIGURED, old))
            return
        if pending is not None:
            # Every device this NMT command resets lets go of its node-ID before any takes
            # a new one: two devices that swap theirs each find the other's free.
            self._nmt.close()
            self.network.devices.release(old, self)
            self.network.loop.call_soon(self._move_for_lss, pending, old, application)
            return
        communication = (
            application or not self.simulation.deviations.reset_communication_keeps_values
        )
        self._power_on(communication=communication, application=application)
        self._boot()
        self._report_storage()

    # ================================================================== LSS

    def _make_lss(self, node_id: int, *, force: bool) -> int:
        """The LSS slave, when asked for or needed; the node-ID the device starts with (the
        one an LSS master had it store wins)."""
        stored_id, stored_timing = self._storage.stored_lss()
        if not (force or node_id == UNCONFIGURED or stored_id is not None):
            return node_id
        if stored_id is not None and stored_id != node_id:
            other = self.network.devices.get(stored_id)
            if other is not None:
                raise NodeIdInUseError(
                    f"node-ID {stored_id}, which an LSS master had this device store, is used "
                    f"by another device of this network ({other!r}); give the device another "
                    "storage, or have the master give it another node-ID"
                )
            node_id = stored_id
            self._set_core_node_id(node_id, follow=False)
        self._lss = LssService(self._core, self._storage, on_assigned=self._assigned)
        self._lss.power_on(node_id, stored_timing)
        return node_id

    def _set_core_node_id(self, node_id: int, *, follow: bool = True) -> None:
        """The device's node-ID becomes ``node_id``; with ``follow`` the values that follow
        ``$NODEID`` move with it (those that hold their default, their CiA 301 COB-ID)."""
        core = self._core
        moving = self._following() if follow and node_id != UNCONFIGURED else {}
        core.node_id = node_id
        if not core.unconfigured:
            self.od.node_id = node_id
        for key, offset in moving.items():
            entry = core.entries[key]
            entry.value = entry.var.value if offset is None else node_id + offset
        if hasattr(self, "_nmt"):
            self._nmt.renew(node_id)
            self._emcy.set_node_id(node_id)
        else:  # (in __init__, before the services exist)
            core.nmt = NmtSlave(core.machine_node_id)

    def _following(self) -> dict[int, int | None]:
        """The entries that follow ``$NODEID`` now: key -> offset from the node-ID, or None
        for an entry that holds its unresolved default (the device had no node-ID)."""
        core = self._core
        out: dict[int, int | None] = {}
        for key, entry in core.entries.items():
            var = entry.var
            if core.unconfigured:
                if var.relative:
                    held = zero_value(entry.data_type) if var.value is None else var.value
                    if entry.value == held:
                        out[key] = None
            elif entry.index < 0x2000 or var.relative:
                offset = core.node_offset(entry, entry.value)
                if offset is not None:
                    out[key] = offset
        return out

    def _assigned(self, node_id: int) -> None:
        """An LSS master gave the unconfigured device ``node_id``: it boots under it."""
        try:
            self._check_free(node_id)
        except NodeIdInUseError as exc:
            assert self._lss is not None
            self._lss.unassign()
            self._core.emit(ConfigurationProblem(UNCONFIGURED, f"LSS node-ID {node_id}: {exc}"))
            return
        self._take_node_id(node_id)

    def _take_node_id(self, node_id: int) -> None:
        """The unconfigured, started device boots under ``node_id`` (a free one)."""
        self.network.devices.claim(node_id, self)
        self._set_core_node_id(node_id)
        self._power_on(communication=True, application=False)
        self._storage.apply_node_relative()
        self._nmt.open()
        self._boot()
        self._report_storage()
        self._core.emit(NodeIdChanged(node_id, UNCONFIGURED))

    def _move_for_lss(self, node_id: int, old: int, application: bool) -> None:
        """The reset goes on under the node-ID an LSS master configured (every device reset
        by the same command has let go of its own by now). One another local device holds
        is not taken: the device goes on under its old one and keeps the new one pending."""
        if self._closed:
            return
        devices = self.network.devices
        assert self._lss is not None
        target = node_id
        if devices.get(node_id) not in (None, self):
            holder = devices.get(node_id)
            self._lss.keep_pending(old, node_id)
            self._core.emit(
                ConfigurationProblem(
                    old,
                    f"LSS node-ID {node_id} is used by another device of this network "
                    f"({holder!r}): device {old} keeps its node-ID, {node_id} stays pending",
                )
            )
            target = old
        if devices.get(target) not in (None, self):  # (its old one was taken meanwhile)
            self._lss.unassign()
            self._set_core_node_id(UNCONFIGURED)
            self._core.emit(NodeIdChanged(UNCONFIGURED, old))
            return
        devices.claim(target, self)
        if target != old:
            self._set_core_node_id(target)
        self._nmt.open()
        self._power_on(communication=True, application=application)
        self._boot()
        self._report_storage()
        if target != old:
            self._core.emit(NodeIdChanged(target, old))

    def _boot(self) -> None:
        self._build_comm()
        self._nmt.boot()
        self._heartbeat.boot(self.network.time())
        self._core.emit(Booted(self._core.node_id))

    def _state_changed(self, old: NmtState, new: NmtState) -> None:
        now = self.network.time()
        self._pdo.state_changed(old, new, now)
        if new is NmtState.STOPPED:
            self._sdo.build()  # transfers in progress end silently: SDO is not available
        self._sync.state_changed(old, new, now)
        self._core.emit(StateChanged(self._core.node_id, old, new))

    def _on_reset(self, application: bool) -> None:
        self._reset(application=application)

    def _in_sync_window(self, now: float) -> bool:
        return self._sync.in_window(now)

    def _sdo_delay_changed(self) -> None:
        self._sdo.delay_changed()

    # ================================================================== building

    def _teardown_comm(self) -> None:
        self._sdo.close()
        self._pdo.close()
        self._heartbeat.close()
        self._guarding.close()
        self._emcy.close()
        self._sync.close()
        self._time.close()

    def _build_comm(self) -> None:
        now = self.network.time()
        self._emcy.build(now)
        self._sdo.build()
        self._heartbeat.build(now)
        self._guarding.build(now)
        self._sync.build()
        self._time.build()
        self._pdo.build()

    # ================================================================== 1021h

    def _install_handlers(self) -> None:
        """1021h (store EDS) reads the device's own EDS."""
        eds = self._core.entries.get(0x1021 << 8)
        if eds is not None:
            eds.reader = self._read_eds

    def _read_eds(self) -> bytes:
        return self.to_eds().replace("\n", "\r\n").encode("utf-8")
