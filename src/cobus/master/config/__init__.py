"""The network description: a YAML file in the spirit of ROS 2 canopen's ``bus.yml``.

```yaml
master:
  node_id: 1               # optional: without it the master sends no heartbeat
  bitrate: 500000          # bit/s
  sync_period: 10          # ms (0: no SYNC); sync_cob_id: 0x80, sync_overflow: 0
  sync_by_interface: false # true: the CAN interface times SYNC (SocketCAN: the kernel;
                           # a simulated network's loop does)
  heartbeat_time: 100      # ms: the master's own heartbeat (needs node_id)
  reset: node              # node | broadcast (one 81h 00 for every node)
  start: node              # node | broadcast (one 01h 00 once every node is configured)
defaults:                  # keys every node takes unless it sets them itself
  heartbeat_time: 100
nodes:
  drive1:
    node_id: 2
    eds: drives/e35.eds    # EDS or DCF, relative to this file (key ``dcf`` works too)
    mandatory: true
    device_type: 0x20192
    tpdo1: {mapping: [statusword, position_actual_value], transmission_type: 1}
    rpdo1: {mapping: [controlword, "0x607A:00"], transmission_type: 255}
    signals:
      position: {object: position_actual_value, scale: 0.001, unit: mm}
```

Times are milliseconds, as plain numbers or as text with a unit (``"1.5 s"``, ``"500 us"``);
``inhibit_time`` is in 100 µs units, as in the dictionary. Objects are named as the node's
EDS names them (case, spaces and punctuation do not matter: ``"Position actual value"`` =
``position_actual_value``), as ``record.sub_name``, ``record[sub]``, or by address
``"0x6041:00"`` (sub-index in hex). :func:`load_network` reads and checks a file;
:func:`check_network` lists every problem with file, line, node and key.

The start-up SDO list of each node is derived from its dictionary: every writable object
whose configured value (DCF ParameterValue, or what this file sets) differs from the EDS
default, the PDOs as the mapping procedure of CiA 301 wants them (disable, clear, map, count,
enable), then the explicit ``sdo`` entries. :meth:`NodeConfig.to_dcf` writes the node's DCF
and :meth:`NodeConfig.concise_dcf` the CiA 302 concise DCF of what the master downloads.
A device whose mapping sub-index 0 is a read-only constant while its entries are writable
(direct mapping, e.g. the STÖBER MDS 5000 of seed 004) gets every entry written instead, 0 for
the unused ones; the master skips those when it reads the mapping.

Devices that are only "based on CANopen" (the EC motor of seed 002: an SDO dialect of its own,
no boot-up, no error control) take ``do_not_initialise: true`` with ``sdo_server: false``: the
master then sends the node no SDO at all (no 1000h/1018h check, no start-up list), counts it
present, and started once it sent the NMT start, and runs its PDOs. An RPDO given an empty
mapping (``rpdo1: {mapping: []}``) is sent with no data (DLC 0), a trigger such a device may
answer, e.g. the EC motor's status poll: a synchronous one with every SYNC, an event-driven
one at the start and with its event timer.
"""

from __future__ import annotations

import os
import re
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any

from cobus._yaml import line_of, read_yaml
from cobus.master.config.model import (
    BIT_RATES,
    EXTENDED,
    IDENTITY_KEYS,
    INVALID,
    RESTORE,
    MasterConfig,
    NetworkConfig,
    NodeConfig,
    PdoLayout,
    SdoEntry,
    Signal,
)
from cobus.master.config.names import (
    DUMMY,
    DUMMY_TYPES,
    ObjectIndex,
    dropped_value,
    mapped_kind,
    normalise,
)
from cobus.master.config.startup import direct_mapping, startup_list, sub_value
from cobus.master.config.values import (
    BadValue,
    Report,
    as_bool,
    as_choice,
    as_int,
    as_mapping,
    as_ms,
    as_number,
    as_whole_ms,
    suggest,
)
from cobus.master.errors import (
    ConfigProblem,
    NetworkConfigError,
    Severity,
)
from cobus.od import (
    Array,
    DataType,
    EdsError,
    ObjectDictionary,
    Record,
    Variable,
    loads,
    mapping_entries,
)
from cobus.proto.pdo import (
    Kind,
    MappingEntry,
    PdoCobId,
    PdoError,
    PdoMap,
    TransmissionType,
    is_restricted_can_id,
)

__all__ = [
    "BIT_RATES",
    "MasterConfig",
    "NetworkConfig",
    "NodeConfig",
    "ObjectIndex",
    "PdoLayout",
    "SdoEntry",
    "Signal",
    "check_network",
    "load_network",
    "loads_network",
    "normalise",
    "parse_network",
]


# ------------------------------------------------------------------------------- parsing

_TOP_KEYS = ("master", "defaults", "nodes")
_MASTER_KEYS = (
    "node_id",
    "bitrate",
    "sync_period",
    "sync_cob_id",
    "sync_overflow",
    "sync_by_interface",
    "heartbeat_time",
    "time_period",
    "time_cob_id",
    "reset",
    "start",
    "bootup_delay",
    "pdo_timeout_factor",
    "bus_load_window",
)
_NODE_KEYS = (
    "node_id",
    "eds",
    "dcf",
    "enabled",
    "mandatory",
    "do_not_initialise",
    "sdo_server",
    "auto_start",
    "device_type",
    "device_type_low16",
    "vendor_id",
    "product_code",
    "revision_number",
    "serial_number",
    "heartbeat_time",
    "guard_time",
    "life_time_factor",
    "consumer_factor",
    "watch_master",
    "sdo_timeout",
    "sdo_retries",
    "boot_timeout",
    "restore_defaults",
    "sdo_from_dcf",
    "sdo_all_pdo",
    "sdo",
    "stop_on_abort",
    "set_sync_period",
    "error_reaction",
    "restart",
    "zero_inputs",
    "signals",
)
_NOT_DEFAULTABLE = ("node_id", "eds", "dcf", "sdo", "signals")
_PDO_KEY = re.compile(r"([tr])pdo([0-9]+)\Z")
_PDO_FIELDS = (
    "enabled",
    "cob_id",
    "transmission_type",
    "event_timer",
    "inhibit_time",
    "sync_start",
    "mapping",
    "timeout",
)
_NODE_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_-]*\Z")
_ALIAS = re.compile(r"[A-Za-z_][A-Za-z0-9_.\[\]]*\Z")
_U32 = 0xFFFFFFFF


class _NodeReader:
    """Reads one node entry into a :class:`NodeConfig`, reporting every problem."""

    def __init__(
        self,
        name: str,
        raw: Mapping[Any, Any],
        defaults: Mapping[Any, Any],
        master: MasterConfig,
        base_dir: Path,
        report: Report,
        texts: dict[Path, str],
    ) -> None:
        self.name = name
        self.raw = raw
        self.defaults = defaults
        self.master = master
        self.base_dir = base_dir
        self.report = report
        self.texts = texts
        self.yaml_set: set[tuple[int, int]] = set()
        self.explicit: list[SdoEntry] = []
        self.yaml_pdos: set[tuple[str, int]] = set()
        #: RPDOs the network file maps with nothing ("rpdo3"): sent with DLC 0.
        self.empty_rpdos: set[str] = set()

    # --- helpers
    def error(self, key: str | None, reason: str, container: Any = None, at: Any = None) -> None:
        where = container if container is not None else self.raw
        line = line_of(where, at if at is not None else key)
        self.report.error(self.name, key, reason, line)

    def warning(self, key: str | None, reason: str, container: Any = None, at: Any = None) -> None:
        where = container if container is not None else self.raw
        line = line_of(where, at if at is not None else key)
        self.report.warning(self.name, key, reason, line)

    def value(self, key: str) -> tuple[bool, Any, Any]:
        """(given, value, container) of ``key`` from the node, else from ``defaults``."""
        if key in self.raw:
            return True, self.raw[key], self.raw
        if key in self.defaults and key not in _NOT_DEFAULTABLE:
            return True, self.defaults[key], self.defaults
        return False, None, None

    def get(self, key: str, parse: Any, default: Any) -> Any:
        given, value, where = self.value(key)
        if not given:
            return default
        try:
            return parse(value)
        except BadValue as exc:
            self.error(key, str(exc), where)
            return default

    # --- the node
    def read(self, node_ids: dict[int, str]) -> NodeConfig | None:
        raw = self.raw
        for key in raw:
            skey = str(key)
            if skey not in _NODE_KEYS and not _PDO_KEY.match(skey):
                self.error(skey, f"unknown key{suggest(skey, _NODE_KEYS)}")
        if "node_id" not in raw:
            self.error("node_id", "missing: give the node-ID (1..127)", raw, None)
            return None
        try:
            node_id = as_int(raw["node_id"], 1, 127, "node-ID")
        except BadValue as exc:
            self.error("node_id", str(exc))
            return None
        if node_id in node_ids:
            self.error("node_id", f"node-ID {node_id} is used by node {node_ids[node_id]!r} too")
            return None
        node_ids[node_id] = self.name
        if self.master.node_id == node_id:
            self.error("node_id", f"node-ID {node_id} is the master's own node-ID")
        od, path = self._dictionary(node_id)
        if od is None or path is None:
            return None
        cfg = NodeConfig(self.name, node_id, path, od, bitrate=self.master.bitrate)
        self._scalars(cfg)
        self._pdos(cfg)
        self._explicit_sdo(cfg)
        self._error_control(cfg)
        self._sync(cfg)
        cfg.startup = startup_list(cfg, self.yaml_set, self.explicit, self._unwritable)
        cfg.tpdos = self._layouts(cfg, transmit=True)
        cfg.rpdos = self._layouts(cfg, transmit=False)
        self._signals(cfg)
        # (a node without error control whose TPDO the master supervises is watched all the
        # same: a missing TPDO tells it failed, as with the ZAPI inverter of the thesis)
        watched = any(layout.timeout for layout in cfg.tpdos)
        if cfg.error_control is None and cfg.enabled and not watched:
            self.warning(
                None,
                "neither heartbeat_time nor guard_time, nor a supervised TPDO: the master "
                "cannot tell when this node fails",
                raw,
                "node_id",
            )
        return cfg

    def _unwritable(self, var: Variable, value: Any, exc: Exception, fatal: bool) -> None:
        key = "eds" if "eds" in self.raw else "dcf"
        where = f"line {var.line} of " if var.line is not None else ""
        file = Path(self.raw_path()).name
        ident = f"0x{var.index:04X}:{var.subindex:02X} ({var.name})"
        if fatal:
            self.error(
                key,
                f"{ident} would be written {value!r}, which it cannot hold: {exc}; correct "
                f"the value ({where}{file})",
            )
        else:
            self.warning(
                key,
                f"{ident} is configured as {value!r}, outside its limits in the EDS ({exc}); "
                f"it is written as configured ({where}{file})",
            )

    def _dictionary(self, node_id: int) -> tuple[ObjectDictionary | None, Path | None]:
        keys = [k for k in ("eds", "dcf") if k in self.raw]
        if len(keys) != 1:
            reason = (
                "give the node's EDS or DCF file (eds: path relative to the network file)"
                if not keys
                else "give either eds or dcf, not both"
            )
            self.error(keys[-1] if keys else "eds", reason, self.raw, keys[-1] if keys else None)
            return None, None
        key = keys[0]
        value = self.raw[key]
        if not isinstance(value, str) or not value.strip():
            self.error(key, f"{value!r} is not a file path")
            return None, None
        path = (self.base_dir / value).resolve()
        text = self.texts.get(path)
        if text is None:
            try:
                data = path.read_bytes()
            except OSError as exc:
                self.error(key, f"cannot read {path}: {exc.strerror}")
                return None, None
            try:
                text = data.decode("utf-8")
            except UnicodeDecodeError:
                text = data.decode("latin-1")
            self.texts[path] = text
        try:
            od = loads(text, node_id, path=str(path))
        except EdsError as exc:
            self.error(key, f"the file cannot be read: {exc}")
            return None, None
        od.path = str(path)
        if not len(od):
            self.error(key, f"{path.name} is not an EDS or DCF: it defines no objects")
            return None, None
        lost = [f for f in od.errors if dropped_value(od, f)]
        for finding in lost:
            # a configured value the reader had to drop: the node would not get it
            self.error(key, f"{finding}; the master cannot write it: correct the value")
        others = [f for f in od.errors if f not in lost]
        if others:
            self.warning(
                key,
                f"{path.name} has {len(others)} error(s) (`cobus eds check {path}` lists "
                f"them); first: {others[0].reason}",
            )
        return od, path

    def _scalars(self, cfg: NodeConfig) -> None:
        g = self.get
        cfg.enabled = g("enabled", as_bool, True)
        cfg.mandatory = g("mandatory", as_bool, False)
        cfg.do_not_initialise = g("do_not_initialise", as_bool, False)
        cfg.sdo_server = g("sdo_server", as_bool, True)
        cfg.auto_start = g("auto_start", as_bool, True)
        cfg.device_type = g("device_type", lambda v: as_int(v, 0, _U32, "device type"), 0)
        cfg.device_type_low16 = g("device_type_low16", as_bool, False)
        for key in IDENTITY_KEYS:
            setattr(cfg, key, g(key, lambda v: as_int(v, 0, _U32, "1018h value"), 0))
        cfg.heartbeat_time = g("heartbeat_time", as_whole_ms, 0)
        cfg.guard_time = g("guard_time", as_whole_ms, 0)
        cfg.life_time_factor = g("life_time_factor", lambda v: as_int(v, 0, 255, "factor"), 0)
        cfg.consumer_factor = g("consumer_factor", lambda v: as_number(v, 1.0, 100.0), 1.5)
        cfg.watch_master = g("watch_master", as_bool, False)
        cfg.sdo_timeout = g("sdo_timeout", lambda v: as_ms(v, 600_000), 1000.0) / 1000.0
        if cfg.sdo_timeout <= 0:
            self.error("sdo_timeout", "must be above 0 ms")
            cfg.sdo_timeout = 1.0
        cfg.sdo_retries = g("sdo_retries", lambda v: as_int(v, 0, 100, "retry count"), 2)
        cfg.boot_timeout = g("boot_timeout", lambda v: as_ms(v, 3_600_000), 2000.0) / 1000.0
        cfg.restore_defaults = g("restore_defaults", as_bool, False)
        cfg.sdo_from_dcf = g("sdo_from_dcf", as_bool, True)
        cfg.sdo_all_pdo = g("sdo_all_pdo", as_bool, False)
        cfg.stop_on_abort = g("stop_on_abort", as_bool, False)
        cfg.set_sync_period = g("set_sync_period", as_bool, True)
        cfg.error_reaction = g(
            "error_reaction", lambda v: as_choice(v, ("none", "stop_node", "stop_all")), "none"
        )
        cfg.restart = g("restart", lambda v: as_choice(v, ("auto", "manual")), "auto")
        cfg.zero_inputs = g("zero_inputs", as_bool, True)
        if cfg.restore_defaults and cfg.od.get(RESTORE) is None:
            self.error("restore_defaults", f"{cfg.eds_path.name} has no 1011h to restore from")
        if cfg.do_not_initialise and cfg.restore_defaults:
            self.error("restore_defaults", "a node that is not initialised cannot be restored")
        if not cfg.sdo_server:
            if not cfg.do_not_initialise:
                self.error(
                    "sdo_server",
                    "the master configures a node by SDO: a node without an SDO server needs "
                    "do_not_initialise: true",
                )
            checks = [k for k in ("device_type", *IDENTITY_KEYS) if getattr(cfg, k)]
            if checks:
                self.error(
                    "sdo_server",
                    f"{', '.join(checks)} would be checked by SDO reads (1000h, 1018h), which a "
                    "node without an SDO server cannot answer: leave them out",
                )

    # --- values set in the dictionary
    def set_value(self, var: Variable, value: Any, key: str, where: Any, at: Any) -> bool:
        """Set ``var``'s ParameterValue (checked); False after reporting a problem."""
        if value == var.value:
            self.yaml_set.add((var.index, var.subindex))
            return True
        if not var.writable:
            self.error(
                key,
                f"0x{var.index:04X}:{var.subindex:02X} ({var.name}) is {var.access} in "
                f"{Path(self.raw_path()).name}: it cannot be configured",
                where,
                at,
            )
            return False
        try:
            var.parameter_value = value
        except Exception as exc:  # the od's typed errors say what does not fit
            self.error(key, f"0x{var.index:04X}:{var.subindex:02X}: {exc}", where, at)
            return False
        self.yaml_set.add((var.index, var.subindex))
        return True

    def raw_path(self) -> str:
        value = self.raw.get("eds", self.raw.get("dcf", ""))
        return str(value)

    # --- PDOs
    def _pdos(self, cfg: NodeConfig) -> None:
        for key in self.raw:
            match = _PDO_KEY.match(str(key))
            if match is None:
                continue
            tx = match.group(1) == "t"
            number = int(match.group(2))
            self._pdo(cfg, str(key), tx, number, self.raw[key])

    def _pdo(self, cfg: NodeConfig, key: str, tx: bool, number: int, raw: Any) -> None:
        kind = "TPDO" if tx else "RPDO"
        try:
            spec = as_mapping(raw, key)
        except BadValue as exc:
            self.error(key, str(exc))
            return
        if not 1 <= number <= 512:
            self.error(key, f"{kind} numbers run 1..512, not {number}")
            return
        od = cfg.od
        comm_index = (0x1800 if tx else 0x1400) + number - 1
        map_index = (0x1A00 if tx else 0x1600) + number - 1
        comm = od.get(comm_index)
        mapping = od.get(map_index)
        if not isinstance(comm, Record | Array) or not isinstance(mapping, Record | Array):
            self.error(
                key,
                f"{cfg.eds_path.name} has no {kind} {number} (objects 0x{comm_index:04X} and "
                f"0x{map_index:04X})",
            )
            return
        self.yaml_pdos.add(("tpdo" if tx else "rpdo", number))
        for field_key in spec:
            if field_key not in _PDO_FIELDS or (field_key == "timeout" and not tx):
                fields = [f for f in _PDO_FIELDS if tx or f != "timeout"]
                self.error(
                    f"{key}.{field_key}",
                    f"unknown PDO setting{suggest(str(field_key), fields)}",
                    spec,
                    field_key,
                )
        if "timeout" in spec:
            try:
                as_ms(spec["timeout"], 0xFFFF)
            except BadValue as exc:
                self.error(f"{key}.timeout", str(exc), spec, "timeout")
        enabled = True
        if "enabled" in spec:
            try:
                enabled = as_bool(spec["enabled"])
            except BadValue as exc:
                self.error(f"{key}.enabled", str(exc), spec, "enabled")
        cob_var = comm.get(1)
        if cob_var is None or not isinstance(cob_var.value, int):
            self.error(key, f"0x{comm_index:04X} has no COB-ID (sub-index 1) with a value")
            return
        current = cob_var.value
        if "cob_id" in spec:
            try:
                cob = as_int(spec["cob_id"], 1, 0x1FFFFFFF | EXTENDED, "COB-ID")
            except BadValue as exc:
                self.error(f"{key}.cob_id", str(exc), spec, "cob_id")
                return
        else:
            cob = current & ~INVALID
        if enabled:
            try:
                parsed = PdoCobId.from_u32(cob & ~INVALID)
            except PdoError as exc:
                self.error(f"{key}.cob_id", str(exc), spec, "cob_id")
                return
            if parsed.can_id == 0 or (not parsed.extended and is_restricted_can_id(parsed.can_id)):
                self.error(
                    f"{key}.cob_id",
                    f"identifier 0x{parsed.can_id:X} is restricted by CiA 301 (NMT, SYNC, EMCY, "
                    "SDO, error control) or unset: give a free cob_id",
                    spec,
                    "cob_id" if "cob_id" in spec else None,
                )
                return
            cob &= ~INVALID
        else:
            cob |= INVALID
        self.set_value(cob_var, cob, f"{key}.cob_id", spec, "cob_id" if "cob_id" in spec else None)
        for field_key, sub, check in (
            ("transmission_type", 2, None),
            ("inhibit_time", 3, (0, 0xFFFF)),
            ("event_timer", 5, None),
            ("sync_start", 6, (0, 240)),
        ):
            if field_key not in spec:
                continue
            label = f"{key}.{field_key}"
            var = comm.get(sub)
            if var is None:
                self.error(label, f"0x{comm_index:04X} has no sub-index {sub}", spec, field_key)
                continue
            if field_key == "sync_start" and not tx:
                self.error(label, "RPDOs have no SYNC start value", spec, field_key)
                continue
            try:
                if field_key == "transmission_type":
                    tt = TransmissionType(as_int(spec[field_key], 0, 255, "transmission type"))
                    if not tx and not tt.valid_for_rpdo:
                        raise BadValue(
                            f"{tt.value} is for TPDOs only (RPDOs take 0..240, 254, 255)"
                        )
                    value = tt.value
                elif field_key == "event_timer":
                    value = as_whole_ms(spec[field_key])
                else:
                    assert check is not None
                    value = as_int(spec[field_key], check[0], check[1], field_key.replace("_", " "))
            except (BadValue, PdoError) as exc:
                self.error(label, str(exc), spec, field_key)
                continue
            self.set_value(var, value, label, spec, field_key)
        if "mapping" in spec:
            self._mapping(cfg, key, tx, mapping, spec)

    def _mapping(
        self, cfg: NodeConfig, key: str, tx: bool, mapping: Record | Array, spec: Mapping[Any, Any]
    ) -> None:
        items = spec["mapping"]
        label = f"{key}.mapping"
        if not isinstance(items, list):
            self.error(label, "give a list of object names or addresses", spec, "mapping")
            return
        if not items and not tx:
            self.empty_rpdos.add(key)
        index = ObjectIndex(cfg.od, cfg.eds_path.name)
        values: list[int] = []
        bits_total = 0
        ok = True
        for pos, item in enumerate(items):
            where = f"{label}[{pos}]"
            if isinstance(item, str) and (dummy := DUMMY.match(item.lower())):
                bits = int(dummy.group(1))
                values.append(DUMMY_TYPES[bits] << 16 | bits)
                bits_total += bits
                continue
            try:
                var = index.resolve(item)
            except BadValue as exc:
                self.error(where, str(exc), items, pos)
                ok = False
                continue
            ident = f"0x{var.index:04X}:{var.subindex:02X} ({var.name})"
            length = var.bit_length
            if length is None:
                self.error(where, f"{ident} is {var.data_type.name}: no fixed length", items, pos)
                ok = False
                continue
            if not var.pdo_mappable:
                self.error(where, f"{ident} is not PDO-mappable in the EDS", items, pos)
                ok = False
                continue
            if tx and not var.readable:
                self.error(where, f"{ident} is write-only: it cannot go in a TPDO", items, pos)
                ok = False
                continue
            if not tx and not var.writable:
                self.error(where, f"{ident} is {var.access}: it cannot go in an RPDO", items, pos)
                ok = False
                continue
            values.append(var.index << 16 | var.subindex << 8 | length)
            bits_total += length
        slots = max((s for s in mapping.subindices if s), default=0)
        if len(values) > slots:
            self.error(
                label,
                f"{len(values)} entries but 0x{mapping.index:04X} has {slots} mapping entries",
                spec,
                "mapping",
            )
            return
        if bits_total > 64:
            self.error(
                label, f"the mapping takes {bits_total} bits; a PDO carries 64", spec, "mapping"
            )
            return
        if not ok:
            return
        count_var = mapping.get(0)
        if count_var is None:
            self.error(label, f"0x{mapping.index:04X} has no sub-index 0", spec, "mapping")
            return
        if direct_mapping(mapping):
            values += [0] * (slots - len(values))  # direct mapping: 0 = an unused entry
        else:
            self.set_value(count_var, len(values), label, spec, "mapping")
        for sub, value in enumerate(values, 1):
            slot = mapping.get(sub)
            if slot is None:
                self.error(label, f"0x{mapping.index:04X} has no sub-index {sub}", spec, "mapping")
                return
            self.set_value(slot, value, label, spec, "mapping")

    # --- explicit SDO writes
    def _explicit_sdo(self, cfg: NodeConfig) -> None:
        if "sdo" not in self.raw:
            return
        items = self.raw["sdo"]
        if not isinstance(items, list):
            self.error("sdo", "give a list of {object: ..., value: ...} entries")
            return
        index = ObjectIndex(cfg.od, cfg.eds_path.name)
        for pos, item in enumerate(items):
            label = f"sdo[{pos}]"
            if not isinstance(item, Mapping) or "value" not in item or "object" not in item:
                self.error(label, "each entry needs object (name or address) and value", items, pos)
                continue
            for extra in item:
                if extra not in ("object", "value"):
                    self.error(
                        f"{label}.{extra}", "unknown key (use object and value)", item, extra
                    )
            try:
                var = index.resolve(item["object"])
            except BadValue as exc:
                self.error(f"{label}.object", str(exc), item, "object")
                continue
            value = item["value"]
            if var.data_type in (DataType.OCTET_STRING, DataType.DOMAIN) and isinstance(value, str):
                try:
                    value = bytes.fromhex(value)
                except ValueError:
                    self.error(f"{label}.value", f"{value!r} is not hex bytes", item, "value")
                    continue
            if not var.writable:
                self.error(
                    f"{label}.object",
                    f"0x{var.index:04X}:{var.subindex:02X} ({var.name}) is {var.access}",
                    item,
                    "object",
                )
                continue
            try:
                data = var.encode(value)
                var.parameter_value = value
            except Exception as exc:  # the od's typed errors say what does not fit
                self.error(f"{label}.value", str(exc), item, "value")
                continue
            self.explicit.append(SdoEntry(var.index, var.subindex, data, value, var.name))

    # --- heartbeat / guarding and SYNC, as values of the DCF
    def _error_control(self, cfg: NodeConfig) -> None:
        od = cfg.od
        given_hb = self.value("heartbeat_time")[0]
        given_guard = self.value("guard_time")[0]
        if not given_hb and not given_guard:
            # none in the network file: take what the DCF configures
            hb = od.get_variable(0x1017, 0)
            guard = od.get_variable(0x100C, 0)
            factor = od.get_variable(0x100D, 0)
            if hb is not None and isinstance(hb.parameter_value, int) and hb.parameter_value:
                cfg.heartbeat_time = hb.parameter_value
            elif (
                guard is not None
                and isinstance(guard.parameter_value, int)
                and guard.parameter_value
            ):
                cfg.guard_time = guard.parameter_value
                if factor is not None and isinstance(factor.value, int):
                    cfg.life_time_factor = cfg.life_time_factor or factor.value
        if cfg.heartbeat_time and od.get_variable(0x1017, 0) is None:
            self.warning(
                "heartbeat_time",
                f"{cfg.eds_path.name} has no 1017h: the master will fall back to node guarding",
            )
        for index, value in (
            (0x1017, cfg.heartbeat_time),
            (0x100C, cfg.guard_time),
            (0x100D, cfg.life_time_factor if cfg.guard_time else 0),
        ):
            var = od.get_variable(index, 0)
            if var is not None and value:
                try:
                    var.parameter_value = value
                except Exception as exc:  # the od's typed errors say what does not fit
                    self.error(None, f"0x{index:04X}: {exc}")
        if cfg.watch_master:
            self._watch_master(cfg)

    def _watch_master(self, cfg: NodeConfig) -> None:
        master = self.master
        if master.node_id is None or not master.heartbeat_time:
            self.error(
                "watch_master",
                "the master needs node_id and heartbeat_time for a node to watch it",
            )
            return
        var = cfg.od.get_variable(0x1016, 1)
        if var is None or not var.writable:
            self.error("watch_master", f"{cfg.eds_path.name} has no writable 1016h sub 1")
            return
        ms = min(round(master.heartbeat_time * cfg.consumer_factor), 0xFFFF)
        value = master.node_id << 16 | ms
        current = var.parameter_value
        if isinstance(current, int) and current and (current >> 16) & 0xFF != master.node_id:
            self.error("watch_master", "the DCF already uses 1016h sub 1 for another node")
            return
        self.set_value(var, value, "watch_master", self.raw, "watch_master")

    def _sync(self, cfg: NodeConfig) -> None:
        master = self.master
        if not cfg.set_sync_period or not master.sync_period:
            return
        period = cfg.od.get_variable(0x1006, 0)
        if period is not None and period.writable:
            try:
                period.parameter_value = master.sync_period_us
                self.yaml_set.add((0x1006, 0))
            except Exception as exc:  # the od's typed errors say what does not fit
                self.error("set_sync_period", f"0x1006: {exc}")
        overflow = cfg.od.get_variable(0x1019, 0)
        if overflow is not None and overflow.writable and master.sync_overflow:
            try:
                overflow.parameter_value = master.sync_overflow
                self.yaml_set.add((0x1019, 0))
            except Exception as exc:  # the od's typed errors say what does not fit
                self.error("set_sync_period", f"0x1019: {exc}")

    # --- what the process image sees
    def _layouts(self, cfg: NodeConfig, *, transmit: bool) -> list[PdoLayout]:
        od = cfg.od
        direction = "tpdo" if transmit else "rpdo"
        kind = "TPDO" if transmit else "RPDO"
        comm_base, map_base = (0x1800, 0x1A00) if transmit else (0x1400, 0x1600)
        names = ObjectIndex(od, cfg.eds_path.name)
        layouts: list[PdoLayout] = []
        for number in range(1, 513):
            comm = od.get(comm_base + number - 1)
            if not isinstance(comm, Record | Array):
                continue
            in_yaml = (direction, number) in self.yaml_pdos
            key = f"{direction}{number}"

            def problem(
                reason: str, key: str = key, in_yaml: bool = in_yaml, number: int = number
            ) -> None:
                if in_yaml:
                    self.error(key, reason)
                else:
                    self.warning(None, f"{kind} {number} (EDS default): {reason}; it is left out")

            cob_var = comm.get(1)
            if cob_var is None or not isinstance(cob_var.value, int):
                continue
            try:
                cob = PdoCobId.from_u32(cob_var.value)
            except PdoError as exc:
                problem(str(exc))
                continue
            if not cob.valid:
                continue
            mapping = od.get(map_base + number - 1)
            if not isinstance(mapping, Record | Array):
                continue
            fields: list[tuple[MappingEntry, Kind | None]] = []
            variables: list[tuple[Variable, int, Kind]] = []
            broken = False
            direct = direct_mapping(mapping)
            for _entry_var, index, sub, bits in mapping_entries(mapping):
                if direct and not (index or sub or bits):
                    continue  # an unused entry of a direct mapping
                entry = MappingEntry(index, sub, bits)
                if entry.is_dummy:
                    fields.append((entry, None))
                    continue
                var = od.get_variable(index, sub)
                if var is None:
                    problem(f"maps 0x{index:04X}:{sub:02X}, which is not in the EDS")
                    broken = True
                    break
                try:
                    kind_of = mapped_kind(var, bits)
                except BadValue as exc:
                    problem(str(exc))
                    broken = True
                    break
                fields.append((entry, kind_of))
                variables.append((var, bits, kind_of))
            if broken or (not variables and (fields or key not in self.empty_rpdos)):
                continue
            try:
                codec = PdoMap(fields)
            except PdoError as exc:
                problem(str(exc))
                continue
            tt = sub_value(comm, 2, 255)
            event_timer = sub_value(comm, 5, 0)
            timeout: float | None = None
            if transmit:
                timeout = self._tpdo_timeout(cfg, number, tt, event_timer)
            positions: list[Signal | None] = []
            for pos, (var, bits, kind_) in enumerate(variables):
                positions.append(
                    Signal(
                        name=names.canonical(var),
                        node_id=cfg.node_id,
                        direction="input" if transmit else "output",
                        pdo=number,
                        position=pos,
                        index=var.index,
                        subindex=var.subindex,
                        data_type=var.data_type,
                        bits=bits,
                        kind=kind_,
                        low=_limit(var.low_limit),
                        high=_limit(var.high_limit),
                    )
                )
            layouts.append(
                PdoLayout(
                    direction=direction,
                    number=number,
                    cob_id=cob.can_id,
                    extended=cob.extended,
                    transmission_type=tt,
                    event_timer=event_timer,
                    inhibit_time=sub_value(comm, 3, 0),
                    timeout=timeout,
                    codec=codec,
                    positions=tuple(positions),
                )
            )
        return layouts

    def _tpdo_timeout(
        self, cfg: NodeConfig, number: int, tt: int, event_timer: int
    ) -> float | None:
        spec = self.raw.get(f"tpdo{number}")
        if isinstance(spec, Mapping) and "timeout" in spec:
            try:
                ms = as_ms(spec["timeout"], 0xFFFF)
            except BadValue:
                return None
            return ms / 1000.0 if ms else None
        factor = self.master.pdo_timeout_factor
        if 1 <= tt <= 240 and self.master.sync_period:
            return min(tt * self.master.sync_period * factor, 65.535)
        if tt >= 254 and event_timer:
            return min(event_timer / 1000.0 * factor, 65.535)
        return None

    def _signals(self, cfg: NodeConfig) -> None:
        """Name the signals (aliases, scaling). An object mapped in several PDOs of a
        direction is one signal: its value comes from (or goes to) each of them."""
        specs: dict[str, tuple[str, float | None, float, str | None]] = {}
        if "signals" in self.raw:
            specs = self._aliases(cfg)
        for layouts in (cfg.tpdos, cfg.rpdos):
            for li, layout in enumerate(layouts):
                new: list[Signal | None] = []
                for sig in layout.positions:
                    if sig is None:
                        new.append(None)
                        continue
                    alias = specs.get(sig.name)
                    local = alias[0] if alias is not None else sig.name
                    scale, offset, unit = (None, 0.0, None) if alias is None else alias[1:]
                    new.append(
                        replace(
                            sig, name=f"{cfg.name}.{local}", scale=scale, offset=offset, unit=unit
                        )
                    )
                layouts[li] = replace(layout, positions=tuple(new))
        cfg.aliases = {alias: canonical for canonical, (alias, *_rest) in specs.items()}

    def _aliases(self, cfg: NodeConfig) -> dict[str, tuple[str, float | None, float, str | None]]:
        raw = self.raw["signals"]
        out: dict[str, tuple[str, float | None, float, str | None]] = {}
        if not isinstance(raw, Mapping):
            self.error(
                "signals", "give a mapping of alias: object (or {object, scale, offset, unit})"
            )
            return out
        index = ObjectIndex(cfg.od, cfg.eds_path.name)
        mapped = {(s.index, s.subindex): s for lay in (*cfg.tpdos, *cfg.rpdos) for s in lay.signals}
        canon_names = {s.name for s in mapped.values()}
        for alias, spec in raw.items():
            label = f"signals.{alias}"
            if not isinstance(alias, str) or not _ALIAS.match(alias):
                self.error(
                    label, f"alias {alias!r} must be a name (letters, digits, _ .)", raw, alias
                )
                continue
            scale: float | None = None
            offset = 0.0
            unit: str | None = None
            target: Any = spec
            if isinstance(spec, Mapping):
                for extra in spec:
                    if extra not in ("object", "scale", "offset", "unit"):
                        hint = suggest(str(extra), ("object", "scale", "offset", "unit"))
                        self.error(f"{label}.{extra}", f"unknown key{hint}", spec, extra)
                target = spec.get("object", alias)
                try:
                    if "scale" in spec:
                        scale = as_number(spec["scale"], -1e12, 1e12)
                        if scale == 0:
                            raise BadValue("a scale of 0 loses the value")
                    if "offset" in spec:
                        offset = as_number(spec["offset"], -1e12, 1e12)
                except BadValue as exc:
                    self.error(label, str(exc), raw, alias)
                    continue
                if "unit" in spec:
                    unit = str(spec["unit"])
            try:
                var = index.resolve(target)
            except BadValue as exc:
                self.error(label, str(exc), raw, alias)
                continue
            sig = mapped.get((var.index, var.subindex))
            if sig is None:
                self.error(
                    label,
                    f"0x{var.index:04X}:{var.subindex:02X} ({var.name}) is not mapped in any "
                    "valid PDO: map it in a tpdoN or rpdoN to see it in the process image",
                    raw,
                    alias,
                )
                continue
            if (scale is not None or offset) and sig.kind not in (
                Kind.SIGNED,
                Kind.UNSIGNED,
                Kind.REAL32,
                Kind.REAL64,
            ):
                self.error(
                    label, f"{var.name} is {var.data_type.name}: it cannot be scaled", raw, alias
                )
                continue
            if alias != sig.name and alias in canon_names:
                self.error(
                    label, f"{alias!r} is already the name of another mapped object", raw, alias
                )
                continue
            if sig.name in out:
                self.error(label, f"{var.name} has two aliases", raw, alias)
                continue
            out[sig.name] = (alias, scale, offset, unit)
        return out


def _limit(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    return value


def _read_master(raw: Any, report: Report) -> MasterConfig:
    cfg = MasterConfig()
    if raw is None:
        return cfg
    try:
        spec = as_mapping(raw, "master")
    except BadValue as exc:
        report.error(None, "master", str(exc), None)
        return cfg
    for key in spec:
        if key not in _MASTER_KEYS:
            report.error(
                None,
                f"master.{key}",
                f"unknown key{suggest(str(key), _MASTER_KEYS)}",
                line_of(spec, key),
            )

    def get(key: str, parse: Any, default: Any) -> Any:
        if key not in spec:
            return default
        try:
            return parse(spec[key])
        except BadValue as exc:
            report.error(None, f"master.{key}", str(exc), line_of(spec, key))
            return default

    if "node_id" in spec and spec["node_id"] is not None:
        cfg.node_id = get("node_id", lambda v: as_int(v, 1, 127, "node-ID"), None)

    def bitrate(value: Any) -> int:
        if value not in BIT_RATES:
            rates = ", ".join(str(r) for r in BIT_RATES)
            raise BadValue(f"{value!r} bit/s is no CiA 301 bit rate ({rates})")
        return int(value)

    cfg.bitrate = get("bitrate", bitrate, 500_000)
    cfg.sync_period = get("sync_period", lambda v: as_ms(v, 4_294_967.295), 0.0) / 1000.0
    cfg.sync_cob_id = get("sync_cob_id", lambda v: as_int(v, 1, 0x7FF, "COB-ID"), 0x80)

    def overflow(value: Any) -> int:
        v = as_int(value, 0, 240, "counter overflow")
        if v == 1:
            raise BadValue("1 is not allowed: use 0 (no counter) or 2..240")
        return v

    cfg.sync_overflow = get("sync_overflow", overflow, 0)
    cfg.sync_by_interface = get("sync_by_interface", as_bool, False)
    cfg.heartbeat_time = get("heartbeat_time", as_whole_ms, 0)
    cfg.time_period = get("time_period", lambda v: as_ms(v, 86_400_000), 0.0) / 1000.0
    cfg.time_cob_id = get("time_cob_id", lambda v: as_int(v, 1, 0x7FF, "COB-ID"), 0x100)
    cfg.reset = get("reset", lambda v: as_choice(v, ("node", "broadcast")), "node")
    cfg.start = get("start", lambda v: as_choice(v, ("node", "broadcast")), "node")
    cfg.bootup_delay = get("bootup_delay", lambda v: as_ms(v, 60_000), 300.0) / 1000.0
    cfg.pdo_timeout_factor = get("pdo_timeout_factor", lambda v: as_number(v, 1.0, 100.0), 3.0)
    cfg.bus_load_window = get("bus_load_window", lambda v: as_ms(v, 10_000), 250.0) / 1000.0
    if cfg.bus_load_window < 0.01:
        report.error(
            None, "master.bus_load_window", "use at least 10 ms", line_of(spec, "bus_load_window")
        )
        cfg.bus_load_window = 0.25
    if cfg.heartbeat_time and cfg.node_id is None:
        report.error(
            None,
            "master.heartbeat_time",
            "a master heartbeat needs master.node_id",
            line_of(spec, "heartbeat_time"),
        )
    if cfg.sync_period and cfg.sync_period_us < 1:
        report.error(None, "master.sync_period", "use at least 1 µs", line_of(spec, "sync_period"))
    if cfg.sync_by_interface and not cfg.sync_period:
        report.warning(
            None,
            "master.sync_by_interface",
            "the master sends no SYNC without a sync_period",
            line_of(spec, "sync_by_interface"),
        )
    return cfg


def _cross_checks(network: NetworkConfig, report: Report) -> None:
    producers: dict[int, str] = {}
    for node in network.nodes.values():
        for layout in node.tpdos:
            other = producers.get(layout.cob_id)
            here = f"{node.name} TPDO {layout.number}"
            if other is not None:
                report.error(
                    node.name,
                    f"tpdo{layout.number}",
                    f"COB-ID 0x{layout.cob_id:X} is also sent by {other}: two producers collide",
                    None,
                )
            producers.setdefault(layout.cob_id, here)
    consumers: dict[int, str] = {}
    for node in network.nodes.values():
        for i, layout in enumerate(node.rpdos):
            here = f"{node.name} RPDO {layout.number}"
            other = consumers.get(layout.cob_id)
            if other is not None:
                report.error(
                    node.name,
                    f"rpdo{layout.number}",
                    f"COB-ID 0x{layout.cob_id:X} is also {other}'s; give each RPDO its own",
                    None,
                )
            consumers.setdefault(layout.cob_id, here)
            source = producers.get(layout.cob_id)
            if source is not None:
                report.warning(
                    node.name,
                    f"rpdo{layout.number}",
                    f"COB-ID 0x{layout.cob_id:X} is fed by {source} (PDO linking): the master "
                    "does not send it",
                    None,
                )
                node.rpdos[i] = replace(
                    layout, positions=tuple(None for _ in layout.positions), linked=True
                )
    master = network.master
    if master.time_period:
        for node in network.nodes.values():
            for layout in (*node.tpdos, *node.rpdos):
                if layout.cob_id == master.time_cob_id:
                    report.error(
                        node.name,
                        f"{layout.direction}{layout.number}",
                        f"COB-ID 0x{layout.cob_id:X} is the master's TIME identifier",
                        None,
                    )


def parse_network(
    data: Any, *, base_dir: str | os.PathLike[str] = ".", path: str = "<network>"
) -> tuple[NetworkConfig | None, list[ConfigProblem]]:
    """Read a network description already parsed from YAML (or built in code).

    Returns the configuration (None when there are errors) and every problem found."""
    report = Report(path)
    return _parse(data, Path(base_dir), report), report.problems


def _parse(data: Any, base_dir: Path, report: Report) -> NetworkConfig | None:
    if not isinstance(data, Mapping):
        report.error(None, None, "the file must be a mapping with master, defaults and nodes", None)
        return None
    for key in data:
        if key not in _TOP_KEYS:
            report.error(
                None,
                str(key),
                f"unknown section{suggest(str(key), _TOP_KEYS)}",
                line_of(data, key),
            )
    master = _read_master(data.get("master"), report)
    defaults: Mapping[Any, Any] = {}
    if data.get("defaults") is not None:
        try:
            defaults = as_mapping(data["defaults"], "defaults")
        except BadValue as exc:
            report.error(None, "defaults", str(exc), line_of(data, "defaults"))
        for key in defaults:
            if str(key) not in _NODE_KEYS or key in _NOT_DEFAULTABLE:
                allowed = [k for k in _NODE_KEYS if k not in _NOT_DEFAULTABLE]
                report.error(
                    None,
                    f"defaults.{key}",
                    f"not a key nodes can share{suggest(str(key), allowed)}",
                    line_of(defaults, key),
                )
    nodes_raw = data.get("nodes")
    if not isinstance(nodes_raw, Mapping) or not nodes_raw:
        report.error(
            None,
            "nodes",
            "give the nodes: a mapping of node name to its settings",
            line_of(data, "nodes"),
        )
        return None
    nodes: dict[int, NodeConfig] = {}
    node_ids: dict[int, str] = {}
    texts: dict[Path, str] = {}
    for name, raw in nodes_raw.items():
        sname = str(name)
        if not isinstance(name, str) or not _NODE_NAME.match(name):
            report.error(
                sname,
                None,
                "node names start with a letter and use letters, digits, _ and -",
                line_of(nodes_raw, name),
            )
            continue
        if not isinstance(raw, Mapping):
            report.error(
                sname, None, "the node's settings must be a mapping", line_of(nodes_raw, name)
            )
            continue
        reader = _NodeReader(sname, raw, defaults, master, base_dir, report, texts)
        cfg = reader.read(node_ids)
        if cfg is not None:
            nodes[cfg.node_id] = cfg
    network = NetworkConfig(report.path, master, nodes)
    _cross_checks(network, report)
    network.warnings = [p for p in report.problems if p.severity is Severity.WARNING]
    if report.errors:
        return None
    return network


def _read_text(text: str, path: str, report: Report) -> Any:
    data, problems = read_yaml(text)
    for problem in problems:
        report.error(None, problem.key, problem.reason, problem.line)
    return data


def check_network(
    path: str | os.PathLike[str],
) -> tuple[NetworkConfig | None, list[ConfigProblem]]:
    """Read ``path`` and list every problem (errors and warnings) without raising."""
    name = os.fspath(path)
    report = Report(name)
    try:
        text = Path(name).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) else str(exc)
        report.error(None, None, f"cannot read the file: {reason}", None)
        return None, report.problems
    data = _read_text(text, name, report)
    if report.errors:
        return None, report.problems
    # Relative EDS paths start beside the file as it was named: a network file reached
    # through a symbolic link finds the EDS files beside the link.
    cfg = _parse(data, Path(os.path.abspath(name)).parent, report)
    return cfg, report.problems


def loads_network(
    text: str, *, base_dir: str | os.PathLike[str] = ".", path: str = "<string>"
) -> NetworkConfig:
    """Read a network description from YAML text; raise :class:`NetworkConfigError` on errors."""
    report = Report(path)
    data = _read_text(text, path, report)
    cfg = None if report.errors else _parse(data, Path(base_dir), report)
    if cfg is None:
        raise NetworkConfigError(report.problems)
    return cfg


def load_network(path: str | os.PathLike[str]) -> NetworkConfig:
    """Read a network description file; raise :class:`NetworkConfigError` on errors."""
    cfg, problems = check_network(path)
    if cfg is None:
        raise NetworkConfigError(problems)
    return cfg
