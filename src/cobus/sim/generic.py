"""Simulated devices that are CANopen devices, and the device of any EDS/DCF file.

:class:`CanopenSimDevice` runs a :class:`cobus.device.Device` on a dictionary its subclass
builds, and adds what every simulated CANopen device shares:

- power: :meth:`~CanopenSimDevice.power_off` takes the node off the bus (it falls silent and
  forgets its volatile state); :meth:`~CanopenSimDevice.power_on` boots it again on the same
  dictionary and the same parameter storage, so what a master saved with 1010h survives;
- parameters from a rig file (``parameters: {"0x1017": 100, "0x1800:5": 50}``) become the
  dictionary's configured values, so they hold after every reset as well;
- the faults of :attr:`CanopenSimDevice.FAULTS`: a node-ID change, a heartbeat that stops, SDO
  answers that come late;
- LSS (CiA 305): a device made with node-ID :data:`~cobus.device.UNCONFIGURED` (a rig's
  ``node: unconfigured``) waits for an LSS master to give it one, found by its ``serial``
  (1018h sub 4; random if not given). A node-ID given by LSS holds until the power goes,
  unless the master had the device store it.

:class:`EdsDevice` (kind ``eds``) serves the objects of an EDS or DCF with their defaults and
its PDOs. What the file lacks that the device runtime needs is said clearly: the mandatory
objects 1000h, 1001h and 1018h (an error, unless ``complete`` adds them), and what a missing
optional object means for the node (no heartbeat without 1017h, ...) in
:attr:`EdsDevice.findings`.
"""

from __future__ import annotations

import random
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any, ClassVar

from cobus.device import (
    UNCONFIGURED,
    ConfigurationProblem,
    Device,
    DeviceEvent,
    NodeIdChanged,
    ParameterStorage,
    minimal_od,
)
from cobus.device.storage import open_storage
from cobus.errors import CobusError
from cobus.od import ObjectDictionary, Variable, load
from cobus.proto.emcy import EmcyCode
from cobus.proto.nmt import check_node_id
from cobus.runtime.network import AsyncNetwork
from cobus.sim.base import SimulatedDevice, SimulationError

__all__ = [
    "CanopenSimDevice",
    "DeviceOffError",
    "EdsDevice",
    "EdsDeviceError",
    "FaultParameterError",
    "check_fault_params",
]

_MANDATORY = (0x1000, 0x1001, 0x1018)
_KEY = re.compile(
    r"^\s*(?:0x)?([0-9a-f]{1,4})h?\s*(?:(?::|sub)\s*(?:0x)?([0-9a-f]{1,2})h?)?\s*$", re.I
)


class DeviceOffError(SimulationError, RuntimeError):
    """The simulated device is powered off: its CANopen device does not exist right now."""


class FaultParameterError(SimulationError, ValueError):
    """A fault was injected with a parameter it does not take or a value it cannot use."""


class EdsDeviceError(SimulationError, ValueError):
    """An EDS/DCF file cannot run as a device; the message says what to add or set."""


def check_fault_params(
    kind: str, fault: str, params: Mapping[str, Any], allowed: Mapping[str, Any]
) -> dict[str, Any]:
    """``params`` completed with the defaults of ``allowed``; :class:`FaultParameterError` for a
    name ``allowed`` does not list (a default of ``...`` marks a required parameter)."""
    unknown = sorted(set(params) - set(allowed))
    if unknown:
        takes = ", ".join(sorted(allowed)) or "no parameters"
        raise FaultParameterError(
            f"{kind} fault {fault!r} takes {takes}; it got {', '.join(unknown)}"
        )
    out = dict(allowed)
    out.update(params)
    missing = sorted(k for k, v in out.items() if v is ...)
    if missing:
        raise FaultParameterError(
            f"{kind} fault {fault!r} needs the parameter(s) {', '.join(missing)}"
        )
    return out


def parse_key(key: int | str) -> tuple[int, int | None]:
    """``"0x1800:5"``, ``"1800sub5"``, ``"1017h"`` or ``0x1017`` as (index, sub-index or None)."""
    if isinstance(key, int) and not isinstance(key, bool):
        return key, None
    match = _KEY.match(str(key))
    if match is None:
        raise SimulationError(
            f"parameter key {key!r} is not an object address: write it as '0x1017', "
            "'0x1800:5' or '1800sub5'"
        )
    index = int(match.group(1), 16)
    sub = match.group(2)
    return index, None if sub is None else int(sub, 16)


def _variable(od: ObjectDictionary, key: int | str, where: str) -> Variable:
    index, sub = parse_key(key)
    obj = od.get(index)
    if obj is None:
        raise SimulationError(f"{where}: parameter {key!r}: there is no object 0x{index:04X}")
    if isinstance(obj, Variable):
        if sub not in (None, 0):
            raise SimulationError(
                f"{where}: parameter {key!r}: 0x{index:04X} is a single variable; leave the "
                "sub-index out"
            )
        return obj
    if sub is None:
        raise SimulationError(
            f"{where}: parameter {key!r}: 0x{index:04X} has sub-indices; write 0x{index:04X}:N"
        )
    var = obj.get(sub)
    if var is None:
        raise SimulationError(f"{where}: parameter {key!r}: 0x{index:04X} has no sub-index {sub}")
    return var


class CanopenSimDevice(SimulatedDevice):
    """A simulated device that is a CANopen device (see the module docstring).

    Subclasses build the dictionary in :meth:`build_od`, bind their model to the running
    device in :meth:`bind` (called at every power-on with the new device), start their physics
    in :meth:`on_power_on` and may follow the device's events in :meth:`on_event`.

    Options: ``storage`` (a path or a :class:`~cobus.device.ParameterStorage`; default in
    memory, kept across power cycles), ``parameters`` (object address -> configured value),
    ``heartbeat_ms`` (the producer heartbeat time 1017h), ``sdo_timeout`` (seconds the SDO
    servers wait within a segmented or block transfer), ``serial`` (1018h sub 4, the serial
    number LSS finds the device by; random for an unconfigured device if not given), ``lss``
    (the device is an LSS slave; always when it starts unconfigured).
    """

    #: The device can be an LSS slave (start unconfigured, take a node-ID by LSS).
    LSS: ClassVar[bool] = True

    kind = "canopen"
    FAULTS: ClassVar[Mapping[str, str]] = {
        "node_id_change": (
            "the node takes another node-ID (node_id=N) and boots under it: boot-up message, "
            "pre-operational, its default COB-IDs follow"
        ),
        "heartbeat_stop": (
            "the heartbeat producer falls silent while the node runs on (until heartbeat_resume "
            "or a power cycle); 1017h keeps its value"
        ),
        "heartbeat_resume": "the heartbeat producer sends again with 1017h",
        "sdo_delay": (
            "every SDO answer comes late by delay seconds (0 ends it): a client whose timeout "
            "is shorter gives up"
        ),
    }
    #: The parameters each fault takes (kind, "?" when optional): checked when a rig loads.
    FAULT_PARAMS: ClassVar[Mapping[str, Mapping[str, str]]] = {
        "node_id_change": {"node_id": "node_id"},
        "heartbeat_stop": {},
        "heartbeat_resume": {},
        "sdo_delay": {"delay": "seconds"},
    }

    def __init__(
        self,
        network: AsyncNetwork,
        node_id: int,
        *,
        quirks: Mapping[str, bool] | None = None,
        name: str | None = None,
        storage: str | Path | ParameterStorage | None = None,
        parameters: Mapping[int | str, Any] | None = None,
        heartbeat_ms: int | None = None,
        sdo_timeout: float = 1.0,
        serial: int | None = None,
        lss: bool | None = None,
    ) -> None:
        if node_id != UNCONFIGURED or isinstance(node_id, bool):
            try:
                check_node_id(node_id)
            except CobusError as exc:
                raise SimulationError(f"{self.kind}: {exc} (or unconfigured, FFh)") from None
        if serial is not None and (
            isinstance(serial, bool) or not isinstance(serial, int) or not 0 <= serial < 1 << 32
        ):
            raise SimulationError(f"{self.kind}: serial {serial!r} is no UNSIGNED32")
        if lss is not None and not isinstance(lss, bool):
            raise SimulationError(f"{self.kind}: lss {lss!r}: give true or false")
        super().__init__(network, node_id, quirks=quirks, name=name)
        #: The node-ID the device has at power-on (FFh: none; an LSS master gives it one).
        self.power_on_node_id = node_id
        self._lss = lss
        self._storage = open_storage(storage)
        self._sdo_timeout = sdo_timeout
        self.od = self.build_od()
        settings: dict[int | str, Any] = {}
        if serial is None and node_id == UNCONFIGURED:
            serial = random.getrandbits(32)
        if node_id == UNCONFIGURED and name is None and serial is not None:
            self.name = f"{self.kind}-{serial:08X}"  # (kind + FFh would name them all alike)
        if serial is not None:
            settings["0x1018:4"] = serial
        if heartbeat_ms is not None:
            settings[0x1017] = heartbeat_ms
        settings.update(parameters or {})
        for key, value in settings.items():
            var = _variable(self.od, key, self.name)
            try:
                var.value = value
            except CobusError as exc:
                raise SimulationError(
                    f"{self.name}: parameter {key!r} = {value!r}: {exc}"
                ) from None
        self._device: Device | None = None
        #: Seconds every SDO answer comes late (the sdo_delay fault; kept across power cycles).
        self.sdo_delay = 0.0
        #: Why parts of the configuration could not be used (from the device at each boot).
        self.problems: list[str] = []

    # ------------------------------------------------------------------ hooks
    def build_od(self) -> ObjectDictionary:
        """The dictionary the device serves (built once; every power-on reuses it)."""
        raise NotImplementedError(f"{type(self).__name__} must build its dictionary")

    def bind(self, device: Device) -> None:
        """Bind the model to a newly created device (read/write callbacks), before it boots."""

    def on_power_on(self) -> None:
        """The device has booted: start the physics (``self.every(...)``)."""

    def on_power_off(self) -> None:
        """The power is gone: forget the volatile state of the model."""

    def on_event(self, event: DeviceEvent) -> None:
        """An event of the running device (NMT changes, writes, RPDOs...)."""

    def on_bus_recovered(self) -> None:
        """The node's CAN controller left bus-off: report it (EMCY 8140h), then clear it."""
        device = self._device
        if device is None:
            return
        device.send_emergency(EmcyCode.BUS_OFF_RECOVERED)
        device.clear_emergency(EmcyCode.BUS_OFF_RECOVERED)

    # ------------------------------------------------------------------ the running device
    @property
    def device(self) -> Device:
        """The running CANopen device; :class:`DeviceOffError` while the power is off."""
        return self._running()

    def _running(self) -> Device:
        device = self._device
        if device is None:
            raise DeviceOffError(
                f"{self.name} is powered off: start it or inject power_return first"
            )
        return device

    @property
    def running(self) -> bool:
        """Whether the device is powered and its CANopen device runs."""
        return self._device is not None

    def start(self) -> None:
        """Power on: a new device on the dictionary boots (boot-up message, pre-operational)."""
        if self._device is not None:
            return
        self.node_id = self.power_on_node_id
        other = self.network.devices.get(self.node_id)
        if other is not None:
            raise SimulationError(
                f"{self.name}: node-ID {self.node_id} is taken by another device on this "
                "network; give each simulated device its own node-ID"
            )
        try:
            device = Device(
                self.network,
                self.node_id,
                self.od,
                storage=self._storage,
                sdo_timeout=self._sdo_timeout,
                lss=self._lss,
            )
        except CobusError as exc:  # (a stored LSS node-ID another device holds)
            raise SimulationError(f"{self.name}: {exc}") from None
        super().start()
        self.node_id = device.node_id  # (the one an LSS master had it store)
        device.simulation.sdo_response_delay = self.sdo_delay
        self.problems = []
        self._device = device
        device.add_listener(self._on_device_event)
        self.bind(device)
        try:
            device.start()
        except Exception:
            self._device = None
            device.close()
            self.powered = False
            raise
        self.on_power_on()

    def power_off(self) -> None:
        device = self._device
        super().power_off()
        if device is None:
            return
        self._device = None
        device.close()
        self.on_power_off()

    def _on_device_event(self, event: DeviceEvent) -> None:
        if isinstance(event, NodeIdChanged):
            self.node_id = event.node_id
        elif isinstance(event, ConfigurationProblem):
            self.problems.append(event.reason)
        self.on_event(event)

    # ------------------------------------------------------------------ panel
    def status(self) -> dict[str, Any]:
        out = super().status()
        device = self._device
        if device is None:
            out.update(nmt="off", error_register=0)
        else:
            out.update(nmt=device.state.name.lower(), error_register=int(device.error_register))
        out["faults"] = self.active_faults()
        return out

    def active_faults(self) -> list[str]:
        """The injected faults in effect now (for a panel)."""
        active = []
        if not self.powered:
            active.append("power_loss")
        device = self._device
        if device is not None and device.simulation.heartbeat_muted:
            active.append("heartbeat_stop")
        if self.sdo_delay > 0:
            active.append(f"sdo_delay={self.sdo_delay:g}s")
        return active

    # ------------------------------------------------------------------ faults
    def inject(self, fault: str, **params: Any) -> None:
        if fault == "node_id_change":
            p = check_fault_params(self.kind, fault, params, {"node_id": ...})
            new = p["node_id"]
            if not isinstance(new, int) or isinstance(new, bool) or not 1 <= new <= 127:
                raise FaultParameterError(f"node_id_change: node_id {new!r} is not 1..127")
            taken = self.network.devices.get(new)
            if taken is not None and taken is not self._device:
                raise FaultParameterError(
                    f"node_id_change: node-ID {new} is taken by another device on this network"
                )
            self.power_on_node_id = new  # and boots under it after a power cycle
            if self._device is None:
                self.node_id = new
            else:
                self._device.set_node_id(new)
        elif fault in ("heartbeat_stop", "heartbeat_resume"):
            check_fault_params(self.kind, fault, params, {})
            self._running().simulation.heartbeat_muted = fault == "heartbeat_stop"
        elif fault == "sdo_delay":
            p = check_fault_params(self.kind, fault, params, {"delay": ...})
            delay = p["delay"]
            if not isinstance(delay, int | float) or isinstance(delay, bool) or not delay >= 0:
                raise FaultParameterError(f"sdo_delay: delay {delay!r} must be seconds >= 0")
            self.sdo_delay = float(delay)
            if self._device is not None:
                self._device.simulation.sdo_response_delay = self.sdo_delay
        else:
            super().inject(fault, **params)


class EdsDevice(CanopenSimDevice):
    """The device of an EDS or DCF file: its objects with their defaults (a DCF's configured
    values), its PDOs, and the CiA 301 services the device runtime gives every node.

    ``eds`` is the file; ``complete`` adds the mandatory objects 1000h, 1001h, 1018h the file
    lacks (with zero identity) instead of refusing the file.
    """

    kind = "eds"

    def __init__(
        self,
        network: AsyncNetwork,
        node_id: int,
        *,
        eds: str | Path,
        complete: bool = False,
        **options: Any,
    ) -> None:
        self.eds = Path(eds)
        self._complete = bool(complete)
        #: What the file lacks and what that means for the node (one sentence each).
        self.findings: list[str] = []
        super().__init__(network, node_id, **options)

    def build_od(self) -> ObjectDictionary:
        od = load(self.eds, node_id=self.node_id if self.node_id <= 127 else None)
        path = str(self.eds)
        missing = [i for i in _MANDATORY if i not in od]
        if missing and not self._complete:
            names = ", ".join(f"{i:04X}h" for i in missing)
            raise EdsDeviceError(
                f"{path}: lacks {names}, which every CANopen device serves (CiA 301); add "
                "them to the file, or set the option complete: true to serve them with "
                "default values"
            )
        if missing:
            spare = minimal_od(node_id=self.node_id)
            for index in missing:
                od.add(spare[index])
                self.findings.append(
                    f"{index:04X}h is not in the file: served with the default of a cobus device"
                )
        self.findings.extend(_consequences(od))
        self.findings.extend(str(f) for f in od.errors)
        return od

    def status(self) -> dict[str, Any]:
        out = super().status()
        out["eds"] = self.eds.name
        return out


def _consequences(od: ObjectDictionary) -> list[str]:
    """What the optional objects an EDS lacks mean for the node."""
    notes = []
    if 0x1017 not in od:
        notes.append("1017h is not in the file: the node sends no heartbeat")
    if 0x1016 not in od:
        notes.append("1016h is not in the file: the node consumes no heartbeat")
    if 0x1200 not in od:
        notes.append("1200h is not in the file: SDO is served on the default 600h/580h + node-ID")
    if 0x1014 not in od:
        notes.append("1014h is not in the file: EMCY goes out on the default 80h + node-ID")
    if 0x1010 not in od:
        notes.append("1010h is not in the file: the node cannot store parameters")
    if 0x100C not in od or 0x100D not in od:
        notes.append("100Ch/100Dh are not in the file: the node does no life guarding")
    if not any(0x1400 <= o.index <= 0x15FF for o in od):
        notes.append("no RPDO communication objects (1400h-15FFh): the node receives no PDO")
    if not any(0x1800 <= o.index <= 0x19FF for o in od):
        notes.append("no TPDO communication objects (1800h-19FFh): the node sends no PDO")
    return notes
