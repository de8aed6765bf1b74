"""A node's PDOs as a network file gives them: the ``tpdoN``/``rpdoN`` keys (communication
parameters and mapping, set in the node's dictionary), the layouts the master runs from the
dictionary (COB-ID, transmission type, event timer, the codec of the mapped values, the
watchdog of a TPDO), and the node's signals (named, scaled values of those PDOs).
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import replace
from typing import TYPE_CHECKING, Any

from cobus.master.config.model import EXTENDED, INVALID, NodeConfig, PdoLayout, Signal
from cobus.master.config.names import DUMMY, DUMMY_TYPES, ObjectIndex, mapped_kind
from cobus.master.config.startup import direct_mapping, sub_value
from cobus.master.config.values import (
    BadValue,
    as_bool,
    as_int,
    as_mapping,
    as_ms,
    as_number,
    as_whole_ms,
    suggest,
)
from cobus.od import (
    Array,
    Record,
    Variable,
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

if TYPE_CHECKING:
    from cobus.master.config.nodes import NodeReader


__all__ = ["PDO_KEY", "PdoReader"]

#: A PDO key of a node entry: ``tpdo1`` .. ``rpdo512``.
PDO_KEY = re.compile(r"([tr])pdo([0-9]+)\Z")
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
_ALIAS = re.compile(r"[A-Za-z_][A-Za-z0-9_.\[\]]*\Z")


def _limit(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    return value


class PdoReader:
    """Reads the PDOs and signals of the node :class:`NodeReader` reads, reporting through it."""

    def __init__(self, node: NodeReader) -> None:
        self.node = node

    # --- PDOs
    def read(self, cfg: NodeConfig) -> None:
        """The ``tpdoN``/``rpdoN`` keys of the node: checked, their values set in its
        dictionary (the start-up list writes them)."""
        for key in self.node.raw:
            match = PDO_KEY.match(str(key))
            if match is None:
                continue
            tx = match.group(1) == "t"
            number = int(match.group(2))
            self._pdo(cfg, str(key), tx, number, self.node.raw[key])

    def _pdo(self, cfg: NodeConfig, key: str, tx: bool, number: int, raw: Any) -> None:
        kind = "TPDO" if tx else "RPDO"
        try:
            spec = as_mapping(raw, key)
        except BadValue as exc:
            self.node.error(key, str(exc))
            return
        if not 1 <= number <= 512:
            self.node.error(key, f"{kind} numbers run 1..512, not {number}")
            return
        od = cfg.od
        comm_index = (0x1800 if tx else 0x1400) + number - 1
        map_index = (0x1A00 if tx else 0x1600) + number - 1
        comm = od.get(comm_index)
        mapping = od.get(map_index)
        if not isinstance(comm, Record | Array) or not isinstance(mapping, Record | Array):
            self.node.error(
                key,
                f"{cfg.eds_path.name} has no {kind} {number} (objects 0x{comm_index:04X} and "
                f"0x{map_index:04X})",
            )
            return
        self.node.yaml_pdos.add(("tpdo" if tx else "rpdo", number))
        for field_key in spec:
            if field_key not in _PDO_FIELDS or (field_key == "timeout" and not tx):
                fields = [f for f in _PDO_FIELDS if tx or f != "timeout"]
                self.node.error(
                    f"{key}.{field_key}",
                    f"unknown PDO setting{suggest(str(field_key), fields)}",
                    spec,
                    field_key,
                )
        if "timeout" in spec:
            try:
                as_ms(spec["timeout"], 0xFFFF)
            except BadValue as exc:
                self.node.error(f"{key}.timeout", str(exc), spec, "timeout")
        enabled = True
        if "enabled" in spec:
            try:
                enabled = as_bool(spec["enabled"])
            except BadValue as exc:
                self.node.error(f"{key}.enabled", str(exc), spec, "enabled")
        cob_var = comm.get(1)
        if cob_var is None or not isinstance(cob_var.value, int):
            self.node.error(key, f"0x{comm_index:04X} has no COB-ID (sub-index 1) with a value")
            return
        current = cob_var.value
        if "cob_id" in spec:
            try:
                cob = as_int(spec["cob_id"], 1, 0x1FFFFFFF | EXTENDED, "COB-ID")
            except BadValue as exc:
                self.node.error(f"{key}.cob_id", str(exc), spec, "cob_id")
                return
        else:
            cob = current & ~INVALID
        if enabled:
            try:
                parsed = PdoCobId.from_u32(cob & ~INVALID)
            except PdoError as exc:
                self.node.error(f"{key}.cob_id", str(exc), spec, "cob_id")
                return
            if parsed.can_id == 0 or (not parsed.extended and is_restricted_can_id(parsed.can_id)):
                self.node.error(
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
        self.node.set_value(
            cob_var, cob, f"{key}.cob_id", spec, "cob_id" if "cob_id" in spec else None
        )
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
                self.node.error(
                    label, f"0x{comm_index:04X} has no sub-index {sub}", spec, field_key
                )
                continue
            if field_key == "sync_start" and not tx:
                self.node.error(label, "RPDOs have no SYNC start value", spec, field_key)
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
                self.node.error(label, str(exc), spec, field_key)
                continue
            self.node.set_value(var, value, label, spec, field_key)
        if "mapping" in spec:
            self._mapping(cfg, key, tx, mapping, spec)

    def _mapping(
        self, cfg: NodeConfig, key: str, tx: bool, mapping: Record | Array, spec: Mapping[Any, Any]
    ) -> None:
        items = spec["mapping"]
        label = f"{key}.mapping"
        if not isinstance(items, list):
            self.node.error(label, "give a list of object names or addresses", spec, "mapping")
            return
        if not items and not tx:
            self.node.empty_rpdos.add(key)
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
                self.node.error(where, str(exc), items, pos)
                ok = False
                continue
            ident = f"0x{var.index:04X}:{var.subindex:02X} ({var.name})"
            length = var.bit_length
            if length is None:
                self.node.error(
                    where, f"{ident} is {var.data_type.name}: no fixed length", items, pos
                )
                ok = False
                continue
            if not var.pdo_mappable:
                self.node.error(where, f"{ident} is not PDO-mappable in the EDS", items, pos)
                ok = False
                continue
            if tx and not var.readable:
                self.node.error(where, f"{ident} is write-only: it cannot go in a TPDO", items, pos)
                ok = False
                continue
            if not tx and not var.writable:
                self.node.error(
                    where, f"{ident} is {var.access}: it cannot go in an RPDO", items, pos
                )
                ok = False
                continue
            values.append(var.index << 16 | var.subindex << 8 | length)
            bits_total += length
        slots = max((s for s in mapping.subindices if s), default=0)
        if len(values) > slots:
            self.node.error(
                label,
                f"{len(values)} entries but 0x{mapping.index:04X} has {slots} mapping entries",
                spec,
                "mapping",
            )
            return
        if bits_total > 64:
            self.node.error(
                label, f"the mapping takes {bits_total} bits; a PDO carries 64", spec, "mapping"
            )
            return
        if not ok:
            return
        count_var = mapping.get(0)
        if count_var is None:
            self.node.error(label, f"0x{mapping.index:04X} has no sub-index 0", spec, "mapping")
            return
        if direct_mapping(mapping):
            values += [0] * (slots - len(values))  # direct mapping: 0 = an unused entry
        else:
            self.node.set_value(count_var, len(values), label, spec, "mapping")
        for sub, value in enumerate(values, 1):
            slot = mapping.get(sub)
            if slot is None:
                self.node.error(
                    label, f"0x{mapping.index:04X} has no sub-index {sub}", spec, "mapping"
                )
                return
            self.node.set_value(slot, value, label, spec, "mapping")

    # --- what the process image sees
    def layouts(self, cfg: NodeConfig, *, transmit: bool) -> list[PdoLayout]:
        """The node's TPDOs (``transmit``) or RPDOs as its dictionary now has them."""
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
            in_yaml = (direction, number) in self.node.yaml_pdos
            key = f"{direction}{number}"

            def problem(
                reason: str, key: str = key, in_yaml: bool = in_yaml, number: int = number
            ) -> None:
                if in_yaml:
                    self.node.error(key, reason)
                else:
                    self.node.warning(
                        None, f"{kind} {number} (EDS default): {reason}; it is left out"
                    )

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
            if broken or (not variables and (fields or key not in self.node.empty_rpdos)):
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
        spec = self.node.raw.get(f"tpdo{number}")
        if isinstance(spec, Mapping) and "timeout" in spec:
            try:
                ms = as_ms(spec["timeout"], 0xFFFF)
            except BadValue:
                return None
            return ms / 1000.0 if ms else None
        factor = self.node.master.pdo_timeout_factor
        if 1 <= tt <= 240 and self.node.master.sync_period:
            return min(tt * self.node.master.sync_period * factor, 65.535)
        if tt >= 254 and event_timer:
            return min(event_timer / 1000.0 * factor, 65.535)
        return None

    def signals(self, cfg: NodeConfig) -> None:
        """Name the signals (aliases, scaling). An object mapped in several PDOs of a
        direction is one signal: its value comes from (or goes to) each of them."""
        specs: dict[str, tuple[str, float | None, float, str | None]] = {}
        if "signals" in self.node.raw:
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
        raw = self.node.raw["signals"]
        out: dict[str, tuple[str, float | None, float, str | None]] = {}
        if not isinstance(raw, Mapping):
            self.node.error(
                "signals", "give a mapping of alias: object (or {object, scale, offset, unit})"
            )
            return out
        index = ObjectIndex(cfg.od, cfg.eds_path.name)
        mapped = {(s.index, s.subindex): s for lay in (*cfg.tpdos, *cfg.rpdos) for s in lay.signals}
        canon_names = {s.name for s in mapped.values()}
        for alias, spec in raw.items():
            label = f"signals.{alias}"
            if not isinstance(alias, str) or not _ALIAS.match(alias):
                self.node.error(
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
                        self.node.error(f"{label}.{extra}", f"unknown key{hint}", spec, extra)
                target = spec.get("object", alias)
                try:
                    if "scale" in spec:
                        scale = as_number(spec["scale"], -1e12, 1e12)
                        if scale == 0:
                            raise BadValue("a scale of 0 loses the value")
                    if "offset" in spec:
                        offset = as_number(spec["offset"], -1e12, 1e12)
                except BadValue as exc:
                    self.node.error(label, str(exc), raw, alias)
                    continue
                if "unit" in spec:
                    unit = str(spec["unit"])
            try:
                var = index.resolve(target)
            except BadValue as exc:
                self.node.error(label, str(exc), raw, alias)
                continue
            sig = mapped.get((var.index, var.subindex))
            if sig is None:
                self.node.error(
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
                self.node.error(
                    label, f"{var.name} is {var.data_type.name}: it cannot be scaled", raw, alias
                )
                continue
            if alias != sig.name and alias in canon_names:
                self.node.error(
                    label, f"{alias!r} is already the name of another mapped object", raw, alias
                )
                continue
            if sig.name in out:
                self.node.error(label, f"{var.name} has two aliases", raw, alias)
                continue
            out[sig.name] = (alias, scale, offset, unit)
        return out
