"""Event loops for the runtime: real time, and a simulated clock that jumps to the next timer.

:class:`SimulatedEventLoop` is an ordinary asyncio selector loop whose ``time()`` is a virtual
clock. Whenever the loop would sleep until its next timer, the clock jumps there instead, so a
60-second heartbeat-loss scenario runs in milliseconds and identically every time. Everything
built on asyncio timers (``asyncio.sleep``, ``call_later``, ``wait_for``) follows the virtual
clock. Real I/O (the loop's self-pipe, sockets) is still polled, without waiting.

Sources of input that are not file descriptors — python-can's virtual bus keeps its frames in a
queue — register a *poll hook*: before the clock moves, every hook is called; if any reports
that it delivered something, the loop runs that first and the clock stays where it is.

:class:`RealTimeLoop` is the blocking facade's real-time loop. It holds its protocol lock
whenever it runs, and lets go of it only while it sleeps in ``select``. A bus's reader thread
(and a blocking caller starting an SDO transfer, or reading its answer from the bus:
``cobus.runtime.reading``) may take the lock and run protocol code
directly — the same code the loop would run, never at the same time as the loop — which saves
a hand-over between threads on every frame (issue 20, ``docs/realtime.md``). Under the lock,
``call_soon``/``call_at`` work from that thread too; the holder wakes the loop, when it must,
after letting go of the lock (:meth:`RealTimeLoop.wake_if_pending`).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import selectors
import threading
import time as _time
from collections.abc import Callable, Coroutine, Mapping
from typing import Any, TypeVar

from cobus.runtime.errors import SimulationStalledError

__all__ = [
    "RealTimeLoop",
    "SimulatedEventLoop",
    "SimulationStalledError",
    "new_event_loop",
    "run",
]

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


_FINE = 0.002  # s: shorter waits use select(), whose timeout is not rounded to milliseconds
_COARSE = frozenset(("EpollSelector", "PollSelector", "DevpollSelector"))  # whole ms only


class _SleepingSelector(selectors.BaseSelector):
    """The platform selector, with the owning loop's protocol lock let go while it waits, and
    timers kept to the microsecond: epoll and poll round a wait up to whole milliseconds (a
    1 ms SYNC would be up to 1 ms late), so a longer wait ends up to 1 ms early and the rest,
    under 2 ms, is waited with ``select()``."""

    def __init__(self, owner: RealTimeLoop) -> None:
        self._real = selectors.DefaultSelector()
        self._fine: selectors.BaseSelector | None = (
            selectors.SelectSelector() if type(self._real).__name__ in _COARSE else None
        )
        self._owner = owner

    def register(self, fileobj: Any, events: int, data: Any = None) -> selectors.SelectorKey:
        key = self._real.register(fileobj, events, data)
        if self._fine is not None:
            try:
                self._fine.register(fileobj, events, data)
            except BaseException:
                self._real.unregister(fileobj)  # both or neither
                raise
        return key

    def unregister(self, fileobj: Any) -> selectors.SelectorKey:
        key = self._real.unregister(fileobj)
        if self._fine is not None:
            self._fine.unregister(fileobj)
        return key

    def modify(self, fileobj: Any, events: int, data: Any = None) -> selectors.SelectorKey:
        try:
            key = self._real.modify(fileobj, events, data)
        except BaseException:
            # A refused change (a closed descriptor) leaves it unregistered there: here too.
            if self._fine is not None and fileobj not in self._real.get_map():
                with contextlib.suppress(KeyError, ValueError):
                    self._fine.unregister(fileobj)
            raise
        if self._fine is not None:
            self._fine.modify(fileobj, events, data)
        return key

    def get_map(self) -> Mapping[Any, selectors.SelectorKey]:
        return self._real.get_map()

    def close(self) -> None:
        self._real.close()
        if self._fine is not None:
            self._fine.close()

    def _wait(self, timeout: float | None) -> list[tuple[selectors.SelectorKey, int]]:
        fine = self._fine
        if fine is None or timeout is None or timeout <= 0:
            return self._real.select(timeout)
        if timeout >= _FINE:
            return self._real.select(timeout - 0.001)  # rounded up: at most 1 ms early
        try:
            return fine.select(timeout)
        except (ValueError, OSError):  # a descriptor select() cannot take (FD_SETSIZE)
            return self._real.select(timeout)

    def select(self, timeout: float | None = None) -> list[tuple[selectors.SelectorKey, int]]:
        owner = self._owner
        lock = owner.protocol_lock
        if timeout == 0 or not owner.lock_held():
            owner._run_wakes()  # (on a turn with work left the loop keeps the lock)
            return self._wait(timeout)
        # Until when the loop sleeps: a timer set meanwhile from another thread wakes it only
        # if it is due earlier (see RealTimeLoop.call_at).
        owner._sleeping_until = math.inf if timeout is None else owner.time() + timeout
        state = lock._release_save()  # type: ignore[attr-defined]
        try:
            owner._run_wakes()
            return self._wait(timeout)
        finally:
            lock._acquire_restore(state)  # type: ignore[attr-defined]
            owner._sleeping_until = None
            owner.wake_pending = False  # awake: what was scheduled runs in this iteration


class RealTimeLoop(asyncio.SelectorEventLoop):
    """A real-time selector loop that runs under its protocol lock (see the module
    docstring): another thread holding the lock may run protocol code and schedule
    callbacks and timers as if it were the loop."""

    def __init__(self) -> None:
        self._sleeping_until: float | None = None
        #: Set when a holder of the lock scheduled work the sleeping loop must wake for:
        #: the holder calls :meth:`wake_if_pending` once it has let go of the lock (waking the
        #: loop before would only make it wait for the lock).
        self.wake_pending = False
        # Threads to wake (lock releases) once the holder of the protocol lock lets go of it
        # (see wake_after_release), kept by the holding thread: each holder runs only its
        # own, so Ctrl-C in the main thread cannot drop another thread's wake-up.
        self._held = threading.local()
        #: The protocol lock: re-entrant, and every operation on it one call into C, so that
        #: Ctrl-C cannot leave it half taken.
        self.protocol_lock = threading.RLock()
        super().__init__(selector=_SleepingSelector(self))

    #: asyncio's clock, called as a C function: ``BaseEventLoop.time`` is a Python method
    #: around it, called several times for every frame received and every turn of the loop.
    time = staticmethod(_time.monotonic)

    def lock_held(self) -> bool:
        """Whether the calling thread holds the protocol lock."""
        return bool(self.protocol_lock._is_owned())  # type: ignore[attr-defined]

    def wake_after_release(self, wake: Callable[[], object]) -> None:
        """Call ``wake`` (it releases a thread waiting for an outcome of protocol code) once
        the caller, who holds the protocol lock, has let go of it; at once if it does not
        hold it.

        A thread woken while the holder still runs Python code would only wait again, for
        the GIL or the lock: one more sleep and wake-up per call (issue 20). The loop thread
        wakes such threads when it is about to sleep, or on a turn with work left, before
        looking at its descriptors; another holder when it calls :meth:`wake_if_pending`.
        """
        if not self.protocol_lock._is_owned():  # type: ignore[attr-defined]
            wake()
            return
        held = self._held
        try:
            held.wakes.append(wake)
        except AttributeError:  # this thread's first
            held.wakes = [wake]

    def _run_wakes(self) -> None:
        held = self._held
        wakes: list[Callable[[], object]] | None = getattr(held, "wakes", None)
        if wakes:
            held.wakes = []
            for wake in wakes:
                wake()

    def wake_if_pending(self) -> None:
        """Wake the threads and the loop that work done under the lock has to wake; call
        after letting go of the lock."""
        held = self._held  # _run_wakes(), inline: a blocking SDO transfer calls this
        wakes: list[Callable[[], object]] | None = getattr(held, "wakes", None)
        if wakes:
            held.wakes = []
            for wake in wakes:
                wake()
        if self.wake_pending:
            self.wake_pending = False
            self._write_to_self()  # type: ignore[attr-defined]  # asyncio's self-pipe

    def run_forever(self) -> None:
        try:
            with self.protocol_lock:
                super().run_forever()
        finally:
            self._run_wakes()

    def call_soon(  # type: ignore[override]  # asyncio's stubs type the arguments variadically
        self, callback: Callable[..., object], *args: Any, context: Any = None
    ) -> asyncio.Handle:
        handle = super().call_soon(callback, *args, context=context)
        if self._sleeping_until is not None and self.lock_held():
            self.wake_pending = True
        return handle

    def call_at(  # type: ignore[override]
        self, when: float, callback: Callable[..., object], *args: Any, context: Any = None
    ) -> asyncio.TimerHandle:
        timer = super().call_at(when, callback, *args, context=context)
        sleeping_until = self._sleeping_until
        if sleeping_until is not None and when < sleeping_until and self.lock_held():
            self.wake_pending = True
        return timer

    def _check_thread(self) -> None:  # asyncio's debug-mode check: the lock's holder may call
        if not self.lock_held():
            super()._check_thread()  # type: ignore[misc]


def run(main: Coroutine[Any, Any, T], *, debug: bool | None = None) -> T:
    """``asyncio.run(main)`` on a :class:`RealTimeLoop`: the asyncio API with the reader
    threads dispatching frames directly (one hand-over fewer per frame; see
    ``docs/realtime.md``). Frame handlers then run in a reader thread, under the loop's
    protocol lock, with the loop as their running loop (``asyncio.create_task`` works)."""
    with asyncio.Runner(debug=debug, loop_factory=RealTimeLoop) as runner:
        return runner.run(main)


def new_event_loop(*, simulated: bool = False, start: float = 0.0) -> asyncio.AbstractEventLoop:
    """A new loop: a :class:`RealTimeLoop`, or a :class:`SimulatedEventLoop`."""
    if simulated:
        return SimulatedEventLoop(start)
    return RealTimeLoop()
