"""The Network page's data: a running :class:`~cobus.master.Master` seen by the panel.

:func:`serve_master` connects a master to a :class:`~cobus.apps.panel.Panel`:

- state keys ``node/<id>`` (the master's view of each node: NMT state, node state and
  diagnostic code with their texts, CiA 303-3 LEDs, EMCY count, error control, problem, device
  name and identity), ``heard/<id>`` (the network time of the node's last heartbeat or guarding
  answer: pages show its age against the snapshot's and deltas' ``time``), ``master`` (its
  state, status and bus diagnostics) and ``bus_load`` (per cent, plotted);
- an event for each of the master's events (``kind`` "master", its class as ``name``, its text,
  the node, and ``level`` "problem" or "info");
- the command ``nmt`` (writes): ``{"cmd": "nmt", "node": 10 | "all", "action": "start" |
  "stop" | "preop" | "reset" | "reset-comm"}``, for managed nodes or all of them.

The device name (1008h) and the vendor and product (1018h sub 1 and 2) are read once per node by
SDO after the master has started it, through the master's own SDO channel; until then the page
shows the names the node's EDS gives.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Mapping
from typing import Any

from cobus.apps.panel.server import CommandError, Panel
from cobus.errors import CobusError
from cobus.master import Master, MasterEvent
from cobus.master.states import NodeState

__all__ = ["NMT_ACTIONS", "MasterView", "serve_master"]

#: The ``nmt`` command's actions, and the NMT command specifier each sends (CiA 301).
NMT_ACTIONS = {"start": 0x01, "stop": 0x02, "preop": 0x80, "reset": 0x81, "reset-comm": 0x82}

#: Master events that tell of a problem (the page marks them); the others are information.
PROBLEMS = frozenset(
    {
        "BootStepFailed",
        "ConfigurationFailed",
        "DeviceTypeMismatch",
        "ErrorControlLost",
        "GuardingToggleFault",
        "IdentityMismatch",
        "NetworkStopped",
        "NodeEmergency",
        "NodeMissing",
        "SdoUnanswered",
        "TpdoLengthError",
        "TpdoMissing",
        "UnexpectedState",
    }
)

_IDENTITY_READ_TIMEOUT = 1.0


class MasterView:
    """What :func:`serve_master` attaches: the samples, events and commands of one master."""

    def __init__(self, panel: Panel, master: Master) -> None:
        self.panel = panel
        self.master = master
        #: What the nodes said of themselves by SDO (1008h, 1018h), by node-ID.
        self.device: dict[int, dict[str, Any]] = {}
        self._reading: set[int] = set()
        #: What each node's key was built from at the last sample (unchanged: not built).
        self._last: dict[int, tuple[Any, ...]] = {}
        self._heard: dict[int, float | None] = {}
        self._tasks: set[asyncio.Task[None]] = set()
        panel.hub.info["nodes"] = [
            {
                "id": node.node_id,
                "name": node.name,
                "product": node.config.od.device_info.product_name,
                "vendor": node.config.od.device_info.vendor_name,
                "mandatory": node.mandatory,
            }
            for node in master.nodes.values()
        ]
        panel.hub.info["bitrate"] = master.config.master.bitrate
        panel.hub.plot("bus_load")
        panel.sample(self.sample)
        panel.command(
            "nmt",
            self._nmt,
            writes=True,
            help="NMT command to a node or all: node, action (start, stop, preop, reset...)",
        )
        master.add_listener(self._on_event)
        panel.views["network"] = self

    def close(self) -> None:
        """Stop listening to the master and cancel the identity reads under way."""
        self.master.remove_listener(self._on_event)
        for task in self._tasks:
            task.cancel()

    # ------------------------------------------------------------------ samples
    def sample(self) -> dict[str, Any]:
        """The master and its nodes as state keys (see the module text): the nodes whose
        state changed since the last sample (all of them the first time), and the master."""
        master = self.master
        diag = master.diagnostics
        values: dict[str, Any] = {}
        last = self._last
        seen_now: dict[int, tuple[Any, ...]] = {}
        for node_id, node in master.nodes.items():
            leds = node.led
            state = node.state
            nmt = node.nmt_state
            seen = (
                nmt,
                state,
                node.diagnostic,
                leds.run,
                leds.error,
                node.emcy_count,
                node.error_control,
                node.problem,
                self.device.get(node_id),
            )
            if last.get(node_id) != seen:
                seen_now[node_id] = seen
                diagnostic = node.diagnostic
                values[f"node/{node_id}"] = {
                    "id": node_id,
                    "name": node.name,
                    "nmt": None if nmt is None else nmt.name,
                    "state": int(state),
                    "state_text": state.text,
                    "diagnostic": int(diagnostic),
                    "diagnostic_text": diagnostic.text,
                    "run_led": leds.run.value,
                    "error_led": leds.error.value,
                    "emcy": node.emcy_count,
                    "error_control": node.error_control,
                    "problem": node.problem,
                    "device": self.device.get(node_id, {}),
                }
            heard = node.heard_at
            if heard != self._heard.get(node_id, -1.0):
                self._heard[node_id] = heard
                values[f"heard/{node_id}"] = heard
            if state is NodeState.OPERATIONAL and node_id not in self._reading:
                self._read_device(node_id)
        last.update(seen_now)  # (only once all is built: a failed sample sends them next time)
        values["master"] = {
            "state": master.state.name,
            "status": master.status.name,
            "bus_state": diag.bus_state.name,
            "tx_errors": diag.tx_errors,
            "rx_errors": diag.rx_errors,
            "bus_off_count": diag.bus_off_count,
            "frames": diag.frames,
            "sync_count": diag.sync_count,
            "send_errors": diag.send_errors,
        }
        values["bus_load"] = round(master.bus_load, 1)
        return values

    def _read_device(self, node_id: int) -> None:
        self._reading.add(node_id)
        task = asyncio.create_task(self._identify(node_id), name=f"cobus panel 1008h {node_id}")
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _identify(self, node_id: int) -> None:
        node = self.master.nodes[node_id]
        found: dict[str, Any] = {}
        for key, index, sub in (
            ("name", 0x1008, 0),
            ("vendor_id", 0x1018, 1),
            ("product_code", 0x1018, 2),
        ):
            with contextlib.suppress(CobusError, TimeoutError, KeyError, ValueError):
                value = await asyncio.wait_for(
                    node.sdo.upload(index, sub), _IDENTITY_READ_TIMEOUT * 2
                )
                found[key] = (
                    value.rstrip(b"\0").decode("latin-1", "replace")
                    if key == "name"
                    else int.from_bytes(value[:4], "little")
                )
        self.device[node_id] = found

    # ------------------------------------------------------------------ events
    def _on_event(self, event: MasterEvent) -> None:
        name = type(event).__name__
        self.panel.hub.event(
            "master",
            name=name,
            node=getattr(event, "node_id", None),
            level="problem" if name in PROBLEMS else "info",
            text=str(event),
        )

    # ------------------------------------------------------------------ commands
    async def _nmt(self, message: Mapping[str, Any]) -> dict[str, Any]:
        action = message.get("action")
        if not isinstance(action, str) or action not in NMT_ACTIONS:
            raise ValueError(f"action {action!r}: one of {', '.join(NMT_ACTIONS)}")
        target = message.get("node")
        nmt = self.master.network.nmt
        command = NMT_ACTIONS[action]
        if target == "all":
            nmt.send(command, 0)
            return {"node": "all", "action": action}
        if isinstance(target, bool) or not isinstance(target, int):
            raise ValueError(f'node {target!r}: a node-ID of this network or "all"')
        if target not in self.master.nodes:
            known = ", ".join(str(n) for n in sorted(self.master.nodes)) or "none"
            raise CommandError("no-node", f"node {target} is not in this network (nodes: {known})")
        nmt.send(command, target)
        return {"node": target, "action": action}


def serve_master(panel: Panel, master: Master) -> MasterView:
    """Show ``master`` on ``panel`` (the Network page); the view (``close()`` detaches it)."""
    return MasterView(panel, master)
