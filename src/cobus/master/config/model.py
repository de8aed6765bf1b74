"""The network as the master runs it: :class:`NetworkConfig` (the master's settings and one
:class:`NodeConfig` per node, with its dictionary, PDO layouts, signals and start-up SDO
list) - what :func:`~cobus.master.config.load_network` makes of a network file.
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cobus._files import replace_file
from cobus.master.errors import (
    ConfigProblem,
    NodeNotFoundError,
    SignalValueError,
)
from cobus.od import (
    DataType,
    ObjectDictionary,
    encode,
)
from cobus.proto.pdo import (
    Kind,
    PdoMap,
)

__all__ = [
    "BIT_RATES",
    "ERROR_CONTROL",
    "EXTENDED",
    "IDENTITY_KEYS",
    "INVALID",
    "RESTORE",
    "SAVE",
    "MasterConfig",
    "NetworkConfig",
    "NodeConfig",
    "PdoLayout",
    "SdoEntry",
    "Signal",
]

#: The CiA 301 bit rates, in bit/s.
BIT_RATES = (10_000, 20_000, 50_000, 100_000, 125_000, 250_000, 500_000, 800_000, 1_000_000)
#: COB-ID bits of a PDO (CiA 301): not valid, 29-bit identifier.
INVALID = 1 << 31
EXTENDED = 1 << 29
#: Store and restore (1010h, 1011h) and the error control objects (guard time, life time
#: factor, producer heartbeat time): never in the start-up list from the dictionary.
SAVE, RESTORE = 0x1010, 0x1011
ERROR_CONTROL = (0x100C, 0x100D, 0x1017)
#: 1018h sub 1..4, as the network file names them.
IDENTITY_KEYS = ("vendor_id", "product_code", "revision_number", "serial_number")


@dataclass(frozen=True, slots=True)
class SdoEntry:
    """One write of the start-up list: object, encoded data, value and why it is written."""

    index: int
    subindex: int
    data: bytes
    value: Any
    name: str

    def __str__(self) -> str:
        shown = f"0x{self.value:X}" if isinstance(self.value, int) else repr(self.value)
        return f"0x{self.index:04X}:{self.subindex:02X} = {shown} ({self.name})"


@dataclass(frozen=True, slots=True)
class Signal:
    """A named value of the process image, carried by a PDO of a node."""

    name: str  # "node.signal"
    node_id: int
    direction: str  # "input" (from a TPDO of the node) or "output" (to one of its RPDOs)
    pdo: int
    position: int  # among the PDO's non-dummy values
    index: int
    subindex: int
    data_type: DataType
    bits: int
    kind: Kind
    scale: float | None = None
    offset: float = 0.0
    unit: str | None = None
    #: LowLimit / HighLimit of the object in the EDS (raw values), if any.
    low: float | None = None
    high: float | None = None

    def to_engineering(self, raw: Any) -> Any:
        """Value of the signal from the raw mapped value (``raw * scale + offset``)."""
        if self.scale is None:
            return raw + self.offset if self.offset and isinstance(raw, int | float) else raw
        return raw * self.scale + self.offset

    def to_raw(self, value: Any) -> Any:
        """The raw mapped value of an engineering value (rounded for integer objects)."""
        if self.scale is None and not self.offset:
            return value
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise SignalValueError(f"{self.name}: {value!r} is not a number")
        raw = (value - self.offset) / (self.scale if self.scale is not None else 1.0)
        if self.kind in (Kind.SIGNED, Kind.UNSIGNED):
            return round(raw)
        return raw

    @property
    def zero(self) -> Any:
        """What the signal reads while its node is faulty (inputs set to 0)."""
        if self.kind is Kind.BOOL:
            return False
        if self.kind is Kind.BYTES:
            return bytes(self.bits // 8)
        if self.kind in (Kind.REAL32, Kind.REAL64) or self.scale is not None:
            return 0.0
        return 0


@dataclass(frozen=True, slots=True, eq=False)
class PdoLayout:
    """A PDO as the master sees it: a TPDO of the node (master input) or an RPDO (output)."""

    direction: str  # "tpdo" or "rpdo" (the node's point of view)
    number: int
    cob_id: int
    extended: bool
    transmission_type: int
    event_timer: int  # ms
    inhibit_time: int  # 100 µs
    timeout: float | None  # s: presence supervision of a TPDO (None: not supervised)
    codec: PdoMap
    #: One per non-dummy mapped value: the signal, or None when another PDO exposes it.
    positions: tuple[Signal | None, ...]
    #: An RPDO fed by another node's TPDO (PDO linking): the master does not send it.
    linked: bool = False

    @property
    def signals(self) -> tuple[Signal, ...]:
        """The process image signals the PDO carries, in mapping order."""
        return tuple(s for s in self.positions if s is not None)

    @property
    def synchronous(self) -> bool:
        """Whether the PDO follows SYNC (transmission types 0..240)."""
        return self.transmission_type <= 240

    @property
    def length(self) -> int:
        """The number of data bytes of the PDO."""
        return self.codec.length


@dataclass
class MasterConfig:
    """The ``master`` section."""

    node_id: int | None = None
    bitrate: int = 500_000
    sync_period: float = 0.0  # s
    sync_cob_id: int = 0x80
    sync_overflow: int = 0
    sync_by_interface: bool = False  # the CAN interface times SYNC (SocketCAN: the kernel)
    heartbeat_time: int = 0  # ms
    time_period: float = 0.0  # s
    time_cob_id: int = 0x100
    reset: str = "node"
    start: str = "node"
    bootup_delay: float = 0.3  # s
    pdo_timeout_factor: float = 3.0
    bus_load_window: float = 0.25  # s

    @property
    def sync_period_us(self) -> int:
        """The SYNC period in microseconds (1006h)."""
        return round(self.sync_period * 1e6)


@dataclass
class NodeConfig:
    """One node of the network: the ``nodes`` entry and everything derived from its EDS."""

    name: str
    node_id: int
    eds_path: Path
    od: ObjectDictionary
    bitrate: int = 500_000
    enabled: bool = True
    mandatory: bool = False
    do_not_initialise: bool = False
    #: False: the node has no CiA 301 SDO server; the master sends it no SDO (see the module).
    sdo_server: bool = True
    auto_start: bool = True
    device_type: int = 0
    device_type_low16: bool = False
    vendor_id: int = 0
    product_code: int = 0
    revision_number: int = 0
    serial_number: int = 0
    #: The master gives the device with this identity (1018h sub 1..4, the LSS address) its
    #: node-ID by LSS (CiA 305) before the node's boot; ``lss_store``: and the device
    #: stores it (so it boots with it by itself at its next power-on).
    lss: bool = False
    lss_store: bool = False
    heartbeat_time: int = 0  # ms, the node's producer time (1017h)
    guard_time: int = 0  # ms (100Ch)
    life_time_factor: int = 0  # (100Dh)
    consumer_factor: float = 1.5
    watch_master: bool = False
    sdo_timeout: float = 1.0  # s
    sdo_retries: int = 2
    boot_timeout: float = 2.0  # s
    restore_defaults: bool = False
    sdo_from_dcf: bool = True
    sdo_all_pdo: bool = False
    stop_on_abort: bool = False
    set_sync_period: bool = True
    error_reaction: str = "none"  # none | stop_node | stop_all
    #: auto: a node back after an error-control fault, re-booted, or put out of the state
    #: the master expects by someone else is brought back; manual: it waits for
    #: ``master.restart(node)``.
    restart: str = "auto"  # auto | manual
    zero_inputs: bool = True
    #: The start-up SDO list (without the error control writes, see below).
    startup: list[SdoEntry] = field(default_factory=list)
    tpdos: list[PdoLayout] = field(default_factory=list)
    rpdos: list[PdoLayout] = field(default_factory=list)
    #: Alias -> canonical signal name (both find the signal).
    aliases: dict[str, str] = field(default_factory=dict)

    @property
    def identity(self) -> tuple[int, int, int, int]:
        """Expected 1018h sub 1..4 (0: not checked)."""
        return (self.vendor_id, self.product_code, self.revision_number, self.serial_number)

    @property
    def error_control(self) -> str | None:
        """``"heartbeat"``, ``"guarding"`` or None (the node is not supervised)."""
        if self.heartbeat_time:
            return "heartbeat"
        if self.guard_time:
            return "guarding"
        return None

    @property
    def heartbeat_consumer_time(self) -> float:
        """Seconds without heartbeat before the node counts as lost."""
        return self.heartbeat_time * self.consumer_factor / 1000.0

    @property
    def fallback_guarding(self) -> tuple[int, int]:
        """Guard time (ms) and life time factor used when the node refuses heartbeat."""
        return (self.guard_time or self.heartbeat_time, self.life_time_factor or 3)

    def error_control_entries(self, kind: str | None = None) -> list[SdoEntry]:
        """The writes that set up ``kind`` (default: the configured error control)."""
        kind = kind or self.error_control
        if kind == "heartbeat":
            return [_entry(self.od, 0x1017, 0, self.heartbeat_time, "producer heartbeat time")]
        if kind == "guarding":
            guard, factor = (
                (self.guard_time, self.life_time_factor or 3)
                if self.guard_time
                else self.fallback_guarding
            )
            return [
                _entry(self.od, 0x100C, 0, guard, "guard time"),
                _entry(self.od, 0x100D, 0, factor, "life time factor"),
            ]
        return []

    def concise_dcf(self) -> bytes:
        """The CiA 302 concise DCF (the format of 1F22h) of what the master downloads:
        count U32, then per entry index U16, sub-index U8, size U32 and the data."""
        entries = [*self.startup, *self.error_control_entries()]
        out = [struct.pack("<I", len(entries))]
        for e in entries:
            out.append(struct.pack("<HBI", e.index, e.subindex, len(e.data)))
            out.append(e.data)
        return b"".join(out)

    def to_dcf(self) -> str:
        """The node's DCF: its EDS with every configured value as ParameterValue."""
        return self.od.to_dcf(self.node_id, self.bitrate)


_FIXED_TYPES = {
    0x1017: DataType.UNSIGNED16,
    0x100C: DataType.UNSIGNED16,
    0x100D: DataType.UNSIGNED8,
}


def _entry(od: ObjectDictionary, index: int, sub: int, value: Any, name: str) -> SdoEntry:
    var = od.get_variable(index, sub)
    data = var.encode(value) if var is not None else encode(_FIXED_TYPES[index], value)
    return SdoEntry(index, sub, data, value, name)


@dataclass
class NetworkConfig:
    """A whole network: the master's settings and the nodes by node-ID (file order)."""

    path: str
    master: MasterConfig
    nodes: dict[int, NodeConfig]
    #: Warnings found while reading (errors raise :class:`NetworkConfigError`).
    warnings: list[ConfigProblem] = field(default_factory=list)

    def node(self, key: int | str) -> NodeConfig:
        """A node by node-ID or name."""
        if isinstance(key, int):
            found = self.nodes.get(key)
        else:
            found = next((n for n in self.nodes.values() if n.name == key), None)
        if found is None:
            names = ", ".join(f"{n.name} ({n.node_id})" for n in self.nodes.values())
            raise NodeNotFoundError(f"no node {key!r} in {self.path}; the nodes are: {names}")
        return found

    @property
    def signals(self) -> dict[str, Signal]:
        """Every signal of the process image by full name (inputs and outputs)."""
        out: dict[str, Signal] = {}
        for node in self.nodes.values():
            for layout in (*node.tpdos, *node.rpdos):
                for sig in layout.signals:
                    out.setdefault(sig.name, sig)
        return out

    def dcf_files(self, outdir: str | os.PathLike[str]) -> list[Path]:
        """The files :meth:`write_dcfs` writes into ``outdir``."""
        target = Path(outdir)
        return [target / f"{n.name}{ext}" for n in self.nodes.values() for ext in (".dcf", ".bin")]

    def write_dcfs(self, outdir: str | os.PathLike[str]) -> list[Path]:
        """Write ``<node>.dcf`` and the concise ``<node>.bin`` of every node into ``outdir``,
        each whole or not at all; a symbolic link there is replaced, never written through."""
        target = Path(outdir)
        target.mkdir(parents=True, exist_ok=True)
        written: list[Path] = []
        for node in self.nodes.values():
            dcf = target / f"{node.name}.dcf"
            replace_file(dcf, node.to_dcf().replace("\n", "\r\n").encode("utf-8"))
            concise = target / f"{node.name}.bin"
            replace_file(concise, node.concise_dcf())
            written += [dcf, concise]
        return written
