"""What the panel publishes, and what each browser still has to be sent.

The :class:`Hub` keeps the panel's state as keyed values (``"node/10"``, ``"master"``...) and a
numbered stream of events (an alarm, an EMCY, an NMT change). Each browser is a
:class:`Client` with a bounded queue:

- **telemetry is conflated**: a value changed ten times before the browser took it is sent
  once, as its latest value, so the queue holds at most one entry per key;
- **events are kept**, in order, each with its sequence number, up to ``max_events``; a client
  that falls further behind loses its queued events and is sent a fresh snapshot instead
  (``resync``), so it never shows a gap silently;
- **answers to commands** are sent first, one per command;
- **a stuck client is dropped**: one whose send has not finished for ``stall`` seconds is
  closed (:meth:`Hub.check`), so a slow or vanished browser never holds the bus back.

No I/O here: the server (:mod:`cobus.apps.panel.server`) moves what :meth:`Client.messages` and
:meth:`Client.delta` give onto its WebSocket.
"""

from __future__ import annotations

import asyncio
import math
from collections import deque
from collections.abc import Callable, Mapping
from typing import Any

__all__ = ["Client", "Hub"]

#: Events a snapshot carries (the newest), so a page opened late still lists what happened.
RECENT_EVENTS = 200
#: Samples kept per plotted key (a minute at 10 Hz).
SERIES_LENGTH = 600


class Client:
    """One browser's queue: the values changed since it was last sent some, the events not
    yet sent, and whether it needs a whole snapshot."""

    def __init__(self, hub: Hub, name: str) -> None:
        self.hub = hub
        self.name = name
        #: The latest value of each key changed since the last delta.
        self.values: dict[str, Any] = {}
        self.events: deque[dict[str, Any]] = deque()
        #: Answers to the client's commands not yet sent.
        self.replies: deque[dict[str, Any]] = deque()
        #: A snapshot is due (at connect, after an overflow, or asked for).
        self.resync = True
        #: Set whenever there is something to send.
        self.ready = asyncio.Event()
        self.ready.set()
        #: When the send under way began (None: none is).
        self.sending_since: float | None = None
        #: Events dropped by overflows, and snapshots sent because of them.
        self.overflows = 0
        #: Why the client was closed ("" while it is open).
        self.closed = ""
        #: Ends the client's connection at once (the server sets it; a stalled client's
        #: send never finishes, so closing it politely would wait for ever).
        self.abort: Callable[[], None] | None = None

    def __repr__(self) -> str:
        return f"<panel client {self.name} {len(self.events)} events {len(self.values)} values>"

    @property
    def depth(self) -> int:
        """Entries waiting: queued events plus conflated values."""
        return len(self.events) + len(self.values) + len(self.replies)

    def reply(self, message: dict[str, Any]) -> None:
        """Queue the answer to one of the client's commands (sent before events)."""
        self.replies.append(message)
        self.ready.set()

    def messages(self) -> list[dict[str, Any]]:
        """What to send now, in order: the replies, then a snapshot if one is due (it replaces
        the queued events and values), else the queued events."""
        out = list(self.replies)
        self.replies.clear()
        if self.resync:
            snapshot = self.hub.snapshot()  # (what its sample changes is in it already)
            self.resync = False
            self.events.clear()
            self.values = {}
            out.append(snapshot)
        else:
            out.extend({"type": "event", **e} for e in self.events)
            self.events.clear()
        if not self.values:
            self.ready.clear()
        return out

    def delta(self) -> dict[str, Any]:
        """The values changed since the last delta (the latest of each), as a message."""
        values, self.values = self.values, {}
        if not self.replies and not self.events and not self.resync:
            self.ready.clear()
        return {"type": "delta", "time": self.hub.clock(), "values": values}

    def close(self, reason: str) -> None:
        """Mark the client closed (its server connection ends it) and wake its sender."""
        if not self.closed:
            self.closed = reason
            self.hub.clients.discard(self)
            self.ready.set()


class Hub:
    """The panel's state and event stream, fanned out to its clients (see the module text).

    ``clock`` gives the time for events and stall checks (the network's clock)."""

    def __init__(
        self,
        clock: Callable[[], float],
        *,
        max_events: int = 500,
        stall: float = 5.0,
    ) -> None:
        if max_events < 1:
            raise ValueError(f"max_events must be at least 1, not {max_events}")
        if not stall > 0:
            raise ValueError(f"stall must be a positive number of seconds, not {stall}")
        self.clock = clock
        self.max_events = max_events
        self.stall = stall
        #: The latest value of every key.
        self.state: dict[str, Any] = {}
        #: The number of the last event (0: none yet).
        self.seq = 0
        self.recent: deque[dict[str, Any]] = deque(maxlen=RECENT_EVENTS)
        #: For plotted keys: (time, value) samples, oldest first.
        self.series: dict[str, deque[tuple[float, float]]] = {}
        self.clients: set[Client] = set()
        #: Static facts a page needs once (sent in every snapshot).
        self.info: dict[str, Any] = {}
        #: Clients dropped because they stalled, since start.
        self.dropped = 0
        #: Called before each snapshot, so that it carries the state as it is now.
        self.before_snapshot: Callable[[], None] | None = None
        self._names = 0

    # ------------------------------------------------------------------ clients
    def connect(self) -> Client:
        """A new client; its first message is a snapshot."""
        self._names += 1
        client = Client(self, f"#{self._names}")
        self.clients.add(client)
        return client

    def snapshot(self) -> dict[str, Any]:
        """Everything a page needs to draw itself: state, recent events, plotted series."""
        if self.before_snapshot is not None:
            self.before_snapshot()
        return {
            "type": "snapshot",
            "seq": self.seq,
            "time": self.clock(),
            "info": self.info,
            "state": dict(self.state),
            "events": list(self.recent),
            "series": {key: [list(s) for s in samples] for key, samples in self.series.items()},
        }

    def check(self) -> list[Client]:
        """Close the clients whose send has been under way for ``stall`` seconds or more;
        the ones closed."""
        now = self.clock()
        stuck = [
            c
            for c in self.clients
            if c.sending_since is not None and now - c.sending_since >= self.stall
        ]
        for client in stuck:
            self.dropped += 1
            client.close(f"stalled: a send took more than {self.stall:g} s")
            if client.abort is not None:
                client.abort()
        return stuck

    def set_info(self, key: str, value: Any) -> None:
        """Change one of the static facts; every client gets a new snapshot with it (a view
        added after pages connected, e.g. a drive once the network booted)."""
        self.info[key] = value
        for client in self.clients:
            client.resync = True
            client.ready.set()

    # ------------------------------------------------------------------ publishing
    def plot(self, key: str) -> None:
        """Keep a time series of ``key``'s numeric values (sent in snapshots)."""
        self.series.setdefault(key, deque(maxlen=SERIES_LENGTH))

    def update(self, values: Mapping[str, Any]) -> dict[str, Any]:
        """Set keys to new values; the ones that changed go to every client (conflated).
        Returns the changed ones."""
        changed = {
            k: v
            for k, v in map(_finite, values.items())
            if k not in self.state or self.state[k] != v
        }
        if not changed:
            return changed
        now = self.clock()
        self.state.update(changed)
        for key, value in changed.items():
            series = self.series.get(key)
            if series is not None and isinstance(value, int | float) and math.isfinite(value):
                series.append((now, float(value)))
        for client in self.clients:
            if not client.resync:
                client.values.update(changed)
            client.ready.set()
        return changed

    def event(self, kind: str, **fields: Any) -> dict[str, Any]:
        """Number ``kind`` with ``fields`` as the next event and queue it for every client.

        A client with ``max_events`` already queued loses them and gets a snapshot."""
        self.seq += 1
        event = {"seq": self.seq, "time": self.clock(), "kind": kind, **fields}
        self.recent.append(event)
        for client in self.clients:
            if client.resync:
                pass  # the snapshot it is due carries this event
            elif len(client.events) >= self.max_events:
                client.overflows += 1
                client.events.clear()
                client.values.clear()
                client.resync = True
            else:
                client.events.append(event)
            client.ready.set()
        return event


def _finite(item: tuple[str, Any]) -> tuple[str, Any]:
    """A value as JSON carries it: NaN and infinities (which JSON has not) become None,
    in lists and mappings too (and NaN, never equal to itself, is not sent every tick)."""
    key, value = item
    return key, _clean(value)


def _clean(value: Any) -> Any:
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_clean(v) for v in value]
    return value
