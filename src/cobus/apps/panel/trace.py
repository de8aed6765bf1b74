"""The Trace page's data: the live bus decoded (:class:`cobus.trace.Decoder`) in the browser.

:func:`serve_trace` decodes every frame of a network (with the network file's EDS files and
PDO layouts when a master's configuration is given: names, signals, units) and publishes the
records in batches, at most ``rate`` times a second:

- state key ``trace/batch``: ``{"first": n, "records": [...], "skipped": k}`` — the records
  numbered from ``first`` decoded since the last batch, the newest ``MAX_BATCH`` of them
  (``skipped`` counts those left out on a busy bus); each record has ``n``, ``time``,
  ``kind`` (nmt, hb, sync, time, emcy, sdo, pdo, lss, other), ``node``, ``cob_id`` and
  ``text``. A page that misses a batch sees the gap in the numbers and says how many
  records it did not show — the bus is never held back by a page;
- state key ``trace/counts``: records per kind since the start.

Pausing and filtering (by node and by service) happen on the page: the decoding goes on.

Decoding costs the bus loop a few microseconds a frame (and a network with a frame monitor
leaves its fast path), so it runs only while a page shows the Trace: such a page sends
``{"cmd": "trace.watch"}`` every few seconds, and decoding stops ``WATCH`` seconds after the
last one (it starts afresh with the next).
"""

from __future__ import annotations

from collections import Counter
from typing import Any

from cobus.apps.panel.server import Panel
from cobus.proto import Frame
from cobus.trace import Decoder

__all__ = ["TraceView", "serve_trace"]

#: The most records one batch carries (the newest; the others are counted as skipped).
MAX_BATCH = 300
#: Seconds decoding goes on after the last ``trace.watch``.
WATCH = 6.0


class TraceView:
    """What :func:`serve_trace` attaches: a decoder on the network's frames."""

    def __init__(self, panel: Panel, network: Any, config: Any = None) -> None:
        self.panel = panel
        self.network = network
        self.config = config
        self.decoder = Decoder(network=config)
        self.count = 0
        self.counts: Counter[str] = Counter()
        self._batch: list[dict[str, Any]] = []
        self._skipped = 0
        self._subscription: Any = None
        self._until = 0.0
        panel.hub.set_info("trace", {"max_batch": MAX_BATCH, "watch": WATCH})
        panel.sample(self.sample)
        panel.command(
            "trace.watch", self._watch, writes=False, help="decode the bus for a few seconds"
        )

    @property
    def decoding(self) -> bool:
        """Whether frames are decoded now (a page showed the Trace lately)."""
        return self._subscription is not None

    async def _watch(self, _message: Any) -> dict[str, Any]:
        self._until = self.network.time() + WATCH
        if self._subscription is None:
            self.decoder = Decoder(network=self.config)  # (afresh: no half transfer kept)
            self._subscription = self.network.subscribe_all(self._on_frame)
        return {"decoding": True, "for": WATCH}

    def close(self) -> None:
        """Stop decoding."""
        if self._subscription is not None:
            self._subscription.cancel()
            self._subscription = None

    def _on_frame(self, frame: Frame, now: float) -> None:
        try:
            records = self.decoder.feed(frame, now)
        except Exception:  # (a decoder bug must never reach the bus loop)
            return
        for record in records:
            self.count += 1
            kind = record.kind
            self.counts[kind] += 1
            self._batch.append(
                {
                    "n": self.count,
                    "time": record.time,
                    "kind": kind,
                    "node": getattr(record, "node", None),
                    "cob_id": record.cob_id,
                    "text": str(record),
                }
            )
            if len(self._batch) > 2 * MAX_BATCH:  # (keep the newest, count the rest)
                drop = len(self._batch) - MAX_BATCH
                self._skipped += drop
                del self._batch[:drop]

    def sample(self) -> dict[str, Any]:
        """The records decoded since the last sample (see the module text)."""
        if self._subscription is not None and self.network.time() > self._until:
            self.close()  # nobody watches: the bus loop is spared the decoding
        if not self._batch:
            return {"trace/counts": dict(self.counts)}
        pending, self._batch = self._batch, []
        batch = pending[-MAX_BATCH:]
        skipped = self._skipped + len(pending) - len(batch)
        self._skipped = 0
        return {
            "trace/batch": {"first": batch[0]["n"], "records": batch, "skipped": skipped},
            "trace/counts": dict(self.counts),
        }


def serve_trace(panel: Panel, network: Any, config: Any = None) -> TraceView:
    """The Trace page for the frames of ``network`` (an :class:`~cobus.runtime.AsyncNetwork`),
    decoded with ``config``'s EDS files and PDO layouts (a master's network configuration)."""
    return TraceView(panel, network, config)
