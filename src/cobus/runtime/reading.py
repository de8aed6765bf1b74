"""Who reads a bus of the blocking network: its reader thread, or a caller waiting for an
answer (leader/follower; ``docs/realtime.md``, "Who reads the bus").

On a bus whose readable descriptor means a whole frame waits (SocketCAN, python-can's
``udp_multicast``), a blocking caller that has sent its request reads the bus itself until its
outcome is there, as a bare python-can script does: the answer wakes one thread, the caller,
where otherwise it wakes the reader thread, which then wakes the caller. One thread reads at a
time: the holder of the *role*.

- The reader thread holds the role while no caller reads. A caller that finds it held waits
  as before (the holder dispatches its answer and wakes it) and says it wants the role: the
  reader thread lets go of it once no waiting caller's outcome is pending, so that the
  caller's next call can take it.
- A caller that takes the role reads and dispatches, under the loop's protocol lock, every
  frame (others' too) until its own outcome is there. An outcome settled by another thread
  (the loop: a timeout, a device in the same process, frames handed to a busy loop) pokes it
  awake through a socket pair. When it lets go while other callers wait, it wakes the reader
  thread, which takes the role at once.
- The reader thread takes the role back only once it has been free for :data:`GRACE`, so
  that back-to-back calls keep it (the request is sent before the caller takes the role);
  meanwhile it looks every 2 ms. While one caller holds the role across its looks (a long
  wait), it looks ever less often (up to :data:`PARK_MAX`), and that caller wakes it when it
  lets go.
- A caller's read that fails gives the role back and keeps callers off it for a while
  (doubling up to a second); the reader thread reports failures and backs off, as always.
- Signals. Python runs signal handlers in the main thread, whatever thread the signal went
  to (so masking a signal there with ``pthread_sigmask`` would not keep it out), at almost
  any bytecode: a handler that raises inside the dispatch of other threads' frames could
  leave their outcomes unreleased or the protocol lock taken. So the main thread reads
  only while no signal but SIGINT has a Python handler (~4 µs to look at them all), and
  with SIGINT's handler put aside for one that notes the signal and pokes the caller: the
  caller gives the role back, the handler is put back and run then (KeyboardInterrupt: the
  transfer is cancelled; a handler that does not raise: the call goes on waiting).
- Frame handlers run with the network's loop as their running loop, whichever thread reads.
"""

from __future__ import annotations

import asyncio
import contextlib
import select
import socket
import threading
import time
from collections.abc import Callable, Sequence
from typing import Protocol

import can

from cobus.runtime._sigint import ASIDE, MAIN, REFUSED, SigintDeferred, other_handlers

__all__ = ["GRACE", "PARK_MAX", "Outcome", "ReadingRole"]

#: s the role stays free after a caller lets go of it before the reader thread takes it back
GRACE = 0.002
#: s at most between two looks of the parked reader thread while one caller holds the role
PARK_MAX = 0.05
_LOOK = 0.002  # s: its first look, and its looks while callers come and go
_READER_WAIT = 0.05  # s: the reader thread's wait for frames, between looks at its stop flag
_CALLER_WAIT = 1.0  # s: a reading caller's wait (it is poked: this only bounds a miss)
_BACKOFF = 0.05  # s callers keep off the role after a failed read, doubling up to 1 s
_ROLE = 0  # the key of the role in the claim dict
_get_running_loop = asyncio.events._get_running_loop
_set_running_loop = asyncio.events._set_running_loop


def _waiter(fds: Sequence[int]) -> Callable[[float], list[int]]:
    """Wait up to ``timeout`` seconds for one of ``fds`` to be readable (or to fail): the
    ones that are. ``poll``, where there is one: ``select`` takes no descriptor above 1023."""
    if not hasattr(select, "poll"):
        return lambda timeout: select.select(fds, (), (), timeout)[0]
    poller = select.poll()
    for fd in fds:
        poller.register(fd, select.POLLIN)

    def wait(timeout: float) -> list[int]:
        return [fd for fd, _ in poller.poll(timeout * 1000.0)]

    return wait


class Outcome(Protocol):
    """What the role needs of a blocking caller's pending outcome (``blocking._Handoff``)."""

    #: set (under the protocol lock) once the outcome is known
    settled: bool
    #: called, by a thread other than ``reader``, once the outcome can be taken
    poke: Callable[[], None] | None
    reader: int

    def ready(self) -> bool:
        """Take the outcome if it is there (true once)."""
        ...

    def block(self) -> None:
        """Wait until the outcome is there, and take it."""
        ...


class ReadingRole:
    """The role of reading one bus (see the module docstring), and its reader thread.

    ``take(bus)`` reads what waits (``recv(0)`` until nothing does, up to a batch);
    ``accept(batch)`` dispatches it under the protocol lock, or hands it to ``loop``, and
    returns False once the loop is closed; ``report(exc)`` tells the network of a failed
    read.
    """

    def __init__(
        self,
        loop: asyncio.AbstractEventLoop,
        bus: can.BusABC,
        fd: int,
        take: Callable[[can.BusABC], list[can.Message]],
        accept: Callable[[list[can.Message]], bool],
        report: Callable[[Exception], None],
    ) -> None:
        self._loop = loop
        self._bus = bus
        self._fd = fd
        self._take = take
        self._accept = accept
        self._report = report
        # The role: the holder's thread ident under _ROLE. dict.setdefault takes it in one
        # call into C, so that it is taken or not, never half.
        self._claim: dict[int, int] = {}
        self._park = threading.Lock()  # held; released to wake the parked reader thread
        self._park.acquire()
        self._stop = threading.Event()
        self._released_at = 0.0
        self._wanted = False  # a caller found the role held
        self._hurry = False  # a thread waits for frames it does not read: take the role now
        self._waiters: set[Outcome] = set()  # callers waiting while another thread reads
        self._takes = 0  # times a caller took the role
        self._reader_wakes_at = 0.0  # when the parked reader thread looks next (0: awake)
        self._avoid_until = 0.0  # a caller's read failed: callers keep off until then
        self._backoff = _BACKOFF
        self._poke_r, self._poke_w = socket.socketpair()
        self._poke_r.setblocking(False)
        self._poke_w.setblocking(False)
        self._reader_wait = _waiter((fd,))
        self._caller_wait = _waiter((fd, self._poke_r.fileno()))
        self._sigint = SigintDeferred(self._poke)
        self._thread: threading.Thread | None = None
        #: Frames read by blocking callers; the others were read by the reader thread.
        self.read_by_callers = 0

    # ------------------------------------------------------------------ the reader thread
    def start(self) -> None:
        """Start the reader thread, which holds the role first."""
        self._thread = threading.Thread(target=self._serve, name="cobus-rx", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop the reader thread. A caller that reads goes back to waiting."""
        self._stop.set()
        self._wake_reader()
        self._poke()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)
        self._thread = None
        self._close_if_done()

    def _close_if_done(self) -> None:
        if self._stop.is_set() and _ROLE not in self._claim:
            self._poke_r.close()  # (idempotent)
            self._poke_w.close()

    def _serve(self) -> None:
        claim, stop = self._claim, self._stop
        me = threading.get_ident()
        _set_running_loop(self._loop)  # handlers run here: get_running_loop() is the loop
        interval = _LOOK
        while not stop.is_set():
            # (said before the look: a caller letting go meanwhile wakes it)
            self._reader_wakes_at = time.monotonic() + interval
            if claim.setdefault(_ROLE, me) != me:  # a caller reads: look again later
                seen = self._takes
                self._park_for(interval)
                held_on = self._takes == seen and _ROLE in claim
                interval = min(interval * 2, PARK_MAX) if held_on else _LOOK
                continue
            self._reader_wakes_at = 0.0
            idle = time.monotonic() - self._released_at
            if idle < GRACE and not self._hurry and not self._waiting():
                del claim[_ROLE]  # freed just now: its caller may come back for it
                self._park_for(GRACE - idle)
                continue
            interval = _LOOK
            self._hurry = False
            try:
                if not self._read_while_held():
                    return
            finally:
                self._released_at = time.monotonic()
                del claim[_ROLE]

    def _park_for(self, seconds: float) -> None:
        self._reader_wakes_at = time.monotonic() + seconds
        self._park.acquire(True, seconds)
        self._reader_wakes_at = 0.0

    def _read_while_held(self) -> bool:
        """Read while this thread holds the role, until a caller wants it (True) or the
        reader stops (False)."""
        stop, bus, wait = self._stop, self._bus, self._reader_wait
        backoff = _BACKOFF
        while not stop.is_set():
            try:
                batch = self._take(bus) if wait(_READER_WAIT) else None
            except Exception as exc:  # any driver failure: report, back off, read on
                if stop.is_set():
                    return False
                self._report(exc)
                stop.wait(backoff)
                backoff = min(backoff * 2, 1.0)
                continue
            backoff = _BACKOFF
            if batch and not self._accept(batch):
                return False
            if self._wanted and not self._waiting():
                self._wanted = False
                return True
        return False

    def _waiting(self) -> bool:
        """Whether a caller still waits for an outcome that another thread must read."""
        return any(not waiter.settled for waiter in list(self._waiters))

    def _wake_reader(self) -> None:
        with contextlib.suppress(RuntimeError):  # (awake already)
            self._park.release()

    # ------------------------------------------------------------------ a blocking caller
    def wait(self, outcome: Outcome) -> None:
        """Wait until ``outcome`` is there (and take it), reading the bus meanwhile when the
        role is free. On Ctrl-C, the caller's handler calls :meth:`drop`.

        The main thread reads only while no other signal than SIGINT has a Python handler,
        and with SIGINT's put aside (see the module docstring)."""
        me = threading.get_ident()
        if self._stop.is_set() or time.monotonic() < self._avoid_until or _ROLE in self._claim:
            self._wait_for(outcome)
            return
        sigint: SigintDeferred | None = None
        if me == MAIN:
            if other_handlers():
                self._wait_for(outcome)
                return
            aside = self._sigint.put_aside()  # (before the role: nothing to give back)
            if aside == REFUSED:
                self._wait_for(outcome)
                return
            if aside == ASIDE:
                sigint = self._sigint
        took = done = False
        try:
            took = self._claim.setdefault(_ROLE, me) == me
            if took:
                self._takes += 1
                done = self._read_until(outcome, me, sigint)
        finally:
            try:
                if took:
                    self._let_go(me, hand_on=not done)
            finally:
                if sigint is not None:
                    sigint.restore()  # (a SIGINT meanwhile: its handler runs now)
        if not done:
            self._wait_for(outcome)

    def hurry(self) -> None:
        """A thread is about to wait for an outcome it will not read the bus for (a
        coroutine run on the loop): if the role is free, the reader thread takes it now
        rather than once :data:`GRACE` has passed."""
        if _ROLE not in self._claim:
            self._hurry = True
            self._wake_reader()

    def drop(self) -> None:
        """Give the role back if the calling thread holds it (after a KeyboardInterrupt)."""
        self._let_go(threading.get_ident())

    def _wait_for(self, outcome: Outcome) -> None:
        self._wanted = True
        waiters = self._waiters
        waiters.add(outcome)
        if _ROLE not in self._claim:  # let go of since this caller looked: someone must read
            self.hurry()
        try:
            outcome.block()
        finally:
            waiters.discard(outcome)

    def _let_go(self, me: int, *, hand_on: bool = False) -> None:
        """Give the role back; ``hand_on``: the caller goes on waiting for frames it will
        not read, so the reader thread takes the role at once."""
        claim = self._claim
        if claim.get(_ROLE) != me:
            return
        self._released_at = now = time.monotonic()
        del claim[_ROLE]
        if hand_on:
            self._hurry = True
            self._wake_reader()
        elif self._waiting() or self._reader_wakes_at > now + _LOOK:
            self._wake_reader()  # others wait for it, or it parks long: it takes the role
        if self._stop.is_set():
            self._close_if_done()

    def _read_until(self, outcome: Outcome, me: int, sigint: SigintDeferred | None) -> bool:
        """Read and dispatch until the outcome is there (True), or until a read fails, the
        reader stops or SIGINT comes (False: wait for it instead, after the handler)."""
        poke_r, fd, bus, stop = self._poke_r, self._fd, self._bus, self._stop
        wait = self._caller_wait
        poked = poke_r.fileno()
        outcome.reader = me
        outcome.poke = self._poke
        running = _get_running_loop()
        _set_running_loop(self._loop)  # handlers run here: get_running_loop() is the loop
        try:
            while not outcome.ready():
                if stop.is_set() or (sigint is not None and sigint.hit):
                    return False
                try:
                    readable = wait(_CALLER_WAIT)
                    if poked in readable:
                        poke_r.recv(64)
                    if fd not in readable:
                        continue
                    # one frame per look: the caller waits for one, and a second recv(0)
                    # would cost a failing select; if more wait, the next look says so
                    msg = bus.recv(0)
                except Exception as exc:  # any failure: report, give the role back, wait
                    if not stop.is_set():
                        self._report(exc)
                        self._avoid_until = time.monotonic() + self._backoff
                        self._backoff = min(self._backoff * 2, 1.0)
                    return False
                if msg is not None:
                    self._backoff = _BACKOFF
                    self.read_by_callers += 1
                    if not self._accept([msg]):
                        return False
            return True
        finally:
            outcome.poke = None
            _set_running_loop(running)

    def _poke(self) -> None:
        with contextlib.suppress(OSError):  # (full: poked already; closed: stopped)
            self._poke_w.send(b"\0")
