"""The Parameters page's data: each node's dictionary from its EDS, read and written by SDO.

:func:`serve_parameters` adds these commands for the nodes of a
:class:`~cobus.master.Master` (through each node's own SDO channel, ``node.sdo``):

- ``param.list {node, query, limit}`` — the node's objects from its EDS (index, sub-index,
  name, type, access, default, limits, unit, whether writing it is a command), those whose
  name contains ``query`` or whose address it gives (``6040``, ``0x6040``, ``6040:00``,
  ``6040h``);
- ``param.read {node, index, subindex}`` — the value the node holds, decoded with its type;
- ``param.write {node, index, subindex, value}`` (writes) — checked here before anything is
  sent: the object must be in the EDS and writable, the value of its type and within its
  limits. An object whose writing is a command (a controlword, a set-point, a mode, an
  output, what an RPDO carries: :class:`cobus.od.CommandObjects`) is refused unless the
  message says ``"command": true`` — the page asks the operator first, saying why;
- ``param.save {node}`` (writes) — "save" to 1010h sub-index 1 (all parameters);
- ``param.diff {node, against}`` — the node's values against the network file
  (``"network"``, the default: each object of its start-up list) or against its parameter
  file (``"parameters"``: each parameter of the set a :class:`~cobus.blocks.Parameterise`
  boot step brings it to), read back and compared with what the file says.

The state key ``parameters/status`` gives, for each node the master parameterises at boot
(a :class:`~cobus.blocks.Parameterise` boot step), its file and the last run's summary
("up to date", "re-parameterised: ...", "failed: ...").
"""

from __future__ import annotations

import contextlib
import math
import os
import re
from collections.abc import Callable, Mapping
from typing import Any

from cobus.apps.panel.server import CommandError, Panel
from cobus.blocks.param_manager import Parameterise
from cobus.blocks.parameters import ParameterFileError, ParameterSet
from cobus.errors import clip
from cobus.od import CommandObjects, DataType, ObjectDictionary, Variable, decode, encode

__all__ = ["ParameterView", "serve_parameters"]

#: The most objects one ``param.list`` answer carries.
MAX_LIST = 2000
#: 1010h sub 1 "save all parameters": the signature "save" (CiA 301).
SAVE_SIGNATURE = 0x65766173
_ADDRESS = re.compile(r"^(?:0x)?([0-9a-f]{1,4})h?(?:[:.sub ]+(?:0x)?([0-9a-f]{1,2})h?)?$", re.I)


def _label(var: Variable) -> str:
    parent = var.parent
    if parent is not None and getattr(parent, "name", None) and parent.name != var.name:
        return f"{parent.name}.{var.name}"
    return var.name


def _shown(value: Any) -> Any:
    """A value as JSON carries it (bytes as hex)."""
    if isinstance(value, bytes | bytearray):
        return bytes(value).hex(" ").upper()
    return value


class ParameterView:
    """What :func:`serve_parameters` attaches (see the module text)."""

    def __init__(self, panel: Panel, master: Any) -> None:
        self.panel = panel
        self.master = master
        self._commands: dict[int, CommandObjects] = {}
        #: The Parameterise boot step of each node that has one, by node-ID.
        self.steps: dict[int, Parameterise] = {
            node.node_id: step
            for node in master.nodes.values()
            for _name, step in node.boot_steps
            if isinstance(step, Parameterise)
        }
        panel.hub.set_info(
            "parameters",
            {
                "nodes": [
                    {
                        "id": n.node_id,
                        "name": n.name,
                        "eds": n.config.eds_path.name,
                        "set": self._set_name(n.node_id),
                    }
                    for n in master.nodes.values()
                ]
            },
        )
        panel.sample(self.sample)
        panel.views["parameters"] = self
        panel.command("param.list", self._list, writes=False, help="a node's objects (EDS)")
        panel.command("param.read", self._read, writes=False, help="read an object by SDO")
        panel.command("param.write", self._write, writes=True, help="write an object by SDO")
        panel.command("param.save", self._save, writes=True, help="save the parameters (1010h)")
        panel.command("param.diff", self._diff, writes=False, help="the node against its file")

    def _set_name(self, node_id: int) -> str | None:
        step = self.steps.get(node_id)
        if step is None:
            return None
        source = step.parameters
        path = source.path if isinstance(source, ParameterSet) else source
        return os.path.basename(path) if path else "(a set given in code)"

    def sample(self) -> dict[str, Any]:
        """The parameter manager's word on each node it parameterises at boot."""
        status = []
        for node_id, step in self.steps.items():
            report = step.reports.get(node_id)
            status.append(
                {
                    "node": node_id,
                    "set": self._set_name(node_id),
                    "summary": "not run yet" if report is None else report.summary,
                    "ok": None if report is None else report.ok,
                }
            )
        return {"parameters/status": status}

    # ------------------------------------------------------------------ helpers
    def _node(self, message: Mapping[str, Any]) -> Any:
        key = message.get("node")
        if isinstance(key, bool) or not isinstance(key, int | str):
            raise ValueError(f"node {clip(repr(key))}: give a node-ID or name of this network")
        node = self.master.nodes.get(key) if isinstance(key, int) else None
        if node is None:
            node = next((n for n in self.master.nodes.values() if n.name == key), None)
        if node is None:
            known = ", ".join(f"{n.name} ({n.node_id})" for n in self.master.nodes.values())
            raise CommandError(
                "no-node",
                f"node {clip(repr(key))} is not in this network (nodes: {known or 'none'})",
            )
        return node

    def _variable(self, node: Any, message: Mapping[str, Any]) -> Variable:
        index, sub = message.get("index"), message.get("subindex", 0)
        for what, value, top in (("index", index, 0xFFFF), ("subindex", sub, 0xFF)):
            if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= top:
                raise ValueError(f"{what} {value!r}: 0-{top:#x}")
        od: ObjectDictionary = node.config.od
        var = od.get_variable(int(index), int(sub))  # type: ignore[arg-type]
        if var is None:
            raise CommandError(
                "no-object",
                f"{index:04X}h:{sub:02X} is not in {node.name}'s EDS ({node.config.eds_path.name})",
            )
        return var

    def _describe(self, node: Any, var: Variable) -> dict[str, Any]:
        commands = self._commands.get(node.node_id)
        if commands is None:
            commands = self._commands[node.node_id] = CommandObjects(node.config.od)
        why = commands.reason(var.index, var.subindex)
        if why is None:
            why = _rpdo_carried(node).get((var.index, var.subindex))
        return {
            "index": var.index,
            "subindex": var.subindex,
            "name": _label(var),
            "type": var.data_type.name,
            "access": str(var.access),
            "default": _shown(var.default),
            "low": _shown(var.low_limit),
            "high": _shown(var.high_limit),
            "unit": var.unit,
            "pdo": var.pdo_mappable,
            "command": why,
        }

    # ------------------------------------------------------------------ commands
    async def _list(self, message: Mapping[str, Any]) -> dict[str, Any]:
        node = self._node(message)
        query = message.get("query", "")
        if not isinstance(query, str) or len(query) > 100:
            raise ValueError("query: a name or an address (6040, 0x6040:00) of 100 characters")
        limit = message.get("limit", 500)
        if isinstance(limit, bool) or not isinstance(limit, int) or not 1 <= limit <= MAX_LIST:
            raise ValueError(f"limit {limit!r}: 1-{MAX_LIST} objects")
        wanted = query.strip().lower()
        address = _ADDRESS.match(wanted) if wanted else None
        rows: list[dict[str, Any]] = []
        more = 0
        for var in node.config.od.variables():
            if wanted:
                by_name = wanted in _label(var).lower()
                by_address = (
                    address is not None
                    and var.index == int(address.group(1), 16)
                    and (address.group(2) is None or var.subindex == int(address.group(2), 16))
                )
                if not (by_name or by_address):
                    continue
            if len(rows) >= limit:
                more += 1
                continue
            rows.append(self._describe(node, var))
        return {"node": node.node_id, "objects": rows, "more": more}

    async def _read(self, message: Mapping[str, Any]) -> dict[str, Any]:
        node = self._node(message)
        var = self._variable(node, message)
        if not var.access.readable:
            raise CommandError("write-only", f"{_label(var)} is write-only ({var.access})")
        data = await node.sdo.upload(var.index, var.subindex)
        try:
            value = decode(var.data_type, data)
        except (ValueError, TypeError):
            value = None
        return {**self._describe(node, var), "value": _shown(value), "raw": data.hex(" ").upper()}

    async def _write(self, message: Mapping[str, Any]) -> dict[str, Any]:
        node = self._node(message)
        var = self._variable(node, message)
        name = _label(var)
        if not var.access.writable:
            raise CommandError("read-only", f"{name} is {var.access}: it cannot be written")
        value = _typed(var, message.get("value"))
        for limit, beyond in ((var.low_limit, "below"), (var.high_limit, "above")):
            if limit is None or not isinstance(value, int | float):
                continue
            if (beyond == "below" and value < limit) or (beyond == "above" and value > limit):
                raise ValueError(
                    f"{name}: {value} is {beyond} the EDS's limit {limit} "
                    f"({var.low_limit}..{var.high_limit})"
                )
        try:
            data = encode(var.data_type, value)
        except (ValueError, TypeError, OverflowError) as exc:
            raise ValueError(f"{name}: {exc}") from None
        why = self._describe(node, var)["command"]
        if why is not None and message.get("command") is not True:
            raise CommandError(
                "command",
                f"writing {name} is a command ({why}): it can switch the device on or move it; "
                'send "command": true once the operator has agreed',
            )
        await node.sdo.download(var.index, var.subindex, data)
        return {"index": var.index, "subindex": var.subindex, "name": name, "value": _shown(value)}

    async def _save(self, message: Mapping[str, Any]) -> dict[str, Any]:
        node = self._node(message)
        if node.config.od.get_variable(0x1010, 1) is None:
            raise CommandError(
                "no-object", f"{node.name}'s EDS has no 1010h sub-index 1: it cannot save"
            )
        await node.sdo.download(0x1010, 1, SAVE_SIGNATURE.to_bytes(4, "little"))
        return {"node": node.node_id, "saved": True}

    async def _diff(self, message: Mapping[str, Any]) -> dict[str, Any]:
        node = self._node(message)
        against = message.get("against", "network")
        if against == "network" and node.config.do_not_initialise:
            rows = [
                {
                    "index": entry.index,
                    "subindex": entry.subindex,
                    "name": entry.name,
                    "file": _shown(entry.value),
                    "node": None,
                    "same": None,
                    "note": "not written: the master leaves this node as it is (do_not_initialise)",
                }
                for entry in node.config.startup
            ]
            source = None
        elif against == "network":
            rows = [
                await self._compare(
                    node,
                    entry.index,
                    entry.subindex,
                    entry.name,
                    entry.value,
                    entry.data.__eq__,
                )
                for entry in node.config.startup
            ]
            source = None
        elif against == "parameters":
            step = self.steps.get(node.node_id)
            if step is None:
                raise CommandError(
                    "no-set",
                    f"{node.name} has no parameter file (cobus run --parameters "
                    f"{node.name}=FILE, or a Parameterise boot step)",
                )
            try:
                chosen = step.set_for(node)
            except ParameterFileError as exc:
                raise CommandError("bad-file", clip(str(exc), 400)) from None
            rows = [
                await self._compare(
                    node,
                    param.index,
                    param.subindex,
                    param.name,
                    param.value,
                    _holds(param),
                    readable=param.readable,
                )
                for param in chosen
            ]
            source = self._set_name(node.node_id)
        else:
            raise ValueError(f"against {clip(repr(against))}: network or parameters")
        differ = sum(1 for r in rows if r["same"] is False)
        return {
            "node": node.node_id,
            "against": against,
            "file": source,
            "rows": rows,
            "differ": differ,
        }

    async def _compare(
        self,
        node: Any,
        index: int,
        subindex: int,
        name: str,
        wanted: Any,
        same: Callable[[bytes], bool],
        *,
        readable: bool = True,
    ) -> dict[str, Any]:
        """One row of a diff: the object read from the node and compared by ``same``."""
        var = node.config.od.get_variable(index, subindex)
        row: dict[str, Any] = {
            "index": index,
            "subindex": subindex,
            "name": name or (_label(var) if var is not None else ""),
            "file": _shown(wanted),
        }
        if not readable or (var is not None and not var.access.readable):
            row.update(node=None, same=None, note="write-only: not read")
            return row
        try:
            data = await node.sdo.upload(index, subindex)
        except Exception as exc:  # (an abort, a timeout: said in the row)
            row.update(node=None, same=None, note=clip(str(exc)))
            return row
        shown: Any = data.hex(" ").upper()
        if var is not None:
            with contextlib.suppress(ValueError, TypeError):
                shown = _shown(decode(var.data_type, data))
        row.update(node=shown, same=same(data), note="")
        return row


def _holds(param: Any) -> Callable[[bytes], bool]:
    """How the parameter manager decides a node holds ``param`` (REAL -0.0 is 0.0)."""

    def same(data: bytes) -> bool:
        try:
            return bool(param.holds(param.decode(data)))
        except (ValueError, TypeError):
            return False

    return same


def _rpdo_carried(node: Any) -> dict[tuple[int, int], str]:
    """The objects the network file maps into the node's RPDOs: process data the master
    sends, so a write is a command."""
    carried = {}
    for layout in node.config.rpdos:
        for signal in layout.signals:
            carried[(signal.index, signal.subindex)] = (
                f"process data: RPDO {layout.number} of the network file carries it"
            )
    return carried


def _typed(var: Variable, value: Any) -> Any:
    """The page's value as the object's type wants it (ValueError says what to give)."""
    dt = var.data_type
    name = _label(var)
    if value is None or isinstance(value, list | dict):
        raise ValueError(f"{name}: give a value of type {dt.name}")
    if dt is DataType.BOOLEAN:
        if isinstance(value, bool):
            return value
        if str(value).strip().lower() in ("1", "true", "on", "yes"):
            return True
        if str(value).strip().lower() in ("0", "false", "off", "no"):
            return False
        raise ValueError(f"{name}: {value!r} is no BOOLEAN (true or false)")
    if dt.is_integer:
        if isinstance(value, bool):
            raise ValueError(f"{name}: {value!r} is no {dt.name}")
        if isinstance(value, float) and value.is_integer():
            return int(value)
        if isinstance(value, int):
            return value
        try:
            return int(str(value).strip(), 0)
        except ValueError:
            raise ValueError(f"{name}: {clip(repr(value))} is no {dt.name} (42, 0x2A)") from None
    if dt.is_real:
        try:
            number = float(value)
        except (TypeError, ValueError, OverflowError):
            raise ValueError(f"{name}: {clip(repr(value))} is no {dt.name}") from None
        if not math.isfinite(number):
            raise ValueError(f"{name}: {clip(repr(value))}: give a finite number")
        return number
    if dt in (DataType.OCTET_STRING, DataType.DOMAIN):
        try:
            return bytes.fromhex(str(value))
        except ValueError:
            raise ValueError(f"{name}: give hex bytes (01 02 AB) for {dt.name}") from None
    return str(value)


def serve_parameters(panel: Panel, master: Any) -> ParameterView:
    """The Parameters page for ``master``'s nodes."""
    return ParameterView(panel, master)
