"""SIGINT's Python handler put aside while the main thread runs code that Ctrl-C must not
cut in two (``docs/realtime.md``): the dispatch of other threads' frames by a reading caller
(``cobus.runtime.reading``), the cancellation of a blocking transfer after a first Ctrl-C
(``cobus.runtime.blocking``). A SIGINT that comes meanwhile is noted, and its handler runs
once the handler is put back.

Python runs signal handlers in the main thread, whichever thread the signal went to, at
almost any bytecode; ``pthread_sigmask`` cannot keep them out. The module's C functions are
used: the ``signal`` module's wrappers convert to enums (~6 µs a call, ~0.5 here).
"""

from __future__ import annotations

import _signal  # type: ignore[import-not-found]
import signal
import threading
from collections.abc import Callable
from types import FrameType
from typing import Any

__all__ = ["ASIDE", "MAIN", "REFUSED", "UNHANDLED", "SigintDeferred", "other_handlers"]

MAIN = threading.main_thread().ident  # where Python runs signal handlers


def other_handlers() -> bool:
    """Whether a signal other than SIGINT has a Python handler (one that could raise in the
    main thread while it dispatches others' frames): ~4 µs, every signal looked at in C."""
    return any(map(callable, map(_signal.getsignal, _OTHER)))


_OTHER = tuple(sorted(set(signal.valid_signals()) - {signal.SIGINT}))
ASIDE, UNHANDLED, REFUSED = 0, 1, 2


class SigintDeferred:
    """SIGINT's Python handler put aside in the main thread (see the module docstring)."""

    __slots__ = ("_frame", "_saved", "hit", "poke")

    def __init__(self, poke: Callable[[], None]) -> None:
        self.poke = poke
        self.hit = False
        self._frame: FrameType | None = None
        self._saved: Any = None

    def put_aside(self) -> int:
        """``ASIDE``: SIGINT's Python handler is put aside; ``UNHANDLED``: it has none (it
        is ignored, or ends the process); ``REFUSED``: it cannot be put aside here (already
        aside, or not the main interpreter). A handler that raises for a SIGINT pending
        already raises here, before anything changed."""
        if self._saved is not None:
            return REFUSED
        saved = _signal.getsignal(signal.SIGINT)
        if saved is None:  # set from C: cannot be put back
            return REFUSED
        if not callable(saved):
            return UNHANDLED
        if saved == self._note:
            return REFUSED
        self.hit = False
        self._frame = None
        try:
            _signal.signal(signal.SIGINT, self._note)
        except ValueError:  # not the main interpreter
            return REFUSED
        self._saved = saved
        return ASIDE

    def _note(self, signum: int, frame: FrameType | None) -> None:
        self.hit = True
        self._frame = frame
        self.poke()

    def restore(self) -> None:
        """Put the handler back, and run it for a SIGINT that came meanwhile."""
        saved = self._saved
        if saved is None:
            return
        _signal.signal(signal.SIGINT, saved)  # (what is pending runs first: _note)
        self._saved = None
        if self.hit:
            self.hit = False
            frame, self._frame = self._frame, None
            saved(signal.SIGINT, frame)
