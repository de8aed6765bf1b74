"""A rig: simulated devices on one bus, described in a YAML file, with scripted faults.

The file::

    bus: embedded              # or: {interface: socketcan, channel: can0, bitrate: 500000}
    devices:
      - node: 8
        kind: zapi_ace2        # a kind of KINDS, or "package.module:Class"
        name: traction         # optional; default: kind + node
      - node: unconfigured     # no node-ID until an LSS master gives it one (CiA 305)
        kind: cia402_drive
        serial: 0x1234         # 1018h sub 4, what LSS finds it by (random if left out)
        options: {...}         # keyword arguments of the device class
        quirks: {...}          # quirk name -> on/off
    faults:                    # optional: injected while the rig runs
      - {at: 5.0, node: 8, fault: power_loss}
      - {at: 0, fault: frame_loss, rate: 0.01, seed: 1}   # no node: a bus fault

``bus: embedded`` means the bus comes from whoever runs the rig: the network given to
:meth:`Rig.start`, or the interface named on the command line (else python-can's
configuration). Relative paths in the options ``eds`` and ``storage`` are relative to the
rig file.

Kinds resolve through :data:`KINDS`, a table of import strings, when the rig starts: a
device module that is missing gives :class:`KindUnavailableError` ("kind X is not
available: ...") instead of an import error when the file is read.

Bus faults (:data:`~cobus.sim.faults.BUS_FAULTS`) need the network's bus to be a
:class:`~cobus.sim.faults.FaultyBus`: :meth:`Rig.create_network` and :meth:`Rig.running`
build it that way.
"""

from __future__ import annotations

import asyncio
import contextlib
import importlib
import logging
import math
from collections.abc import AsyncIterator, Mapping, Sequence
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from cobus._yaml import read_yaml
from cobus.device import UNCONFIGURED
from cobus.errors import clip
from cobus.proto import Event, Frame
from cobus.proto.nmt import check_node_id
from cobus.runtime import open_bus
from cobus.runtime.events import BusState, BusStateChanged, HandlerFailed
from cobus.runtime.network import AsyncNetwork, Subscription
from cobus.sim.base import SimulatedDevice, SimulationError
from cobus.sim.faults import (
    BUS_FAULTS,
    Babbler,
    FaultConfigError,
    FaultyBus,
    check_fault_parameters,
    fault_catalogue,
)
from cobus.sim.generic import CanopenSimDevice, FaultParameterError, check_fault_params

__all__ = [
    "KINDS",
    "BusSpec",
    "DeviceSpec",
    "FaultSpec",
    "KindUnavailableError",
    "Rig",
    "RigError",
    "ready_rig",
    "ready_rigs",
    "resolve_kind",
]

log = logging.getLogger(__name__)

#: Device kinds of rig files -> "module:Class" of their simulated device.
KINDS: dict[str, str] = {
    "cia402_drive": "cobus.sim.drive402:SimulatedDrive402",
    "cia401_io": "cobus.sim.io401:SimulatedIo401",
    "eds": "cobus.sim.generic:EdsDevice",
    "zapi_ace2": "cobus.sim.zapi:ZapiAce2",
    "ec_motor": "cobus.sim.ecmotor:EcMotor",
    "stober_mds5000": "cobus.sim.stober:StoberMds5000",
}

_PATH_OPTIONS = ("eds", "storage")
_DEVICE_KEYS = {"node", "kind", "name", "options", "quirks", "serial"}
_BUS_KEYS = {"interface", "channel", "bitrate"}


class RigError(SimulationError, ValueError):
    """A rig file or a rig operation that cannot work; says where and what to change."""

    def __str__(self) -> str:
        return "\n".join(clip(line, 600) for line in super().__str__().split("\n"))


class KindUnavailableError(RigError):
    """A device kind whose simulator cannot be imported (its module is missing or broken)."""


def resolve_kind(kind: str) -> type[SimulatedDevice]:
    """The simulated device class of ``kind`` (a name of :data:`KINDS` or "module:Class")."""
    target = KINDS.get(kind)
    if target is None:
        if ":" not in kind:
            known = ", ".join(sorted(KINDS))
            raise RigError(f"kind {kind!r} is unknown; known kinds: {known} (or 'module:Class')")
        target = kind
    module_name, _, class_name = target.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise KindUnavailableError(
            f"kind {kind} is not available: module {module_name} cannot be imported ({exc})"
        ) from exc
    cls = getattr(module, class_name, None)
    if not isinstance(cls, type) or not issubclass(cls, SimulatedDevice):
        raise KindUnavailableError(
            f"kind {kind} is not available: {target} is not a SimulatedDevice class"
        )
    return cls


def ready_rigs() -> list[str]:
    """The names of the rig files shipped with cobus (``cobus sim NAME`` runs one)."""
    folder = resources.files("cobus.sim") / "rigs"
    if not folder.is_dir():
        return []
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".yaml"))


def ready_rig(name: str) -> Path:
    """The path of the shipped rig file ``name`` (e.g. ``"thesis"``)."""
    target = resources.files("cobus.sim") / "rigs" / f"{name}.yaml"
    if not target.is_file():
        known = ", ".join(ready_rigs()) or "none"
        raise RigError(f"there is no ready rig {name!r}; cobus ships: {known}")
    return Path(str(target))


@dataclass(frozen=True)
class BusSpec:
    """Where the rig runs: an interface (python-can arguments) or embedded (None)."""

    interface: str | None = None
    channel: Any = None
    bitrate: int | None = None
    options: Mapping[str, Any] = field(default_factory=dict)

    @property
    def embedded(self) -> bool:
        """Whether the rig runs on a bus given by the program that loads it."""
        return self.interface is None and self.channel is None


@dataclass(frozen=True)
class DeviceSpec:
    """One device of a rig file; ``node`` :data:`~cobus.device.UNCONFIGURED` (FFh) for one
    that waits for an LSS master to give it a node-ID."""

    node: int
    kind: str
    name: str | None = None
    options: Mapping[str, Any] = field(default_factory=dict)
    quirks: Mapping[str, bool] = field(default_factory=dict)


@dataclass(frozen=True)
class FaultSpec:
    """A fault injected ``at`` seconds after the rig started; ``node`` None: a bus fault."""

    fault: str
    node: int | None = None
    at: float = 0.0
    params: Mapping[str, Any] = field(default_factory=dict)


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


class _Traffic:
    """Frames and bits seen on the network, for the bus load of the status table."""

    def __init__(self, network: AsyncNetwork) -> None:
        self.network = network
        self.frames = 0
        self.bits = 0
        self._mark = (network.time(), 0, 0)
        self.subscription: Subscription = network.subscribe_all(self._count)

    def _count(self, frame: Frame, now: float) -> None:
        self.frames += 1
        # without bit stuffing: SOF..EOF and interframe space of a classic frame
        self.bits += (67 if frame.extended else 47) + (0 if frame.rtr else 8 * frame.dlc)

    def sample(self, bitrate: int | None) -> dict[str, Any]:
        now = self.network.time()
        then, frames, bits = self._mark
        self._mark = (now, self.frames, self.bits)
        span = now - then
        rate = (self.frames - frames) / span if span > 0 else 0.0
        out: dict[str, Any] = {"frames": self.frames, "frames_per_s": round(rate, 1)}
        if bitrate and span > 0:
            out["load_percent"] = round(100.0 * (self.bits - bits) / span / bitrate, 1)
        return out


class Rig:
    """Simulated devices on one bus (see the module docstring)."""

    def __init__(
        self,
        devices: Sequence[DeviceSpec],
        *,
        bus: BusSpec | None = None,
        faults: Sequence[FaultSpec] = (),
        path: str | Path | None = None,
    ) -> None:
        self.path = None if path is None else Path(path)
        self.bus_spec = bus or BusSpec()
        self.specs = list(devices)
        self.fault_specs = list(faults)
        where = str(self.path or "rig")
        seen: dict[int, int] = {}
        for i, spec in enumerate(self.specs):
            if spec.node == UNCONFIGURED:
                continue  # (as many as there are: LSS tells them apart by their serials)
            if spec.node in seen:
                raise RigError(
                    f"{where}: devices[{i}]: node {spec.node} is used twice (devices"
                    f"[{seen[spec.node]}] and devices[{i}]); give each device its own node-ID"
                )
            seen[spec.node] = i
        for i, fault in enumerate(self.fault_specs):
            if fault.node is None and fault.fault not in BUS_FAULTS:
                raise RigError(
                    f"{where}: faults[{i}]: {fault.fault!r} is no bus fault ("
                    f"{', '.join(BUS_FAULTS)}); name the node of a device fault"
                )
            if fault.node is not None and fault.node not in seen:
                raise RigError(f"{where}: faults[{i}]: there is no device with node {fault.node}")
            self._check_params(i, fault, where)
            self._check_new_node(i, fault, where)
        #: The running devices by the node-ID their spec gives (empty until started); an
        #: unconfigured one by 100h + its place in the file (:meth:`device` finds it by the
        #: node-ID LSS gave it, or by name).
        self.devices: dict[int, SimulatedDevice] = {}
        self.network: AsyncNetwork | None = None
        self._handles: list[asyncio.TimerHandle] = []
        self._babbler: Babbler | None = None
        self._babbler_node: int | None = None
        self._traffic: _Traffic | None = None
        self._opened: FaultyBus | None = None
        self._bitrate: int | None = self.bus_spec.bitrate

    def _check_params(self, i: int, fault: FaultSpec, where: str) -> None:
        """The fault's parameters, checked now rather than when it fires."""
        device: type[SimulatedDevice] | None = None
        if fault.node is not None and fault.fault not in BUS_FAULTS:  # (babbling as a node)
            spec = next(s for s in self.specs if s.node == fault.node)
            try:
                device = resolve_kind(spec.kind)
            except Exception:  # (an unknown kind is reported when the rig starts)
                return
        try:
            check_fault_parameters(device, fault.fault, fault.params)
        except FaultParameterError as exc:
            raise RigError(f"{where}: faults[{i}]: {exc}") from None

    def _check_new_node(self, i: int, fault: FaultSpec, where: str) -> None:
        """A node_id_change to the node-ID of a device of the rig that never moves away
        would fail when it fires: said now."""
        if fault.fault != "node_id_change":
            return
        new = fault.params.get("node_id")
        movers = {f.node for f in self.fault_specs if f.fault == "node_id_change"}
        if new != fault.node and any(s.node == new and s.node not in movers for s in self.specs):
            raise RigError(
                f"{where}: faults[{i}]: node_id_change to node {new}: that node-ID is taken by "
                "another device of this rig"
            )

    # ------------------------------------------------------------------ files
    @classmethod
    def load(cls, path: str | Path) -> Rig:
        """Read a rig file."""
        path = Path(path)
        try:
            text = path.read_text(encoding="utf-8")
        except OSError as exc:
            raise RigError(f"cannot read the rig file {path}: {exc.strerror}") from None
        except UnicodeDecodeError as exc:
            line = exc.object[: exc.start].count(b"\n") + 1
            raise RigError(
                f"{path}:{line}: not UTF-8 text (byte 0x{exc.object[exc.start]:02X}); save the "
                "rig file as UTF-8"
            ) from None
        return cls.loads(text, path=path)

    @classmethod
    def loads(cls, text: str, *, path: str | Path | None = None) -> Rig:
        """Read rig YAML text; relative paths in options are relative to ``path``'s folder."""
        where = str(path or "<rig>")
        data, problems = read_yaml(text)  # (control characters, huge numbers, deep nesting)
        if problems:
            first = problems[0]
            line = "" if first.line is None else f":{first.line}"
            key = "" if first.key is None else f" {first.key}:"
            raise RigError(f"{where}{line}:{key} {first.reason}")
        if data is None:
            data = {}
        if not isinstance(data, dict):
            raise RigError(f"{where}: the rig must be a mapping with bus, devices and faults")
        unknown = set(data) - {"bus", "devices", "faults"}
        if unknown:
            raise RigError(
                f"{where}: unknown key(s) {', '.join(sorted(map(str, unknown)))}; a rig has "
                "bus, devices and faults"
            )
        base = Path(path).parent if path is not None else Path.cwd()
        bus = _bus_spec(data.get("bus", "embedded"), where)
        raw_devices = data.get("devices")
        if not isinstance(raw_devices, list) or not raw_devices:
            raise RigError(f"{where}: 'devices' must be a list of at least one device")
        devices = [
            _device_spec(d, f"{where}: devices[{i}]", base) for i, d in enumerate(raw_devices)
        ]
        raw_faults = data.get("faults") or []
        if not isinstance(raw_faults, list):
            raise RigError(f"{where}: 'faults' must be a list")
        faults = [_fault_spec(f, f"{where}: faults[{i}]") for i, f in enumerate(raw_faults)]
        return cls(devices, bus=bus, faults=faults, path=path)

    # ------------------------------------------------------------------ the bus
    def create_network(
        self,
        *,
        interface: str | None = None,
        channel: Any = None,
        bitrate: int | None = None,
    ) -> AsyncNetwork:
        """A network on the rig's bus (or the one named here), through a :class:`FaultyBus`
        so that bus faults can be injected. :meth:`close_bus` shuts the bus down after the
        network has disconnected (:meth:`running` does both)."""
        spec = self.bus_spec
        args: dict[str, Any] = dict(spec.options)
        if interface is not None or channel is not None:
            args.update(interface=interface, channel=channel)
        else:
            args.update(interface=spec.interface, channel=spec.channel)
        args["bitrate"] = bitrate if bitrate is not None else spec.bitrate
        inner = open_bus(**{k: v for k, v in args.items() if v is not None})
        self._opened = FaultyBus(inner)
        self._bitrate = args["bitrate"]
        return AsyncNetwork(self._opened)

    def close_bus(self) -> None:
        """Shut down the bus :meth:`create_network` opened."""
        if self._opened is not None:
            self._opened.shutdown()
            self._opened = None

    @property
    def bus(self) -> FaultyBus | None:
        """The faulty bus under the rig's network (None: bus faults are not available)."""
        network = self.network
        if network is None or not network.connected:
            return self._opened
        bus = network.bus
        return bus if isinstance(bus, FaultyBus) else None

    @contextlib.asynccontextmanager
    async def running(
        self,
        network: AsyncNetwork | None = None,
        *,
        interface: str | None = None,
        channel: Any = None,
        bitrate: int | None = None,
    ) -> AsyncIterator[AsyncNetwork]:
        """Run the rig for the ``async with`` block: on ``network``, or on a network of its own
        (:meth:`create_network`) that is closed at the end."""
        if network is not None:
            await self.start(network)
            try:
                yield network
            finally:
                await self.stop()
            return
        net = self.create_network(interface=interface, channel=channel, bitrate=bitrate)
        try:
            async with net:
                await self.start(net)
                try:
                    yield net
                finally:
                    await self.stop()
        finally:
            self.close_bus()

    # ------------------------------------------------------------------ running
    async def start(self, network: AsyncNetwork) -> None:
        """Create and power on every device on ``network`` (connected), then arm the faults."""
        if self.network is not None:
            raise RigError("the rig is running already: stop it first")
        where = str(self.path or "rig")
        classes = [resolve_kind(spec.kind) for spec in self.specs]  # all or nothing
        for i, fault in enumerate(self.fault_specs):
            if fault.node is not None:
                cls = classes[[s.node for s in self.specs].index(fault.node)]
                if fault.fault not in fault_catalogue(cls):
                    raise RigError(
                        f"{where}: faults[{i}]: {cls.kind} cannot inject {fault.fault!r}; it "
                        f"knows {', '.join(fault_catalogue(cls))}"
                    )
        self.network = network
        try:
            for i, (spec, cls) in enumerate(zip(self.specs, classes, strict=True)):
                here = f"{where}: devices[{i}] ({spec.kind})"
                if spec.node == UNCONFIGURED and not cls.LSS:
                    raise RigError(
                        f"{here}: a {cls.kind} has no LSS slave, so it cannot start "
                        "unconfigured; give it a node-ID"
                    )
                device = self._create(cls, spec, here)
                self.devices[spec.node if spec.node != UNCONFIGURED else 0x100 + i] = device
                device.start()
        except Exception:
            await self.stop()
            raise
        network.add_listener(self._on_network_event)
        self._traffic = _Traffic(network)
        loop = network.loop
        for fault in self.fault_specs:
            self._handles.append(loop.call_later(fault.at, self._scheduled, fault))

    def _create(self, cls: type[SimulatedDevice], spec: DeviceSpec, where: str) -> SimulatedDevice:
        assert self.network is not None
        kwargs: dict[str, Any] = dict(spec.options)
        if spec.name is not None:
            kwargs["name"] = spec.name
        if spec.quirks:
            kwargs["quirks"] = dict(spec.quirks)
        try:
            return cls(self.network, spec.node, **kwargs)
        except TypeError as exc:
            raise RigError(f"{where}: the options do not fit {cls.__name__}: {exc}") from None
        except SimulationError as exc:
            raise RigError(f"{where}: {exc}") from exc

    async def stop(self) -> None:
        """Power every device off for good and cancel the faults still to come."""
        for handle in self._handles:
            handle.cancel()
        self._handles.clear()
        if self._babbler is not None:
            self._babbler.stop()
            self._babbler = None
        for device in self.devices.values():
            try:
                device.close()
            except Exception:  # one device failing to close must not keep the others on
                log.exception("closing %s failed", device.name)
        self.devices.clear()
        network = self.network
        if network is not None:
            network.remove_listener(self._on_network_event)
            if self._traffic is not None:
                self._traffic.subscription.cancel()
                self._traffic = None
        self.network = None

    def _on_network_event(self, event: Event) -> None:
        if (
            isinstance(event, BusStateChanged)
            and event.old is BusState.BUS_OFF
            and event.new is not BusState.BUS_OFF
        ):
            for device in self.devices.values():
                if isinstance(device, CanopenSimDevice):
                    device.on_bus_recovered()

    def _scheduled(self, fault: FaultSpec) -> None:
        try:
            self.inject(fault.node, fault.fault, **fault.params)
        except Exception as exc:  # a scripted fault that fails is reported, the rig runs on
            log.error("scheduled fault %s failed: %s", fault.fault, exc)
            if self.network is not None:
                self.network.emit(HandlerFailed(f"rig fault {fault.fault}", repr(exc)))

    # ------------------------------------------------------------------ faults
    def device(self, node: int | str) -> SimulatedDevice:
        """The device with node-ID ``node`` now (or configured so), or the one named so."""
        for device in self.devices.values():
            if device.node_id == node or device.name == node:
                return device
        if isinstance(node, int) and node in self.devices:
            return self.devices[node]
        present = ", ".join(f"{d.node_id} ({d.name})" for d in self.devices.values()) or "none"
        raise RigError(f"the rig has no device {node!r}; it has {present}")

    def faults(self, node: int | str | None = None) -> dict[str, str]:
        """What can be injected: into the device ``node``, or (None) into the bus."""
        if node is None:
            return fault_catalogue()
        return fault_catalogue(self.device(node))

    def inject(self, node: int | str | None, fault: str, **params: Any) -> None:
        """Inject ``fault`` into device ``node`` (see :meth:`faults`), or into the bus when
        ``node`` is None (or names the node a babbling node pretends to be)."""
        if fault in BUS_FAULTS:
            self._bus_fault(node, fault, params)
            return
        if node is None:
            raise RigError(
                f"{fault!r} is no bus fault ({', '.join(BUS_FAULTS)}); name the device to inject "
                "it into"
            )
        device = self.device(node)
        check_fault_parameters(device, fault, params)
        device.inject(fault, **params)

    def _bus_fault(self, node: int | str | None, fault: str, params: Mapping[str, Any]) -> None:
        check_fault_parameters(None, fault, params)
        network = self.network
        if network is None:
            raise RigError("the rig is not running: start it before injecting faults")
        if fault in ("babbling", "babbling_stop"):
            if self._babbler is not None:
                self._babbler.stop()
                self._babbler = None
            if fault == "babbling":
                p = check_fault_params("bus", fault, params, {"cob_id": 0x001, "period_us": 200})
                self._babbler = Babbler(network, cob_id=p["cob_id"], period_us=p["period_us"])
                self._babbler.start()
                self._babbler_node = node if isinstance(node, int) else None
            else:
                check_fault_params("bus", fault, params, {})
            return
        bus = self.bus
        if bus is None:
            raise RigError(
                f"bus fault {fault!r} needs the rig's network on a FaultyBus: create it with "
                "rig.create_network() (or rig.running()), or wrap the bus in "
                "cobus.sim.FaultyBus yourself"
            )
        try:
            if fault == "bus_off":
                p = check_fault_params("bus", fault, params, {"duration": None})
                bus.bus_off()
                duration = p["duration"]
                if duration is not None:
                    if isinstance(duration, bool) or not isinstance(duration, int | float):
                        raise FaultParameterError(f"bus_off: duration {duration!r} is not seconds")
                    self._handles.append(network.loop.call_later(float(duration), bus.restart))
            elif fault == "bus_restart":
                check_fault_params("bus", fault, params, {})
                bus.restart()
            elif fault in ("frame_loss", "frame_corruption"):
                p = check_fault_params("bus", fault, params, {"rate": ..., "seed": None})
                if p["seed"] is not None:
                    bus.reseed(p["seed"])
                if fault == "frame_loss":
                    bus.loss = p["rate"]
                else:
                    bus.corruption = p["rate"]
        except FaultConfigError as exc:
            raise FaultParameterError(f"{fault}: {exc}") from None

    # ------------------------------------------------------------------ panel
    def status(self) -> list[dict[str, Any]]:
        """One row per device (its ``status()``), in the order of the rig file."""
        return [device.status() for device in self.devices.values()]

    def bus_status(self) -> dict[str, Any]:
        """The bus: state, traffic since the last call, the faults in effect."""
        network = self.network
        out: dict[str, Any] = {"state": "off" if network is None else network.bus_state.value}
        if self._traffic is not None:
            out.update(self._traffic.sample(self._bitrate))
        bus = self.bus
        if bus is not None:
            out.update(loss=bus.loss, corruption=bus.corruption, lost=bus.lost)
        if self._babbler is not None:
            out["babbling"] = f"{self._babbler.cob_id:03X}h every {self._babbler.period * 1e6:g} us"
        return out


# ---------------------------------------------------------------------- file parts
def _bus_spec(raw: Any, where: str) -> BusSpec:
    if raw is None or raw == "embedded":
        return BusSpec()
    if not isinstance(raw, dict):
        raise RigError(
            f"{where}: bus: write 'embedded' or a mapping with interface, channel and bitrate"
        )
    options = {str(k): v for k, v in raw.items() if k not in _BUS_KEYS}
    bitrate = raw.get("bitrate")
    if bitrate is not None and (not _is_int(bitrate) or bitrate <= 0):
        raise RigError(f"{where}: bus: bitrate {bitrate!r} must be bits per second, e.g. 500000")
    interface = raw.get("interface")
    if interface is not None and not isinstance(interface, str):
        raise RigError(f"{where}: bus: interface {interface!r} must be a python-can interface name")
    return BusSpec(interface, raw.get("channel"), bitrate, options)


def _device_spec(raw: Any, where: str, base: Path) -> DeviceSpec:
    if not isinstance(raw, dict):
        raise RigError(f"{where}: a device is a mapping with node and kind")
    unknown = set(raw) - _DEVICE_KEYS
    if unknown:
        raise RigError(
            f"{where}: unknown key(s) {', '.join(sorted(map(str, unknown)))}; a device has "
            f"{', '.join(sorted(_DEVICE_KEYS))} (device settings go under options)"
        )
    node = raw.get("node")
    if node == "unconfigured":
        node = UNCONFIGURED
    elif not isinstance(node, int) or isinstance(node, bool):
        raise RigError(f"{where}: node {node!r} must be a node-ID 1..127 or unconfigured")
    else:
        try:
            check_node_id(node)
        except ValueError as exc:
            raise RigError(f"{where}: {exc}") from None
    kind = raw.get("kind")
    if not isinstance(kind, str):
        raise RigError(f"{where}: kind {kind!r} must name a device kind ({', '.join(KINDS)})")
    if kind not in KINDS and ":" not in kind:
        raise RigError(
            f"{where}: kind {kind!r} is unknown; known kinds: {', '.join(sorted(KINDS))} "
            "(or 'module:Class')"
        )
    name = raw.get("name")
    if name is not None and not isinstance(name, str):
        raise RigError(f"{where}: name {name!r} must be text")
    options = raw.get("options") or {}
    quirks = raw.get("quirks") or {}
    if not isinstance(options, dict) or not all(isinstance(k, str) for k in options):
        raise RigError(f"{where}: options must be a mapping of option names to values")
    if not isinstance(quirks, dict) or not all(isinstance(v, bool) for v in quirks.values()):
        raise RigError(f"{where}: quirks must map quirk names to true or false")
    options = dict(options)
    if "serial" in raw:
        serial = raw["serial"]
        if not _is_int(serial) or not 0 <= serial < 1 << 32:
            raise RigError(f"{where}: serial {serial!r} must be a number 0..0xFFFFFFFF")
        options["serial"] = serial
    for key in _PATH_OPTIONS:
        value = options.get(key)
        if isinstance(value, str) and not Path(value).is_absolute():
            options[key] = str(base / value)
    return DeviceSpec(node, kind, name, options, dict(quirks))


def _fault_spec(raw: Any, where: str) -> FaultSpec:
    if not isinstance(raw, dict) or not isinstance(raw.get("fault"), str):
        raise RigError(f"{where}: a fault is a mapping with fault (and at, node, parameters)")
    at = raw.get("at", 0)
    if isinstance(at, bool) or not isinstance(at, int | float) or not 0 <= at < math.inf:
        raise RigError(f"{where}: at {at!r} must be seconds after the start (>= 0, finite)")
    node = raw.get("node")
    if node is not None and not _is_int(node):
        raise RigError(f"{where}: node {node!r} must be a node-ID (leave it out for a bus fault)")
    params = {str(k): v for k, v in raw.items() if k not in ("fault", "at", "node")}
    return FaultSpec(raw["fault"], node, float(at), params)
