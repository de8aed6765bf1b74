"""STOeBER MDS 5000 (5th generation inverter) with the CAN 5000 option, as seed 004 describes it.

A CiA 301 device (1000h = 00020192h) whose parameters live in groups A..Z: parameter ``Gnn.e``
is object ``2000h + 200h x (group - 1) + nn``, sub-index ``e`` (A = 2000h, C01 -> 2401h,
E08 -> 2808h ... Z = 5200h; 5400h-5FFFh reserved). The communication parameters have a
STOeBER address too (A207 = 1014h, A218 = 1201h, A221-A224 = 1400h-1403h, A225-A228 =
1600h-1603h, A229-A232 = 1800h-1803h, A233-A236 = 1A00h-1A03h, elements counted from 0 where
CiA counts sub-indexes from 1; A229.3 is the event timer 1800h sub 5); both addresses reach
the same parameter. A237-A244 show the mapped length of each PDO in bytes.

Behaviour the manual describes, on a :class:`~cobus.device.Device` with the deviations the
drive makes (:attr:`StoberMds5000.QUIRKS`):

- four SDO channels: 1 fixed (600h/580h + node-ID), 2-4 (1201h-1203h, disabled by default)
  activated with bit 31 = 1 (the opposite of CiA) and taking new COB-IDs at reset
  communication or stop -> pre-operational; each channel edits the axis its element of A11
  names (A11.1-A11.4; axis 1 is the one the motor model runs, axes 2-4 are parameter sets);
- a COB-ID parameter holding the bare function code (e.g. 180h) means "plus the node-ID";
- PDO transmission types 0, 1-240 and 254; type 254 applies each RPDO at once and answers it
  with the TPDO of the same channel; up to 6 mapping entries per PDO written directly (bit
  length 0 is filled in); a short RPDO writes the objects it covers;
- EMCY once on entering fault (reaction) and once with code 0000h on acknowledge: code, error
  register (no generic bit), byte 3 = E82 event, byte 4 = E39 cause (:data:`EVENTS`); also in
  stopped. NMT reset node clears the CANopen side's errors (1001h) but not the inverter's
  fault: the event is then reported once more after the boot-up, so that 1001h shows it again
  (the manual: "1001h error register (E82)") and its acknowledge sends 0000h;
- life guarding (100Ch x 100Dh) lost: event 52 "communication", cause 1, NMT -> pre-operational;
  heartbeat 1017h; boot-up always; no TIME; 1005h = 7FFh ignores SYNC;
- reset communication applies the communication parameters as written (the manual's example
  activates an SDO channel that way; its NMT table says "start values", read as the values
  the parameters hold); they survive a power cycle only when saved (1010h sub 1, A00);
- the LEDs of CiA 303-3 in :meth:`~StoberMds5000.status`.

This simulator's own choices (the manual leaves the application's process data to POSITool):
device control A180 (20B4h, U16, mappable) bit 0 enable, bit 1 quick stop, bit 2 acknowledge
(rising edge); D230 (26E6h, I16, mappable) the speed setpoint in rpm; C230 (24E6h, U16,
mappable) M-max in % of the rated torque; E08 n-Motor (2808h, I16 rpm) the actual speed;
E48 (2830h) the device state 0-7 (self test, switch-on disabled, ready to switch on, switched
on, operation enabled, quick stop, fault reaction active, fault; also 1002h); E82 (2852h) and
E39 (2827h) the last event and its cause; E52 (2834h) the serial number; A82 (2052h) the bit
rate in kbit/s; A83 (2053h) the node-ID. 2000h sub 0 is a DOMAIN (the segmented transfers of
the vectors); A00 "save values" is reached at its CANopen address 1010h sub 1. The event of a
speed above 120 % of C01 is 56 "overspeed", of a load above C230 event 47 "M-Max limit".
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Mapping
from functools import partial
from pathlib import Path
from typing import Any, ClassVar

from cobus.device import (
    Booted,
    Device,
    DeviceConfigError,
    DeviceEvent,
    DictionaryBuilder,
    EntryWritten,
    LifeGuardingLost,
    LifeGuardingRestored,
    MemoryStorage,
    ParametersStored,
    ParameterStorage,
    RpdoReceived,
    StateChanged,
    SyncLost,
    SyncRestored,
)
from cobus.device.device import Deviations
from cobus.errors import CobusError
from cobus.od import Access, DataType, ObjectDictionary, Record, Variable
from cobus.profiles.stober import EVENTS, STATES, StoberError
from cobus.profiles.stober import parameter_index as _parameter_index
from cobus.proto import Frame
from cobus.proto.connection_set import (
    PDO_STEP,
    RPDO_BASE,
    SDO_RX_BASE,
    SDO_TX_BASE,
    TPDO_BASE,
    sdo_cob_ids,
)
from cobus.proto.nmt import NmtState
from cobus.proto.sdo import SdoAbort, SdoAbortCode, SdoServer, SdoServerBackend
from cobus.runtime.events import BusState
from cobus.runtime.network import AsyncNetwork, MachineHost, Subscription
from cobus.sim.base import SimulatedDevice, SimulationError

__all__ = ["EVENTS", "STATES", "StoberMds5000", "parameter_index"]

NO_EVENT, MOTOR_TEMPERATURE, M_MAX, COMMUNICATION, OVERSPEED = 30, 41, 47, 52, 56
CAUSE_ERROR_CONTROL = 1

SWITCH_ON_DISABLED, ENABLED, QUICK_STOP, FAULT_REACTION, FAULT = 1, 4, 5, 6, 7

VENDOR_ID = 0xB9


def parameter_index(coordinate: str) -> tuple[int, int]:
    """The CANopen index and sub-index of a STOeBER parameter: ``"C01"`` -> (2401h, 0),
    ``"A225.3"`` -> (20E1h, 3), ``"E08"`` -> (2808h, 0) (see
    :func:`cobus.profiles.stober.parameter_index`; a bad name is a SimulationError here)."""
    try:
        return _parameter_index(coordinate)
    except StoberError as exc:
        raise SimulationError(str(exc)) from None


A11 = parameter_index("A11")[0]
A82 = parameter_index("A82")[0]
A83 = parameter_index("A83")[0]
A180 = parameter_index("A180")[0]
C01 = parameter_index("C01")[0]
C230 = parameter_index("C230")[0]
D230 = parameter_index("D230")[0]
E08 = parameter_index("E08")[0]
E39 = parameter_index("E39")[0]
E48 = parameter_index("E48")[0]
E52 = parameter_index("E52")[0]
E82 = parameter_index("E82")[0]
DOMAIN = 0x2000
# A180 device control bits (this simulator's)
ENABLE_BIT, QUICK_STOP_BIT, ACK_BIT = 1 << 0, 1 << 1, 1 << 2


def _aliases() -> dict[tuple[int, int], tuple[int, int]]:
    """STOeBER address -> CANopen address of the communication parameters."""
    table: dict[tuple[int, int], tuple[int, int]] = {}

    def single(coordinate: str, index: int, sub: int = 0) -> None:
        table[parameter_index(coordinate)] = (index, sub)

    for coordinate, index in (
        ("A200", 0x1005),
        ("A201", 0x1006),
        ("A203", 0x100C),
        ("A204", 0x100D),
        ("A207", 0x1014),
        ("A208", 0x1015),
        ("A210", 0x1017),
        ("A83", 0x100B),
        ("E48", 0x1002),
        ("E52", 0x1018),
    ):
        single(coordinate, index, 4 if index == 0x1018 else 0)
    single("A211", 0x1020, 1)
    single("A212", 0x1020, 2)
    for n in range(3):  # A218-A220: SDO channels 2-4
        base = parameter_index(f"A{218 + n}")[0]
        for e in range(3):
            table[(base, e)] = (0x1201 + n, e + 1)
    for n in range(4):
        rx = parameter_index(f"A{221 + n}")[0]
        for e in range(2):
            table[(rx, e)] = (0x1400 + n, e + 1)
        tx = parameter_index(f"A{229 + n}")[0]
        for e, sub in enumerate((1, 2, 3, 5)):
            table[(tx, e)] = (0x1800 + n, sub)
        for first, mapping in ((225, 0x1600), (233, 0x1A00)):
            index = parameter_index(f"A{first + n}")[0]
            for e in range(6):
                table[(index, e)] = (mapping + n, e + 1)
    return table


ALIASES: Mapping[tuple[int, int], tuple[int, int]] = _aliases()
#: A237-A240 (RPDO 1-4) and A241-A244 (TPDO 1-4): mapped lengths in bytes.
MAPPED_LENGTHS: Mapping[int, int] = {
    **{parameter_index(f"A{237 + n}")[0]: 0x1600 + n for n in range(4)},
    **{parameter_index(f"A{241 + n}")[0]: 0x1A00 + n for n in range(4)},
}
_AXIS_AREA = range(0x2200, 0x5400)  # groups B..Z: the parameters of an axis

_SDO_FUNCTION = {(n, 1): SDO_RX_BASE + 0x20 * (n - 1) for n in (2, 3, 4)} | {
    (n, 2): SDO_TX_BASE + 0x20 * (n - 1) for n in (2, 3, 4)
}
_INVALID = 1 << 31


def _var(
    index: int,
    sub: int,
    name: str,
    dtype: DataType,
    access: str = "rw",
    default: Any = None,
    *,
    mappable: bool = False,
    low: Any = None,
    high: Any = None,
) -> Variable:
    return Variable(
        index,
        sub,
        name,
        dtype,
        Access(access),
        mappable,
        default=default,
        low_limit=low,
        high_limit=high,
    )


class _Channel:
    """The back end of one SDO channel: STOeBER addresses, the axis that channel edits (A11),
    the computed mapped lengths; everything else is the device's dictionary."""

    __slots__ = ("number", "sim")

    def __init__(self, sim: StoberMds5000, number: int) -> None:
        self.sim = sim
        self.number = number

    @property
    def _device(self) -> SdoServerBackend:
        device = self.sim.device
        if device is None:
            raise SdoAbort(SdoAbortCode.DEVICE_STATE, "the inverter is off")
        return device.sdo_backend

    def _axis(self, index: int) -> int:
        device = self.sim.device
        if device is None or index not in _AXIS_AREA:
            return 1
        axis: int = device.get(A11, self.number)
        return axis

    def upload(self, index: int, subindex: int) -> bytes:
        if index in MAPPED_LENGTHS:
            if subindex:
                raise SdoAbort(SdoAbortCode.NO_SUBINDEX, "A237-A244 have element 0 only")
            return bytes((self.sim.mapped_length(MAPPED_LENGTHS[index]),))
        index, subindex = ALIASES.get((index, subindex), (index, subindex))
        data = self._device.upload(index, subindex)
        axis = self._axis(index)
        if axis != 1:
            value = self.sim.axis_parameter(axis, index, subindex)
            if value is not None:
                return value
        return data

    def download(self, index: int, subindex: int, data: bytes) -> None:
        if index in MAPPED_LENGTHS:
            raise SdoAbort(SdoAbortCode.WRITE_READ_ONLY, "A237-A244 are display parameters")
        index, subindex = ALIASES.get((index, subindex), (index, subindex))
        axis = self._axis(index)
        if axis != 1:
            self.sim.set_axis_parameter(axis, index, subindex, data)
            return
        self._device.download(index, subindex, data)

    def size_hint(self, index: int, subindex: int) -> int | None:
        if index in MAPPED_LENGTHS:
            raise SdoAbort(SdoAbortCode.WRITE_READ_ONLY, "A237-A244 are display parameters")
        index, subindex = ALIASES.get((index, subindex), (index, subindex))
        return _size_hint(self._device, index, subindex)


class StoberMds5000(SimulatedDevice):
    """A STOeBER MDS 5000 on ``network`` with node-ID ``node_id`` (A83; 1 by default in the
    manual; 1-31 when SDO channels 2-4 are used).

    Options: ``quirks`` (:attr:`QUIRKS`), ``storage`` (where "save values" keeps the
    parameters; memory across power cycles of this object by default), ``rated_power`` (kW,
    1018h product code in 0.1 kW), ``serial`` (E52), ``sw_build`` (1018h revision),
    ``device_name``/``hardware_version``/``software_version`` (1008h/1009h/100Ah), ``ramp``
    and ``quick_stop_ramp`` (rpm/s), ``tick`` (s), ``sdo_timeout`` (s).
    """

    kind: ClassVar[str] = "stober_mds5000"
    QUIRKS: ClassVar[Mapping[str, str]] = {
        "sdo_channel_bit31_enables": "bit 31 = 1 activates SDO channels 2-4 (CiA: disables)",
        "sdo_ids_at_reset": "new SDO COB-IDs take effect at reset communication or stop -> "
        "pre-operational (CiA: at once)",
        "function_code_cob_ids": "a COB-ID parameter holding the bare function code (180h) "
        "means plus the node-ID",
        "padded_expedited_writes": "expedited writes of 4 bytes to 8/16-bit parameters are "
        "accepted when the upper bytes are 0",
        "pdo_reply_254": "an RPDO of type 254 is answered with the TPDO of the same channel",
        "pdo_params_while_valid": "PDO COB-ID and inhibit time can be written while the PDO "
        "is valid (they take effect when it starts)",
        "direct_pdo_mapping": "the 6 mapping entries are written directly (0 = unused, bit "
        "length 0 filled in); sub 0 is a constant",
        "partial_rpdos": "a short RPDO writes the objects it covers; no length errors",
        "transmission_types_limited": "only transmission types 0, 1-240 and 254",
        "emcy_without_generic_bit": "the error register holds the event's bits only (CiA sets "
        "the generic bit with any error)",
        "emcy_in_stopped": "emergencies are sent in stopped too",
    }
    FAULTS: ClassVar[Mapping[str, str]] = {
        "motor_overtemperature": "the motor temperature sensor trips (event 41, EMCY 4310h, "
        "register 08) while active=True; active=False cools it down",
        "event": "any E82 event number= (31-70) with cause= (E39), e.g. 44 external fault; "
        "active=False removes its cause",
        "overload": "a load= in % of the rated torque; above M-max (C230) the drive reports "
        "event 47",
    }
    #: The parameters each fault takes (kind, "?" when optional): checked when a rig loads.
    FAULT_PARAMS: ClassVar[Mapping[str, Mapping[str, str]]] = {
        "motor_overtemperature": {"active": "bool?"},
        "event": {"number": "int?", "cause": "int?", "active": "bool?"},
        "overload": {"load": "number?"},
    }

    def __init__(
        self,
        network: AsyncNetwork,
        node_id: int,
        *,
        quirks: Mapping[str, bool] | None = None,
        name: str | None = None,
        storage: str | Path | ParameterStorage | None = None,
        rated_power: float = 1.5,
        serial: int = 8000000,
        sw_build: int = 1,
        device_name: str = "MDS 5xxx",
        hardware_version: str = "MDS 5/123/3802",
        software_version: str = "V5.0alpha1",
        ramp: float = 3000.0,
        quick_stop_ramp: float = 10000.0,
        tick: float = 0.01,
        sdo_timeout: float = 1.0,
    ) -> None:
        super().__init__(network, node_id, quirks=quirks, name=name)
        if not isinstance(node_id, int) or not 1 <= node_id <= 127:
            raise SimulationError(f"node-ID {node_id!r}: A83 takes 1..127")
        for what, value in (
            ("ramp", ramp),
            ("quick_stop_ramp", quick_stop_ramp),
            ("tick", tick),
            ("sdo_timeout", sdo_timeout),
            ("rated_power", rated_power),
        ):
            if not isinstance(value, int | float) or not value > 0:
                raise SimulationError(f"{what}={value!r} must be a positive number")
        for what, text in (
            ("device_name", device_name),
            ("hardware_version", hardware_version),
            ("software_version", software_version),
        ):
            if len(text) > 16:
                raise SimulationError(f"{what} {text!r} is longer than the 16 characters it has")
        self.ramp = float(ramp)
        self.quick_stop_ramp = float(quick_stop_ramp)
        self.tick = float(tick)
        self.sdo_timeout = float(sdo_timeout)
        self.storage: str | Path | ParameterStorage = (
            storage if storage is not None else MemoryStorage()
        )
        self.od = self._dictionary(
            rated_power, serial, sw_build, device_name, hardware_version, software_version
        )
        self.device: Device | None = None
        self._channels: dict[int, tuple[SdoServer, MachineHost, Subscription]] = {}
        self._saved_axes: dict[int, dict[tuple[int, int], bytes]] = {}
        # the world around the drive, kept while the power is off
        self.load = 0.0  # % of the rated torque
        self.motor_hot = False
        self.causes: dict[int, int] = {}  # injected events whose cause is there -> E39 cause
        self._reset_volatile()

    # ------------------------------------------------------------------ dictionary
    def _bare(self, function_code: int) -> int:
        """The default of a COB-ID parameter: the bare function code (quirk) or CiA's value."""
        if self.quirks["function_code_cob_ids"]:
            return function_code
        return function_code + self.node_id

    def _dictionary(
        self,
        rated_power: float,
        serial: int,
        sw_build: int,
        device_name: str,
        hardware_version: str,
        software_version: str,
    ) -> ObjectDictionary:
        b = DictionaryBuilder(
            device_type=0x00020192,
            vendor_id=VENDOR_ID,
            product_code=round(rated_power * 10),
            revision=sw_build,
            serial=serial,
            device_name=device_name,
            vendor_name="STOEBER ANTRIEBSTECHNIK",
            hardware_version=hardware_version,
            software_version=software_version,
            rpdos=4,
            tpdos=4,
            mapping_entries=6,
            sdo_servers=4,
            error_history=0,
        )
        u8, u16, u32, i16 = (
            DataType.UNSIGNED8,
            DataType.UNSIGNED16,
            DataType.UNSIGNED32,
            DataType.INTEGER16,
        )
        # parameters
        b.variable(DOMAIN, "data (segmented transfers)", DataType.DOMAIN, default=b"")
        a11 = Record(A11, "A11 axis to edit")
        for e in range(5):
            what = "display" if e == 0 else f"SDO channel {e}"
            a11.add(_var(A11, e, f"A11.{e} axis ({what})", u8, default=1, low=1, high=4))
        b.od.add(a11)
        b.variable(A82, "A82 CAN baud rate (kbit/s)", u16, default=250)
        b.variable(A180, "A180 device control", u16, access="rww", mappable=True, default=0)
        b.variable(C01, "C01 n-Max (rpm)", u16, default=3000)
        b.variable(C230, "C230 M-max (%)", u16, access="rww", mappable=True, default=150)
        b.variable(D230, "D230 speed setpoint (rpm)", i16, access="rww", mappable=True, default=0)
        b.variable(E08, "E08 n-Motor (rpm)", i16, access="ro", mappable=True, default=0)
        b.variable(E39, "E39 event cause", u8, access="ro", mappable=True, default=0)
        b.variable(E48, "E48 device state", u8, access="ro", mappable=True, default=0)
        b.variable(E82, "E82 event", u8, access="ro", mappable=True, default=NO_EVENT)
        od = b.od
        # the communication objects as the manual lists them
        for index in (0x1003, 0x1007, 0x1011, 0x1012, 0x1016, 0x1019, 0x1021, 0x1022, 0x1029):
            if index in od:
                od.remove(index)
        od.add(_var(0x1002, 0, "Manufacturer status register (E48)", u32, "ro", 0))
        od.add(_var(0x100B, 0, "Node-ID (A83)", u32, "ro", self.node_id))
        od.remove(0x1010)
        store = Record(0x1010, "Store parameters")
        store.add(_var(0x1010, 0, "Highest sub-index supported", u8, "ro", 1))
        store.add(_var(0x1010, 1, "Save all parameters (A00.0)", u32, "rw", 1))
        od.add(store)
        verify = Record(0x1020, "Verify configuration")
        verify.add(_var(0x1020, 0, "Highest sub-index supported", u8, "ro", 2))
        verify.add(_var(0x1020, 1, "Configuration date (A211)", u32, "rw", 0))
        verify.add(_var(0x1020, 2, "Configuration time (A212)", u32, "rw", 0))
        od.add(verify)
        bit31 = 0 if self.quirks["sdo_channel_bit31_enables"] else _INVALID
        for n in (2, 3, 4):
            for sub in (1, 2):
                var = od.get_variable(0x1200 + n - 1, sub)
                assert var is not None
                var.default = bit31 | self._bare(_SDO_FUNCTION[(n, sub)])
        for n in range(4):
            rx, tx = 0x1400 + n, 0x1800 + n
            od.remove(rx)
            rec = Record(rx, f"RPDO communication parameter {n + 1}")
            rec.add(_var(rx, 0, "Highest sub-index supported", u8, "ro", 2))
            rec.add(
                _var(rx, 1, "COB-ID used by RPDO", u32, "rw", self._bare(RPDO_BASE + PDO_STEP * n))
            )
            rec.add(_var(rx, 2, "Transmission type", u8, "rw", 254))
            od.add(rec)
            od.remove(tx)
            rec = Record(tx, f"TPDO communication parameter {n + 1}")
            rec.add(_var(tx, 0, "Highest sub-index supported", u8, "ro", 5))
            rec.add(
                _var(tx, 1, "COB-ID used by TPDO", u32, "rw", self._bare(TPDO_BASE + PDO_STEP * n))
            )
            rec.add(_var(tx, 2, "Transmission type", u8, "rw", 254))
            rec.add(_var(tx, 3, "Inhibit time", u16, "rw", 0))
            rec.add(_var(tx, 5, "Event timer", u16, "rw", 0))
            od.add(rec)
            for mapping in (0x1600 + n, 0x1A00 + n):
                count = od.get_variable(mapping, 0)
                assert count is not None
                count.access = Access.RO if self.quirks["direct_pdo_mapping"] else Access.RW
                count.default = 6 if self.quirks["direct_pdo_mapping"] else 0
        return b.build()

    def _deviations(self) -> Deviations:
        q = self.quirks
        return Deviations(
            comm_error_emcy=False,  # the drive reports them through its own events
            serve_sdo=False,  # four channels with the drive's own rules, see _build_channels
            cob_id_rule=self._cob_id_rule,
            padded_writes=q["padded_expedited_writes"],
            pdo_params_while_valid=q["pdo_params_while_valid"],
            direct_pdo_mapping=q["direct_pdo_mapping"],
            partial_rpdos=q["partial_rpdos"],
            transmission_types=frozenset((*range(241), 254))
            if q["transmission_types_limited"]
            else None,
            generic_error_bit=not q["emcy_without_generic_bit"],
            emcy_in_stopped=q["emcy_in_stopped"],
            # the manual's example activates new SDO COB-IDs by reset communication (its state
            # table says "start values": read as the values the parameters hold)
            reset_communication_keeps_values=True,
        )

    def _cob_id_rule(self, kind: str, number: int, value: int) -> int:
        """The drive's COB-ID parameters in CiA 301 form (see the quirks)."""
        bare = self.quirks["function_code_cob_ids"]
        if kind in ("sdo_rx", "sdo_tx"):
            function = _SDO_FUNCTION.get((number, 1 if kind == "sdo_rx" else 2))
            if self.quirks["sdo_channel_bit31_enables"]:
                value ^= _INVALID
        elif kind == "emcy":
            function = 0x80
        else:
            function = (TPDO_BASE if kind == "tpdo" else RPDO_BASE) + PDO_STEP * (number - 1)
        if bare and function is not None and value & 0x1FFFFFFF == function:
            value += self.node_id
        return value

    # ------------------------------------------------------------------ life cycle
    def start(self) -> None:
        if self.powered:
            return
        other = self.network.devices.get(self.node_id)
        if other is not None:
            raise SimulationError(
                f"{self.name}: node-ID {self.node_id} is already used by {other!r} on this "
                "network; set A83 to a free node-ID"
            )
        super().start()
        self._reset_volatile()
        self.axes.update({axis: dict(values) for axis, values in self._saved_axes.items()})
        device = Device(
            self.network,
            self.node_id,
            self.od,
            storage=self.storage,
            sdo_timeout=self.sdo_timeout,
            deviations=self._deviations(),
        )
        self.device = device
        for index, reader in (
            (E08, lambda: round(self.speed)),
            (E39, lambda: self.cause),
            (E48, lambda: self.state),
            (E82, lambda: self.event),
        ):
            device.on_read(index, 0, reader)
        device.on_write(A180, 0, self._on_control)
        device.add_listener(self._on_device_event)
        device.start()
        self._set_state(SWITCH_ON_DISABLED)
        self.every(self.tick, self._step)

    def power_off(self) -> None:
        self._close_channels()
        if self.device is not None:
            self.device.close()
            self.device = None
        super().power_off()

    def _reset_volatile(self) -> None:
        self.state = SWITCH_ON_DISABLED
        self.event = NO_EVENT
        self.cause = 0
        self.speed = 0.0  # rpm
        self.axes: dict[int, dict[tuple[int, int], bytes]] = {}
        self.guard_event = False
        self.sync_error = False
        self._control = 0

    # ------------------------------------------------------------------ SDO channels
    def _close_channels(self) -> None:
        for _, host, sub in self._channels.values():
            sub.cancel()
            host.close()
        self._channels.clear()

    def _build_channels(self) -> None:
        """SDO channel 1 on its fixed identifiers, 2-4 as 1201h-1203h say."""
        self._close_channels()
        device = self.device
        if device is None:
            return
        for number in (1, 2, 3, 4):
            if number == 1:
                rx, tx = sdo_cob_ids(self.node_id)
            else:
                index = 0x1200 + number - 1
                rx_value = self._cob_id_rule("sdo_rx", number, device.get(index, 1))
                tx_value = self._cob_id_rule("sdo_tx", number, device.get(index, 2))
                if (rx_value | tx_value) & _INVALID:
                    continue
                rx, tx = rx_value & 0x7FF, tx_value & 0x7FF
            server = SdoServer(
                rx, tx, _Channel(self, number), timeout=self.sdo_timeout, reports=False
            )
            host = self.network.attach(server)
            sub = self.network.subscribe(rx, partial(self._on_sdo_frame, host))
            self._channels[number] = (server, host, sub)

    def _on_sdo_frame(self, host: MachineHost, frame: Frame, now: float) -> None:
        device = self.device
        if device is not None and device.nmt.sdo_allowed:
            host.feed(frame, now)

    @property
    def sdo_channels(self) -> dict[int, tuple[int, int]]:
        """The active SDO channels: number -> (COB-ID client -> server, server -> client)."""
        return {n: (s.rx_cob_id, s.tx_cob_id) for n, (s, _, _) in self._channels.items()}

    # ------------------------------------------------------------------ axes 2-4
    def axis_parameter(self, axis: int, index: int, subindex: int) -> bytes | None:
        """The value of a parameter of axis 2-4 as stored (None: still its default)."""
        return self.axes.get(axis, {}).get((index, subindex))

    def set_axis_parameter(self, axis: int, index: int, subindex: int, data: bytes) -> None:
        """Write a parameter of axis 2-4 (checked as the device checks axis 1)."""
        device = self.device
        var = self.od.get_variable(index, subindex)
        if device is None or var is None:
            raise SdoAbort(SdoAbortCode.NO_OBJECT, f"no parameter 0x{index:04X}:{subindex:02X}")
        _size_hint(device.sdo_backend, index, subindex)  # refuses what the device refuses
        size = var.data_type.size
        if (
            self.quirks["padded_expedited_writes"]
            and size is not None
            and size < len(data) <= 4
            and not any(data[size:])
        ):
            data = data[:size]
        try:
            value = var.decode(data)
            var.check(value)
        except CobusError as exc:
            raise SdoAbort(SdoAbortCode.INVALID_VALUE, str(exc)) from None
        self.axes.setdefault(axis, {})[(index, subindex)] = var.encode(value)

    # ------------------------------------------------------------------ values
    @property
    def nmt_state(self) -> NmtState | None:
        """The inverter's NMT state."""
        return self.device.state if self.device is not None else None

    def _get(self, index: int, sub: int = 0) -> int:
        device = self.device
        if device is None:
            return 0
        value: int = device.get(index, sub)
        return value

    def mapped_length(self, mapping_index: int) -> int:
        """The bytes mapped into the PDO whose mapping parameter is ``mapping_index``."""
        bits = 0
        for sub in range(1, 7):
            bits += self._get(mapping_index, sub) & 0xFF
        return (bits + 7) // 8

    def leds(self) -> tuple[str, str]:
        """The green and red LEDs of CiA 303-3 as the manual describes them."""
        state = self.nmt_state
        green = {
            None: "off",
            NmtState.PRE_OPERATIONAL: "blinking",
            NmtState.OPERATIONAL: "on",
            NmtState.STOPPED: "single flash",
        }.get(state, "off")
        if self.network.bus_state is BusState.BUS_OFF:
            red = "on"
        elif self.sync_error:
            red = "triple flash"
        elif self.guard_event:
            red = "double flash"
        elif self.network.bus_state is not BusState.ACTIVE:
            red = "single flash"
        else:
            red = "off"
        return green, red

    def status(self) -> dict[str, Any]:
        state = self.nmt_state
        green, red = self.leds()
        text, code, register = EVENTS.get(self.event, ("?", 0, 0))
        return {
            **super().status(),
            "state": state.name.lower() if state is not None else "off",
            "device_state": STATES[self.state],
            "speed_rpm": round(self.speed, 1),
            "setpoint_rpm": self._get(D230),
            "fault": self.state in (FAULT_REACTION, FAULT),
            "event": self.event,
            "event_text": text,
            "cause": self.cause,
            "emcy_code": code,
            "error_register": register,
            "motor_temperature_tripped": self.motor_hot,
            "led_green": green,
            "led_red": red,
            "sdo_channels": sorted(self.sdo_channels),
        }

    # ------------------------------------------------------------------ events of the device
    def _on_device_event(self, event: DeviceEvent) -> None:
        device = self.device
        if device is None:
            return
        if isinstance(event, Booted):
            self._build_channels()
            self._report_fault_after_reset()
        elif isinstance(event, StateChanged):
            if event.new is NmtState.STOPPED:
                self._close_channels()  # SDO is not available; transfers end silently
            elif event.new is NmtState.PRE_OPERATIONAL and event.old is NmtState.STOPPED:
                self._build_channels()
        elif isinstance(event, EntryWritten):
            if (
                0x1201 <= event.index <= 0x1203
                and event.subindex in (1, 2)
                and not self.quirks["sdo_ids_at_reset"]
            ):
                self.network.loop.call_soon(self._rebuild_if_on)
        elif isinstance(event, RpdoReceived):
            if self.quirks["pdo_reply_254"] and device.get(0x1800 + event.number - 1, 2) == 254:
                with contextlib.suppress(DeviceConfigError):  # the TPDO is not valid
                    device.send_tpdo(event.number)
        elif isinstance(event, LifeGuardingLost):
            self.guard_event = True
            self.raise_event(COMMUNICATION, CAUSE_ERROR_CONTROL)
        elif isinstance(event, LifeGuardingRestored):
            self.guard_event = False
        elif isinstance(event, SyncLost):
            self.sync_error = True
        elif isinstance(event, SyncRestored):
            self.sync_error = False
        elif isinstance(event, ParametersStored):
            self._saved_axes = {axis: dict(values) for axis, values in self.axes.items()}

    def _rebuild_if_on(self) -> None:
        if self.device is not None:
            self._build_channels()

    # ------------------------------------------------------------------ the device state machine
    def raise_event(self, number: int, cause: int = 0) -> None:
        """The inverter meets event ``number`` (E82) with ``cause`` (E39): fault reaction,
        EMCY once. Ignored while a fault is being handled (the first event is reported)."""
        if number not in EVENTS or number == NO_EVENT:
            known = ", ".join(str(n) for n in EVENTS if n != NO_EVENT)
            raise SimulationError(f"E82 event {number!r} is not in the manual's table: {known}")
        if not 0 <= cause <= 0xFF:
            raise SimulationError(f"E39 cause {cause!r} must be 0..255")
        if self.state in (FAULT_REACTION, FAULT):
            return
        self._set_state(FAULT_REACTION)
        self.event, self.cause = number, cause
        _, code, register = EVENTS[number]
        device = self.device
        if device is not None:
            device.send_emergency(code, register, bytes((number, cause)))

    def _report_fault_after_reset(self) -> None:
        """A reset node cleared the device's errors while the inverter is still in fault:
        report the event again (reset communication keeps them: 1001h is not 0 then)."""
        device = self.device
        if device is None or self.state not in (FAULT_REACTION, FAULT) or device.get(0x1001):
            return
        _, code, register = EVENTS[self.event]
        device.send_emergency(code, register, bytes((self.event, self.cause)))

    def acknowledge(self) -> bool:
        """Acknowledge the fault (A180 bit 2, a terminal or the keypad): back to switch-on
        disabled with EMCY 0000h, when the drive stands still in fault and the cause is gone.
        Returns whether it did."""
        if self.state != FAULT or self._cause_present(self.event):
            return False
        self._set_state(SWITCH_ON_DISABLED)
        self.event, self.cause = NO_EVENT, 0
        device = self.device
        if device is not None:
            device.clear_emergency(manufacturer_data=bytes((NO_EVENT, 0)))
        return True

    def _set_state(self, state: int) -> None:
        """Enter device state ``state`` (E48, also 1002h)."""
        self.state = state
        device = self.device
        if device is not None and device.get(0x1002, 0) != state:
            device.set(0x1002, 0, state)

    def _cause_present(self, event: int) -> bool:
        if event == MOTOR_TEMPERATURE:
            return self.motor_hot
        if event == M_MAX:
            return self.load > self._get(C230)
        return event in self.causes

    def _on_control(self, value: int) -> None:
        if value & ACK_BIT and not self._control & ACK_BIT:
            self._control = value  # before acknowledging: a level enable takes effect after
            self.acknowledge()
        self._control = value

    # ------------------------------------------------------------------ physics
    def _step(self, dt: float) -> None:
        if self.device is None or dt <= 0:
            return
        control = self._get(A180)
        if self.motor_hot:
            self.raise_event(MOTOR_TEMPERATURE)
        if self.load > self._get(C230):
            self.raise_event(M_MAX)
        for number, cause in self.causes.items():
            self.raise_event(number, cause)
        n_max = self._get(C01)
        if abs(self.speed) > 1.2 * n_max:
            self.raise_event(OVERSPEED)
        state = self.state
        if state in (SWITCH_ON_DISABLED, 2, 3, ENABLED):
            if control & QUICK_STOP_BIT and state == ENABLED:
                state = QUICK_STOP
            elif control & ENABLE_BIT:
                state = ENABLED
            else:
                state = SWITCH_ON_DISABLED
        if state == ENABLED:
            setpoint = max(-n_max, min(n_max, self._get(D230)))
            self.speed = _toward(self.speed, setpoint, self.ramp * dt)
        elif state in (QUICK_STOP, FAULT_REACTION):
            self.speed = _toward(self.speed, 0.0, self.quick_stop_ramp * dt)
            if self.speed == 0.0:
                state = FAULT if state == FAULT_REACTION else SWITCH_ON_DISABLED
        else:  # the power stage is off: the motor coasts
            self.speed = _toward(self.speed, 0.0, 1000.0 * dt)
        self._set_state(state)

    # ------------------------------------------------------------------ faults
    def inject(self, fault: str, **params: Any) -> None:
        if fault == "motor_overtemperature":
            self.motor_hot = bool(params.get("active", True))
            if self.motor_hot:
                self.raise_event(MOTOR_TEMPERATURE)
        elif fault == "event":
            number = int(params.get("number", 44))
            cause = int(params.get("cause", 0))
            if params.get("active", True):
                self.causes[number] = cause
                self.raise_event(number, cause)
            else:
                self.causes.pop(number, None)
        elif fault == "overload":
            self.load = float(params.get("load", 200))
            if self.load > self._get(C230):
                self.raise_event(M_MAX)
        else:
            super().inject(fault, **params)


def _size_hint(backend: SdoServerBackend, index: int, subindex: int) -> int | None:
    """The back end's size hint (it refuses unknown and read-only entries), if it has one."""
    hint = getattr(backend, "size_hint", None)
    if hint is None:
        return None
    size: int | None = hint(index, subindex)
    return size


def _toward(value: float, target: float, step: float) -> float:
    if abs(target - value) <= step:
        return target
    return value + math.copysign(step, target - value)
