"""Reading a network file (YAML) into a :class:`NetworkConfig`: the master's keys, the defaults,
each node (:class:`~cobus.master.config.nodes.NodeReader`), the checks across nodes, and the
report of every problem with file, line, node and key.
"""

from __future__ import annotations

import os
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from cobus._yaml import line_of, read_yaml
from cobus.master.config.checks import cross_checks
from cobus.master.config.model import BIT_RATES, MasterConfig, NetworkConfig, NodeConfig
from cobus.master.config.nodes import NODE_KEYS, NOT_DEFAULTABLE, NodeReader
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

# ------------------------------------------------------------------------------- parsing

__all__ = ["check_network", "load_network", "loads_network", "parse_network"]

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
_NODE_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_-]*\Z")


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
            if str(key) not in NODE_KEYS or key in NOT_DEFAULTABLE:
                allowed = [k for k in NODE_KEYS if k not in NOT_DEFAULTABLE]
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
        reader = NodeReader(sname, raw, defaults, master, base_dir, report, texts)
        cfg = reader.read(node_ids)
        if cfg is not None:
            nodes[cfg.node_id] = cfg
    network = NetworkConfig(report.path, master, nodes)
    cross_checks(network, report)
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
