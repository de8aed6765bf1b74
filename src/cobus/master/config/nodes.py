"""One node entry of a network file read into a :class:`NodeConfig`: its dictionary (EDS or
DCF, relative to the file), its scalar keys, its explicit SDO writes, its error control and
SYNC settings, its PDOs and signals (through :class:`~cobus.master.config.pdos.PdoReader`)
and its start-up list - every problem reported with file, line, node and key.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from cobus._yaml import line_of
from cobus.master.config.model import IDENTITY_KEYS, RESTORE, MasterConfig, NodeConfig, SdoEntry
from cobus.master.config.names import ObjectIndex, dropped_value
from cobus.master.config.pdos import PDO_KEY, PdoReader
from cobus.master.config.startup import startup_list
from cobus.master.config.values import (
    BadValue,
    Report,
    as_bool,
    as_choice,
    as_int,
    as_ms,
    as_number,
    as_whole_ms,
    suggest,
)
from cobus.od import (
    DataType,
    EdsError,
    ObjectDictionary,
    Variable,
    loads,
)

__all__ = ["NODE_KEYS", "NOT_DEFAULTABLE", "NodeReader"]

#: The keys of a node entry (besides ``tpdoN``/``rpdoN``).
NODE_KEYS = (
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
    "lss",
    "lss_store",
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
#: Keys ``defaults`` cannot give (each node has its own).
NOT_DEFAULTABLE = ("node_id", "eds", "dcf", "sdo", "signals")
_U32 = 0xFFFFFFFF


class NodeReader:
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
        """An error at ``key`` (its line in ``container``, the node entry unless given)."""
        where = container if container is not None else self.raw
        line = line_of(where, at if at is not None else key)
        self.report.error(self.name, key, reason, line)

    def warning(self, key: str | None, reason: str, container: Any = None, at: Any = None) -> None:
        """A warning at ``key``, as :meth:`error` places it."""
        where = container if container is not None else self.raw
        line = line_of(where, at if at is not None else key)
        self.report.warning(self.name, key, reason, line)

    def value(self, key: str) -> tuple[bool, Any, Any]:
        """(given, value, container) of ``key`` from the node, else from ``defaults``."""
        if key in self.raw:
            return True, self.raw[key], self.raw
        if key in self.defaults and key not in NOT_DEFAULTABLE:
            return True, self.defaults[key], self.defaults
        return False, None, None

    def get(self, key: str, parse: Any, default: Any) -> Any:
        """``key`` parsed by ``parse`` (``default`` when not given or wrong; reported)."""
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
        """The node, or None when it cannot be used (``node_ids``: the IDs taken so far)."""
        raw = self.raw
        for key in raw:
            skey = str(key)
            if skey not in NODE_KEYS and not PDO_KEY.match(skey):
                self.error(skey, f"unknown key{suggest(skey, NODE_KEYS)}")
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
        pdos = PdoReader(self)
        pdos.read(cfg)
        self._explicit_sdo(cfg)
        self._error_control(cfg)
        self._sync(cfg)
        cfg.startup = startup_list(cfg, self.yaml_set, self.explicit, self._unwritable)
        cfg.tpdos = pdos.layouts(cfg, transmit=True)
        cfg.rpdos = pdos.layouts(cfg, transmit=False)
        pdos.signals(cfg)
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
        cfg.lss = g("lss", as_bool, False)
        cfg.lss_store = g("lss_store", as_bool, False)
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
        if cfg.lss:
            _given, _value, where = self.value("lss")
            inherited = " (lss: true comes from defaults: set lss: false on this node)"
            inherited = inherited if where is not self.raw else ""
            missing = [
                k for k in ("vendor_id", "product_code", "serial_number") if not getattr(cfg, k)
            ]
            if missing:
                self.error(
                    "lss",
                    f"the master finds the device by its LSS address: give {', '.join(missing)} "
                    "(not 0; revision_number too, or the master looks for it)" + inherited,
                    where,
                )
            if cfg.do_not_initialise:
                self.error(
                    "lss",
                    "a node with do_not_initialise: true gets nothing from the master, "
                    "no LSS either" + inherited,
                    where,
                )
        elif cfg.lss_store and "lss_store" in self.raw:
            self.error("lss_store", "stores the node-ID LSS gives: set lss: true too")
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
        """The node's ``eds`` (or ``dcf``) as the file gives it."""
        value = self.raw.get("eds", self.raw.get("dcf", ""))
        return str(value)

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
