"""Event loops for the runtime: real time, and a simulated clock that jumps to the next timer.

:class:`SimulatedEventLoop` is an ordinary asyncio selector loop whose ``time()`` is a virtual
clock. Whenever the loop would sleep until its next timer, the clock jumps there instead, so a
60-second heartbeat-loss scenario runs in milliseconds and identically every time. Everything
built on asyncio timers (``asyncio.sleep``, ``call_later``, ``wait_for``) follows the virtual
clock. Real I/O (the loop's self-pipe, sockets) is still polled, without waiting.

Sources of input that are not file descriptors — python-can's virtual bus keeps its frames in a
queue — register a *poll hook*: before the clock moves, every hook is called; if any reports
that it delivered something, the loop runs that first and the clock stays where it is.
"""

from __future__ import annotations

import asyncio
import selectors
from collections.abc import Callable, Coroutine, Mapping
from typing import Any, TypeVar

from cobus.runtime.errors import SimulationStalledError

__all__ = ["SimulatedEventLoop", "SimulationStalledError", "new_event_loop"]

PollHook = Callable[[], bool]
T = TypeVar("T")


class _VirtualSelector(selectors.BaseSelector):
    """A selector that never blocks: it moves the owning loop's clock instead."""

    def __init__(self, owner: SimulatedEventLoop) -> None:
        self._real = selectors.DefaultSelector()
        self._owner = owner

    def register(self, fileobj: Any, events: int, data: Any = None) -> selectors.SelectorKey:
        return self._real.register(fileobj, events, data)

    def unregister(self, fileobj: Any) -> selectors.SelectorKey:
        return self._real.unregister(fileobj)

    def modify(self, fileobj: Any, events: int, data: Any = None) -> selectors.SelectorKey:
        return self._real.modify(fileobj, events, data)

    def get_map(self) -> Mapping[Any, selectors.SelectorKey]:
        return self._real.get_map()

    def close(self) -> None:
        self._real.close()

    def select(self, timeout: float | None = None) -> list[tuple[selectors.SelectorKey, int]]:
        ready = self._real.select(0)
        if ready or timeout == 0:
            return ready
        if self._owner._run_poll_hooks():
            return []
        if timeout is None:
            raise SimulationStalledError(
                "simulated clock: nothing is scheduled and no frame is pending, so the awaited "
                "operation can never finish (give it a timeout, or check that its peer exists)"
            )
        self._owner._advance(timeout)
        return []


class SimulatedEventLoop(asyncio.SelectorEventLoop):
    """An asyncio loop on a virtual clock that starts at ``start`` seconds."""

    def __init__(self, start: float = 0.0) -> None:
        self._virtual_now = float(start)
        self._poll_hooks: list[PollHook] = []
        super().__init__(selector=_VirtualSelector(self))

    def time(self) -> float:
        return self._virtual_now

    def add_poll_hook(self, hook: PollHook) -> None:
        """Call ``hook()`` before each jump of the clock; it returns True if it delivered input."""
        self._poll_hooks.append(hook)

    def remove_poll_hook(self, hook: PollHook) -> None:
        """Stop calling ``hook`` (given to :meth:`add_poll_hook`)."""
        if hook in self._poll_hooks:
            self._poll_hooks.remove(hook)

    def start_first(self, coro: Coroutine[Any, Any, T]) -> asyncio.Task[T]:
        """A task for ``coro`` whose first step runs before the callbacks already queued.

        That is what ``await coro`` does in async code: the coroutine runs at once, up to its
        first wait. Blocking code on the simulated clock uses it, so that an operation that
        waits for an answer (``wait_for_bootup()`` right after ``reset_node()``) is listening
        before the frames sent just before it are delivered, exactly as in async code.
        """
        ready = self._ready  # type: ignore[attr-defined]  # asyncio's queue of callbacks
        before = len(ready)
        task = self.create_task(coro)
        if len(ready) == before + 1:  # its first step was queued last: it goes first
            ready.rotate(1)
        return task

    def _run_poll_hooks(self) -> bool:
        progressed = False
        for hook in list(self._poll_hooks):
            if hook():
                progressed = True
        return progressed

    def _advance(self, seconds: float) -> None:
        if seconds > 0:
            self._virtual_now += seconds


def new_event_loop(*, simulated: bool = False, start: float = 0.0) -> asyncio.AbstractEventLoop:
    """A new loop: the platform's default, or a :class:`SimulatedEventLoop`."""
    if simulated:
        return SimulatedEventLoop(start)
    return asyncio.new_event_loop()
