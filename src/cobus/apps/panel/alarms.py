"""The Alarms page's data: an :class:`~cobus.blocks.alarms.AlarmHandler` seen by the panel.

:func:`serve_alarms` connects an alarm handler to a :class:`~cobus.apps.panel.Panel`:

- state keys ``alarms/current`` (the rotating current alarm, as the thesis panel shows it:
  each active alarm in turn for the handler's ``view_time``; None when none is active),
  ``alarms/active`` (every active alarm, oldest first) and ``alarms/summary`` (how many, how
  many unacknowledged, the worst severity);
- an event (``kind`` "alarm", ``action`` raised / cleared / acknowledged) for each change;
- the commands ``alarm.ack`` (``{"source", "node", "code"}`` for one alarm, ``{"all": true}``
  for every unacknowledged one; it changes the controller's state, so a panel that needs a
  token needs it here too) and ``alarm.history`` (the history's activations, newest first,
  filtered by ``node``, ``source``, ``code``, ``active``, ``since`` / ``until`` in seconds
  since the epoch, at most ``limit`` rows, 1000 at most);
- ``GET /alarms.csv`` with the same filters as query parameters: the history as CSV, newest
  first, at most ``MAX_CSV`` rows (narrow it with ``since``).

History reads run in a worker thread (SQLite): a long history never holds the bus loop.
"""

from __future__ import annotations

import asyncio
import io
import math
from collections.abc import Mapping
from typing import Any

from aiohttp import web

from cobus.apps.panel.server import CommandError, Panel
from cobus.blocks.alarms import (
    Alarm,
    AlarmAcknowledged,
    AlarmCleared,
    AlarmEvent,
    AlarmHandler,
    AlarmRaised,
)
from cobus.errors import clip

__all__ = ["AlarmView", "serve_alarms"]

#: The most history rows one ``alarm.history`` answer carries.
MAX_ROWS = 1000
#: The most rows one CSV export carries (the newest).
MAX_CSV = 20_000
#: Who acknowledged, when the page does not say (at most this many characters if it does).
DEFAULT_BY = "panel"
MAX_BY = 40


def alarm_dict(alarm: Alarm) -> dict[str, Any]:
    """An active alarm as the page gets it (times in seconds since the epoch)."""
    return {
        "source": alarm.source,
        "node": alarm.node,
        "code": alarm.code,
        "code_text": alarm.code_text,
        "text": alarm.text,
        "severity": alarm.severity.name.lower(),
        "raised_at": alarm.raised_at,
        "acknowledged_by": alarm.acknowledged_by,
    }


class AlarmView:
    """What :func:`serve_alarms` attaches: the samples, events, commands and CSV route."""

    def __init__(self, panel: Panel, handler: AlarmHandler) -> None:
        self.panel = panel
        self.handler = handler
        panel.hub.info["alarms"] = {
            "view_time": handler.view_time,
            "history": handler.history is not None,
        }
        panel.sample(self.sample)
        panel.command(
            "alarm.ack",
            self._ack,
            writes=True,
            help="acknowledge an alarm (source, node, code) or all of them (all: true)",
        )
        panel.command(
            "alarm.history",
            self._history,
            writes=False,
            help="the alarm history, newest first (node, source, code, active, since, until)",
        )
        panel.route("GET", "/alarms.csv", self._csv)
        handler.add_listener(self._on_event)

    def close(self) -> None:
        """Stop listening to the handler."""
        self.handler.remove_listener(self._on_event)

    def sample(self) -> dict[str, Any]:
        """The current, active and summary keys (see the module text)."""
        handler = self.handler
        active = handler.active
        current = handler.current()
        worst = max((a.severity for a in active), default=None)
        return {
            "alarms/current": None if current is None else alarm_dict(current),
            "alarms/active": [alarm_dict(a) for a in active],
            "alarms/summary": {
                "active": len(active),
                "unacknowledged": sum(1 for a in active if not a.acknowledged),
                "worst": None if worst is None else worst.name.lower(),
            },
        }

    def _on_event(self, event: AlarmEvent) -> None:
        action = {
            AlarmRaised: "raised",
            AlarmCleared: "cleared",
            AlarmAcknowledged: "acknowledged",
        }.get(type(event), "changed")
        alarm = event.alarm
        self.panel.hub.event(
            "alarm",
            action=action,
            node=alarm.node,
            level="problem" if action == "raised" and alarm.severity.name != "INFO" else "info",
            text=f"alarm {action}: {alarm}",
            alarm=alarm_dict(alarm),
        )
        # the page's lists follow at once, not at the next sample
        self.panel.hub.update(self.sample())

    # ------------------------------------------------------------------ commands
    async def _ack(self, message: Mapping[str, Any]) -> dict[str, Any]:
        by = message.get("by", DEFAULT_BY)
        if not isinstance(by, str) or not by.strip() or len(by) > MAX_BY:
            raise ValueError(f"by: who acknowledges, a text of 1-{MAX_BY} characters")
        by = by.strip()
        if message.get("all") is True:
            return {"acknowledged": self.handler.acknowledge(by=by)}
        source = message.get("source")
        node = message.get("node")
        code = message.get("code")
        if not isinstance(source, str):
            raise ValueError('give source, node and code of the alarm, or "all": true')
        if node is not None and (isinstance(node, bool) or not isinstance(node, int)):
            raise ValueError(f"node {node!r}: a node-ID or null")
        if isinstance(code, bool) or not isinstance(code, int):
            raise ValueError(f"code {code!r}: the alarm's number")
        key = (source, node, code)
        if not any(a.key == key for a in self.handler.active):
            raise CommandError("no-alarm", f"no active alarm {source} {code} of node {node}")
        return {"acknowledged": self.handler.acknowledge(key, by=by)}

    async def _history(self, message: Mapping[str, Any]) -> list[dict[str, Any]]:
        filters = _filters(message)
        limit = message.get("limit", 200)
        if isinstance(limit, bool) or not isinstance(limit, int) or not 1 <= limit <= MAX_ROWS:
            raise ValueError(f"limit {limit!r}: 1-{MAX_ROWS} rows")
        history = self.handler.history
        if history is None:
            raise CommandError("no-history", "this controller keeps no alarm history file")
        records = await asyncio.to_thread(history.query, limit=limit, **filters)
        return [
            {
                "id": r.id,
                "raised_at": r.raised_at,
                "cleared_at": r.cleared_at,
                "node": r.node,
                "source": r.source,
                "code": r.code,
                "text": r.text,
                "severity": r.severity,
                "acknowledged_at": r.acknowledged_at,
                "acknowledged_by": r.acknowledged_by,
            }
            for r in records
        ]

    async def _csv(self, request: web.Request) -> web.StreamResponse:
        history = self.handler.history
        if history is None:
            raise web.HTTPNotFound(text="this controller keeps no alarm history file\n")
        query: dict[str, Any] = {}
        try:
            for key, value in request.query.items():
                if key in ("node", "code"):
                    query[key] = int(value, 0)
                elif key in ("since", "until"):
                    query[key] = float(value)
                elif key == "active":
                    query[key] = value.lower() in ("1", "true", "yes")
                elif key == "source":
                    query[key] = value
            filters = _filters(query)
        except (ValueError, OverflowError) as exc:
            raise web.HTTPBadRequest(text=f"{clip(str(exc))}\n") from None
        out = io.StringIO()
        # (bounded: the history's lock is held while it is read, and an alarm raised
        # meanwhile waits for it)
        await asyncio.to_thread(
            history.export_csv, out, limit=MAX_CSV, newest_first=True, **filters
        )
        return web.Response(
            text=out.getvalue(),
            content_type="text/csv",
            headers={"Content-Disposition": 'attachment; filename="alarms.csv"'},
        )


def _filters(message: Mapping[str, Any]) -> dict[str, Any]:
    """The history filters of a command or query, checked (ValueError says which is wrong)."""
    filters: dict[str, Any] = {}
    for key, top in (("node", 127), ("code", 2**32 - 1)):
        value = message.get(key)
        if value is not None:
            if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= top:
                raise ValueError(f"{key} {clip(repr(value))}: a number 0-{top}")
            filters[key] = value
    source = message.get("source")
    if source is not None:
        if not isinstance(source, str) or len(source) > 40:
            raise ValueError(f"source {source!r}: a source name (emcy, master, zapi...)")
        filters["source"] = source
    active = message.get("active")
    if active is not None:
        if not isinstance(active, bool):
            raise ValueError(f"active {active!r}: true (only active) or false (only cleared)")
        filters["active"] = active
    for key in ("since", "until"):
        value = message.get(key)
        if value is not None:
            if (
                isinstance(value, bool)
                or not isinstance(value, int | float)
                or not math.isfinite(value)
            ):
                raise ValueError(f"{key} {value!r}: seconds since 1970")
            filters[key] = float(value)
    return filters


def serve_alarms(panel: Panel, handler: AlarmHandler) -> AlarmView:
    """Show ``handler`` on ``panel`` (the Alarms page and the current-alarm line)."""
    return AlarmView(panel, handler)
