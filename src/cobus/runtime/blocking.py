"""The blocking facade: the same network for scripts and the REPL, without ``await``.

In real time the event loop runs in a background thread and each call waits for its result.
On the simulated clock there is no thread: each call runs the loop in the caller's thread until
the call is done, so virtual time only moves while the caller waits (``net.sleep(10)`` jumps
ten virtual seconds) and a script's behaviour is the same on every run.

User callbacks (frame handlers, event listeners) registered here never run on the event loop in
real time: they run in one callback thread, in order, so a slow callback cannot stall the
protocol. On the simulated clock they run inline, for determinism.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import logging
import queue
import threading
from collections.abc import Callable, Coroutine
from typing import TYPE_CHECKING, Any, Generic, TypeVar

import can

from cobus._moved import Moved, renamed_names
from cobus.proto import Event, Frame
from cobus.runtime import emcy as _emcy
from cobus.runtime import nmt as _nmt
from cobus.runtime import pdo as _pdo
from cobus.runtime import remote as _remote
from cobus.runtime._sigint import ASIDE, MAIN, SigintDeferred
from cobus.runtime.errors import ReentrantCallError
from cobus.runtime.events import BusState
from cobus.runtime.loop import RealTimeLoop, SimulatedEventLoop, new_event_loop
from cobus.runtime.lss import AsyncNetworkLss
from cobus.runtime.network import AsyncNetwork, FrameHandler, NetworkClosedError, Subscription
from cobus.runtime.remote import AsyncRemoteNode, NetworkSync, NmtMaster, SdoChannel
from cobus.runtime.sdo_transport import downloaded, refused_block, uploaded
from cobus.runtime.twin import BlockingTwin, twin_of

if TYPE_CHECKING:
    from collections.abc import Iterator
    from pathlib import Path

    from cobus.od import ObjectDictionary
    from cobus.runtime.reading import ReadingRole

__all__ = [
    "BlockingNetworkSync",
    "BlockingNmtMaster",
    "BlockingSdoChannel",
    "BlockingTwin",
    "Network",
    "NetworkLss",
    "PdoSet",
    "ReentrantCallError",
    "RemoteEmcy",
    "RemoteNmt",
    "RemoteNode",
    "RemotePdo",
    "Runner",
    "SdoRecord",
    "SdoVariable",
]

T = TypeVar("T")
A = TypeVar("A")
log = logging.getLogger(__name__)


class Runner:
    """Runs coroutines and plain calls on a network's loop from a blocking caller."""

    def __init__(self, *, simulated: bool) -> None:
        self.simulated = simulated
        self.loop = new_event_loop(simulated=simulated)
        self._thread: threading.Thread | None = None
        self._loop_ident: int | None = None  # the loop thread's, while it runs
        self._callbacks: queue.SimpleQueue[Callable[[], object] | None] | None = None
        self._callback_thread: threading.Thread | None = None
        self._callback_lock = threading.Lock()
        self._closed = False
        #: The network whose blocking SDO transfers pass here (its bus may be read by the
        #: waiting caller: ``AsyncNetwork._reading``).
        self.network: AsyncNetwork | None = None
        if not simulated:
            self._thread = threading.Thread(target=self._run_loop, name="cobus-loop", daemon=True)
            self._thread.start()

    def _run_loop(self) -> None:
        # (an ident, unlike a Thread, is reused once the thread is gone: cleared on the way out)
        self._loop_ident = threading.get_ident()
        try:
            self.loop.run_forever()
            if self._closed and not self.loop.is_closed():  # close() came from protocol code
                self.loop.close()
        finally:
            self._loop_ident = None

    def run(self, coro: Coroutine[Any, Any, T], timeout: float | None = None) -> T:
        """Run ``coro`` on the loop and return its result; ``TimeoutError`` after ``timeout``
        seconds (virtual seconds on the simulated clock)."""
        if self._closed:
            coro.close()
            raise NetworkClosedError("the network is closed")
        if self.simulated:
            if self.loop.is_running():
                coro.close()
                raise ReentrantCallError(
                    "a blocking call from inside a callback on the simulated clock would "
                    "re-enter the event loop: use the async API there (AsyncNetwork, await)"
                )
            assert isinstance(self.loop, SimulatedEventLoop)
            task = self.loop.start_first(coro)  # listening before queued frames arrive
            if timeout is not None:
                return self.loop.run_until_complete(asyncio.wait_for(task, timeout))
            return self.loop.run_until_complete(task)
        if self._on_loop():
            coro.close()
            raise ReentrantCallError(
                "a blocking call from the event loop thread would deadlock: use the async API"
            )
        if not asyncio.iscoroutine(coro):
            raise TypeError(f"run() takes a coroutine (call the async function), not {coro!r}")
        loop = self.loop
        handoff: _Handoff[T] = _Handoff(loop)

        def start() -> None:
            try:
                task = loop.create_task(coro)
            except BaseException as exc:  # pragma: no cover - the loop is closing
                with contextlib.suppress(Exception):
                    coro.close()
                handoff.fail(exc)
                return
            handoff.task = task
            task.add_done_callback(handoff.finish)

        loop.call_soon_threadsafe(start)
        network = self.network
        reading = network._reading if network is not None else None
        if reading is not None:  # what it waits for is read by the reader thread
            reading.hurry()
        done = False
        try:
            done = handoff.wait(timeout)
        finally:  # timed out, or Ctrl-C while waiting: the operation ends with it
            if not done:
                with contextlib.suppress(RuntimeError):  # the loop closed: nothing runs
                    loop.call_soon_threadsafe(handoff.cancel)
        if not done:
            raise TimeoutError(f"the operation did not complete within {timeout} s")
        return handoff.outcome()

    def run_direct(
        self,
        begin: Callable[[A, Callable[[Any], None]], Callable[[], None] | None],
        fallback: Callable[[A], Coroutine[Any, Any, T]],
        arg: A,
    ) -> T:
        """Begin an operation from the caller's thread and wait for it here, with no hop
        through the loop (real time, see ``docs/realtime.md``).

        ``begin(arg, finish)`` runs under the loop's protocol lock: it starts the operation
        and returns a function that cancels it, or returns None when it cannot start now;
        the protocol code that ends the operation calls ``finish(outcome)`` once (an
        exception is raised here). When it cannot start now — and on the simulated clock, or
        from protocol code — ``fallback(arg)`` is run on the loop as :meth:`run` does.
        (``arg`` is passed rather than bound in closures: every blocking SDO transfer
        passes here.)
        """
        loop = self.loop
        if self.simulated or self._closed or not isinstance(loop, RealTimeLoop):
            return self.run(fallback(arg))
        lock = loop.protocol_lock
        # _on_loop(), inline: every blocking SDO transfer passes here
        if lock._is_owned() or threading.get_ident() == self._loop_ident:  # type: ignore[attr-defined]
            return self.run(fallback(arg))  # raises ReentrantCallError
        network = self.network
        reading = network._reading if network is not None else None
        handoff: _Handoff[T] = _Handoff(loop, reading is not None)
        with lock:
            cancel = begin(arg, handoff.settle)
        loop.wake_if_pending()
        if cancel is None:
            return self.run(fallback(arg))
        try:  # the operation's own timeout ends it (an SDO timeout)
            if reading is None:
                handoff._lock.acquire()
            else:  # the caller may read the bus itself meanwhile (cobus.runtime.reading)
                reading.wait(handoff)
        except BaseException:  # Ctrl-C while waiting: the operation ends with it
            _end_after_interrupt(reading, lock, cancel, loop)
            raise
        return handoff.outcome()

    def call(self, fn: Callable[..., T], *args: Any) -> T:
        """Run a plain function on the loop thread and return its result."""
        if self.simulated or self._on_loop():
            return fn(*args)
        if self._closed:
            raise NetworkClosedError("the network is closed")
        handoff: _Handoff[T] = _Handoff(self.loop)

        def job() -> None:
            try:
                result = fn(*args)
            except BaseException as exc:
                handoff.fail(exc)
            else:
                handoff.succeed(result)

        self.loop.call_soon_threadsafe(job)
        handoff.wait(None)
        return handoff.outcome()

    def _on_loop(self) -> bool:
        """Whether the caller runs protocol code: on the loop thread, or a reader thread
        dispatching under the loop's protocol lock."""
        loop = self.loop
        return threading.get_ident() == self._loop_ident or (
            isinstance(loop, RealTimeLoop) and loop.lock_held()
        )

    def callback(self, fn: Callable[..., object]) -> Callable[..., None]:
        """Wrap a user callback so that, in real time, it runs in the callback thread.

        A coroutine function is run as a task on the network's loop.
        """
        loop = self.loop
        if self.simulated:

            def inline(*args: Any) -> None:
                result = fn(*args)
                if asyncio.iscoroutine(result):
                    loop.create_task(result)

            return inline
        with self._callback_lock:
            if self._callbacks is None:
                self._callbacks = queue.SimpleQueue()
                self._callback_thread = threading.Thread(
                    target=self._callback_worker, name="cobus-callbacks", daemon=True
                )
                self._callback_thread.start()
        callbacks = self._callbacks

        def job(*args: Any) -> None:
            result = fn(*args)
            if asyncio.iscoroutine(result):
                asyncio.run_coroutine_threadsafe(result, loop)

        def deferred(*args: Any) -> None:
            callbacks.put(lambda: job(*args))

        return deferred

    def _callback_worker(self) -> None:
        assert self._callbacks is not None
        while True:
            job = self._callbacks.get()
            if job is None:
                return
            try:
                job()
            except Exception:  # a user callback's failure is theirs; keep serving the others
                log.exception("callback failed")

    def close(self) -> None:
        """Cancel what still runs on the loop, stop it and its threads. Idempotent, and safe
        from a callback."""
        if self._closed:
            return
        self._closed = True
        current = threading.current_thread()
        on_loop = self._on_loop()  # protocol code (loop or dispatching reader): cannot wait
        if self._callbacks is not None:
            self._callbacks.put(None)
            if self._callback_thread is not None and self._callback_thread is not current:
                self._callback_thread.join(timeout=2.0)
        if self._thread is not None:
            if not on_loop:
                with contextlib.suppress(concurrent.futures.TimeoutError, RuntimeError):
                    asyncio.run_coroutine_threadsafe(_cancel_tasks(), self.loop).result(5.0)
            self.loop.call_soon_threadsafe(self.loop.stop)
            if not on_loop:
                self._thread.join(timeout=5.0)
        elif not self.loop.is_running():
            self.loop.run_until_complete(_cancel_tasks())
        if not self.loop.is_running():
            self.loop.close()


def _end_after_interrupt(
    reading: ReadingRole | None,
    lock: threading.RLock,
    cancel: Callable[[], None],
    loop: RealTimeLoop,
) -> None:
    """End an operation begun by :meth:`Runner.run_direct` whose caller was interrupted.

    In the main thread SIGINT's handler is put aside meanwhile (``cobus.runtime._sigint``):
    a second Ctrl-C landing in the middle of ``cancel()`` would leave the operation half
    ended (an SDO channel busy for good); it is raised once the operation has ended."""
    deferred: SigintDeferred | None = None
    try:
        if threading.get_ident() == MAIN:
            deferred = SigintDeferred(_nothing)
            if deferred.put_aside() != ASIDE:
                deferred = None
    finally:  # (a SIGINT pending already has raised in put_aside: end the operation anyway)
        try:
            if reading is not None:
                reading.drop()
            with lock:
                cancel()
            loop.wake_if_pending()
        finally:
            if deferred is not None:
                deferred.restore()  # a Ctrl-C meanwhile: its KeyboardInterrupt, now


def _nothing() -> None:
    pass


class _Handoff(Generic[T]):
    """One result handed from the loop thread to a waiting caller: one wake-up each way (the
    loop's self-pipe in, a plain lock out), where ``run_coroutine_threadsafe`` chains an
    asyncio future to a ``concurrent.futures.Future`` and its condition variable."""

    __slots__ = (
        "_error",
        "_lock",
        "_loop",
        "_pokeable",
        "_result",
        "poke",
        "reader",
        "settled",
        "task",
    )

    def __init__(self, loop: asyncio.AbstractEventLoop, pokeable: bool = False) -> None:
        """``pokeable``: the waiting caller may read the bus itself (see ``poke``)."""
        self._lock = threading.Lock()
        # released once, when the outcome is there: by the protocol code that has it, or on a
        # RealTimeLoop by the thread that ran it, once it has let go of the protocol lock
        self._lock.acquire()
        self._loop = loop if isinstance(loop, RealTimeLoop) else None
        self._result: T | None = None
        self._error: BaseException | None = None
        self.task: asyncio.Task[T] | None = None
        #: Whether the outcome is known (it may not be released to the caller yet).
        self.settled = False
        #: Set while the waiting caller reads the bus itself (thread ``reader``): wakes it
        #: there when another thread releases the outcome (``cobus.runtime.reading``).
        self.poke: Callable[[], None] | None = None
        self.reader = 0
        self._pokeable = pokeable

    def succeed(self, result: T) -> None:
        self._result = result
        self._release()

    def fail(self, error: BaseException) -> None:
        self._error = error
        self._release()

    def _release(self) -> None:
        self.settled = True
        # (the release alone, in C, where no poke can be needed)
        wake = self._wake if self._pokeable else self._lock.release
        loop = self._loop
        if loop is None:
            wake()
        else:
            loop.wake_after_release(wake)

    def _wake(self) -> None:
        self._lock.release()
        poke = self.poke  # (read after the release: see ReadingRole._read_until)
        if poke is not None and threading.get_ident() != self.reader:
            poke()

    def settle(self, outcome: Any) -> None:
        """A result, or an exception to raise in the waiting caller."""
        if isinstance(outcome, BaseException):
            self._error = outcome
        else:
            self._result = outcome
        self._release()

    def ready(self) -> bool:
        """Take the outcome if it is there."""
        return self._lock.acquire(False)

    def block(self) -> None:
        """Wait until the outcome is there, and take it."""
        self._lock.acquire()

    def finish(self, task: asyncio.Task[T]) -> None:
        if task.cancelled():
            self.fail(concurrent.futures.CancelledError())
            return
        error = task.exception()
        if error is not None:
            self.fail(error)
        else:
            self.succeed(task.result())

    def cancel(self) -> None:
        """On the loop thread, after the caller gave up waiting."""
        if self.task is not None:
            self.task.cancel()

    def wait(self, timeout: float | None) -> bool:
        """Whether the outcome came within ``timeout`` seconds (None: as long as it takes;
        0 or less: only if it is there already)."""
        if timeout is None:
            return self._lock.acquire()
        if timeout <= 0:
            return self._lock.acquire(False)
        return self._lock.acquire(timeout=timeout)

    def outcome(self) -> T:
        error = self._error
        if error is None:
            return self._result  # type: ignore[return-value]
        self._error = None
        try:
            raise error
        finally:
            del error  # the traceback would hold this frame and the error in a cycle


async def _cancel_tasks() -> None:
    """Cancel every task of the running loop but this one and wait for them to end."""
    me = asyncio.current_task()
    tasks = [t for t in asyncio.all_tasks() if t is not me]
    for task in tasks:
        task.cancel()
    await asyncio.gather(*tasks, return_exceptions=True)


class _LoopSubscription(Subscription):
    """A subscription made from blocking code: cancelled on the loop thread."""

    def __init__(self, inner: Subscription, runner: Runner) -> None:
        self._inner = inner
        self._runner = runner

    def cancel(self) -> None:
        self._runner.call(self._inner.cancel)


class Network:
    """A CAN network for blocking code. See :class:`AsyncNetwork` for the arguments.

    ``simulated=True`` runs on the virtual clock (with a private virtual bus unless one is
    given). Use as a context manager or call :meth:`close`.

    ``read_on_loop`` is False here: a thread reads the bus and dispatches what it receives
    under the loop's protocol lock, where :class:`AsyncNetwork` has its loop read a bus that
    gives a descriptor. A blocking caller waits in its own thread either way, and the
    thread's read costs less than a turn of the loop. On SocketCAN and ``udp_multicast`` a
    blocking SDO transfer reads its answer itself when no other thread reads
    (:mod:`cobus.runtime.reading`; ``docs/realtime.md``, "Who reads the bus").
    """

    #: Given to a blocking twin's method, the :class:`AsyncNetwork` behind it is passed on.
    _twin_unwrap = True

    #: Moved above the runtime (it knows no device): ``cobus.device.add_device``.
    add_device = Moved("cobus.device.add_device(network, node_id, od)")

    def __init__(
        self,
        bus: can.BusABC | None = None,
        *,
        simulated: bool = False,
        interface: str | None = None,
        channel: Any = None,
        bitrate: int | None = None,
        read_on_loop: bool = False,
        **bus_kwargs: Any,
    ) -> None:
        self._runner = Runner(simulated=simulated)
        self._listeners: dict[Callable[[Event], object], Callable[..., None]] = {}
        self._remote_twins: dict[int, RemoteNode] = {}
        self._device_twins: dict[int, Any] = {}
        self._services: dict[int, BlockingTwin] = {}  # nmt and sync: one each, for good
        self.aio = AsyncNetwork(
            bus,
            interface=interface,
            channel=channel,
            bitrate=bitrate,
            read_on_loop=read_on_loop,
            **bus_kwargs,
        )
        self._runner.network = self.aio
        try:
            self._runner.run(self.aio.connect())
        except BaseException:
            self._runner.close()
            raise

    def __enter__(self) -> Network:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Disconnect and stop the loop; calling it again does nothing."""
        if self._runner._closed:
            return
        if self.aio.connected:
            try:
                self._runner.run(self.aio.disconnect())
            except ReentrantCallError:  # closed from a callback on the simulated clock
                self.aio.loop.create_task(self.aio.disconnect())
        self._runner.close()

    @property
    def simulated(self) -> bool:
        """Whether the network runs on the simulated clock."""
        return self._runner.simulated

    def time(self) -> float:
        """The network's clock in seconds (virtual on the simulated clock)."""
        return self._runner.loop.time()

    def sleep(self, seconds: float) -> None:
        """Let the network run for ``seconds`` (virtual seconds on the simulated clock)."""
        self._runner.run(asyncio.sleep(seconds))

    def run(self, coro: Coroutine[Any, Any, T], timeout: float | None = None) -> T:
        """Run a coroutine of the async API on the network's loop and wait for it."""
        return self._runner.run(coro, timeout)

    def send(self, frame: Frame) -> None:
        """Transmit ``frame`` (see :meth:`AsyncNetwork.send`)."""
        self._runner.call(self.aio.send, frame)

    def subscribe(
        self, cob_id: int, handler: FrameHandler, *, extended: bool = False
    ) -> Subscription:
        """Call ``handler(frame, now)`` for every frame with this identifier (in the callback
        thread in real time)."""
        wrapped = self._runner.callback(handler)
        return self._runner.call(lambda: self.aio.subscribe(cob_id, wrapped, extended=extended))

    def subscribe_all(self, handler: FrameHandler) -> Subscription:
        """Call ``handler(frame, now)`` for every frame (in the callback thread in real time)."""
        wrapped = self._runner.callback(handler)
        inner = self._runner.call(self.aio.subscribe_all, wrapped)
        return _LoopSubscription(inner, self._runner)

    def add_listener(self, listener: Callable[[Event], object]) -> None:
        """Call ``listener(event)`` for every event of the network (in the callback thread in real
        time)."""
        wrapped = self._runner.callback(listener)
        self._listeners[listener] = wrapped
        self._runner.call(self.aio.add_listener, wrapped)

    def remove_listener(self, listener: Callable[[Event], object]) -> None:
        """Stop calling ``listener`` (given to :meth:`add_listener`)."""
        wrapped = self._listeners.pop(listener, None)
        if wrapped is not None:
            self._runner.call(self.aio.remove_listener, wrapped)

    @property
    def connected(self) -> bool:
        """Whether the network is connected (False once closed)."""
        return self.aio.connected

    @property
    def bus(self) -> can.BusABC:
        """The python-can bus (for what only the interface offers: filters, its state...)."""
        return self.aio.bus

    @property
    def bus_state(self) -> BusState:
        """The controller's last reported state: error-active, warning, error-passive, bus-off."""
        return self.aio.bus_state

    @property
    def tx_backlog(self) -> int:
        """How many frames wait for the interface to take them."""
        return self.aio.tx_backlog

    @property
    def remotes(self) -> dict[int, RemoteNode]:
        """The nodes added with :meth:`add_remote`, by node-ID."""
        return {n: self._remote(node) for n, node in self.aio.remotes.items()}

    @property
    def devices(self) -> dict[int, Any]:
        """The local devices by node-ID, now (see :attr:`AsyncNetwork.devices`), each in its
        blocking form when it has one (a :class:`cobus.device.BlockingDevice`): the same
        object each time for the same device."""
        current = self._runner.call(lambda: dict(self.aio.devices))
        twins = self._device_twins
        out: dict[int, Any] = {}
        for node_id, device in current.items():
            twin = twins.get(node_id)
            if twin is None or twin.aio is not device:
                made = twin_of(type(device))
                if made is None:
                    out[node_id] = device
                    continue
                twin = twins[node_id] = made(device, self._runner)
            out[node_id] = twin
        for node_id in set(twins) - set(out):
            del twins[node_id]
        return out

    def _remote(self, node: AsyncRemoteNode) -> RemoteNode:
        twin = self._remote_twins.get(node.node_id)
        if twin is None or twin.aio is not node:
            twin = self._remote_twins[node.node_id] = RemoteNode(node, self._runner)
        return twin

    @property
    def frames_sent(self) -> int:
        """How many frames this network has sent (not those the interface sends by itself:
        SYNC ``by_interface``)."""
        return self.aio.frames_sent

    @property
    def frames_received(self) -> int:
        """How many frames this network has received from the bus."""
        return self.aio.frames_received

    # ------------------------------------------------------------------ nodes and services
    def add_remote(
        self,
        node_id: int,
        od: ObjectDictionary | str | Path | None = None,
        *,
        sdo_timeout: float = 1.0,
    ) -> RemoteNode:
        """A node this network talks to as a client; ``od`` may be an EDS/DCF path."""
        node = self._runner.call(lambda: self.aio.add_remote(node_id, od, sdo_timeout=sdo_timeout))
        return self._remote(node)

    def remove_remote(self, node_id: int) -> None:
        """Forget a node added with :meth:`add_remote` (it can be added again)."""
        self._runner.call(self.aio.remove_remote, node_id)
        self._remote_twins.pop(node_id, None)

    @property
    def nmt(self) -> BlockingNmtMaster:
        """The NMT master service: ``net.nmt.start(2)``, ``net.nmt.reset_node()``..."""
        twin: BlockingNmtMaster = self._service(self.aio.nmt)
        return twin

    @property
    def lss(self) -> NetworkLss:
        """The LSS master: ``net.lss.fastscan()``, ``net.lss.configure_node_id(12)``..."""
        twin: NetworkLss = self._service(self.aio.lss)
        return twin

    @property
    def sync(self) -> BlockingNetworkSync:
        """The SYNC producer: ``net.sync.start(0.01)``, ``net.sync.stop()``."""
        twin: BlockingNetworkSync = self._service(self.aio.sync)
        return twin

    def _service(self, aio: Any) -> Any:
        twin = self._services.get(id(aio))
        if twin is None:
            made = twin_of(type(aio))
            assert made is not None
            twin = self._services[id(aio)] = made(aio, self._runner)
        return twin


# One SDO transfer from blocking code is begun in the caller's thread when the channel is
# free (the answer wakes the caller directly), else awaited on the loop in its turn:
# ``runner.run_direct(channel.begin, channel.transfer, start)``.


def _upload(runner: Runner, channel: SdoChannel, index: int, subindex: int, block: bool) -> bytes:
    start = channel.transport.upload_call(index, subindex, block)
    event = runner.run_direct(channel.begin, channel.transfer, start)
    if block and refused_block(event):
        return _upload(runner, channel, index, subindex, False)
    return uploaded(event)


def _download(
    runner: Runner,
    channel: SdoChannel,
    index: int,
    subindex: int,
    data: bytes,
    block: bool,
    size_indicated: bool,
) -> None:
    start = channel.transport.download_call(index, subindex, data, block, size_indicated)
    event = runner.run_direct(channel.begin, channel.transfer, start)
    if block and refused_block(event):
        _download(runner, channel, index, subindex, data, False, size_indicated)
        return
    downloaded(event)


class BlockingSdoChannel(BlockingTwin, twin_of=SdoChannel):
    """The blocking face of an :class:`~cobus.runtime.remote.SdoChannel`: the same methods,
    each waiting for its transfer.

    A transfer begins in the calling thread and the answer wakes it directly, as in
    python-canopen; dictionary look-ups (``sdo["Device type"]``) run in the calling thread.
    """

    _async_only = frozenset(
        {"begin", "transfer", "client", "check_open", "variable_to_read", "value_to_write"}
    )

    if TYPE_CHECKING:
        aio: SdoChannel

    def upload(self, index: int, subindex: int = 0, *, block: bool = False) -> bytes:
        """Read the raw bytes of ``index:subindex`` from the server (``block=True``: block
        upload, segmented if the server refuses it)."""
        return _upload(self._runner, self.aio, index, subindex, block)

    def download(
        self,
        index: int,
        subindex: int,
        data: bytes,
        *,
        block: bool = False,
        size_indicated: bool = True,
    ) -> None:
        """Write raw bytes to ``index:subindex`` on the server."""
        _download(self._runner, self.aio, index, subindex, data, block, size_indicated)

    def read(self, index: Any, subindex: Any = 0) -> Any:
        """Read an entry and decode it with its data type (see
        :meth:`cobus.runtime.remote.SdoChannel.read`)."""
        var = self.aio.variable_to_read(index, subindex)
        return var.decode(self.upload(var.index, var.subindex))

    def write(
        self, index: Any, subindex: Any = _remote.NO_VALUE, value: Any = _remote.NO_VALUE
    ) -> None:
        """Encode ``value`` with the entry's data type and write it (see
        :meth:`cobus.runtime.remote.SdoChannel.write`)."""
        var, data = self.aio.value_to_write(index, subindex, value)
        self.download(var.index, var.subindex, data)

    def variable(self, index: Any, subindex: Any = 0) -> Any:
        """The dictionary entry named by index or name, and subindex or name."""
        return self.aio.variable(index, subindex)

    def __getitem__(self, key: Any) -> Any:
        return self._wrap(self.aio[key])


class SdoVariable(BlockingTwin, twin_of=_remote.AsyncSdoVariable):
    """One object of a remote node over SDO, for blocking code: ``node.sdo["Device
    type"].read()``."""

    if TYPE_CHECKING:
        aio: _remote.AsyncSdoVariable

    @property
    def raw(self) -> Any:
        """The value, read from the node now; ``var.raw = 5`` writes it (as python-canopen's
        ``.raw``)."""
        return self.read()

    @raw.setter
    def raw(self, value: Any) -> None:
        self.write(value)

    def read(self) -> Any:
        """Read the value from the node and decode it."""
        var = self.aio.od
        _remote.check_access(var, self.aio.channel.node_id, write=False)
        return var.decode(self.upload())

    def write(self, value: Any) -> None:
        """Check ``value`` against the type, access and limits and write it to the node."""
        var, channel = self.aio.od, self.aio.channel
        _remote.check_access(var, channel.node_id, write=True)
        self.download(_remote.encode_for(var, value, channel.node_id))

    def upload(self, *, block: bool = False) -> bytes:
        """The raw bytes of the object."""
        var = self.aio.od
        return _upload(self._runner, self.aio.channel, var.index, var.subindex, block)

    def download(self, data: bytes, *, block: bool = False) -> None:
        """Write raw bytes to the object."""
        var = self.aio.od
        _download(self._runner, self.aio.channel, var.index, var.subindex, data, block, True)


class SdoRecord(BlockingTwin, twin_of=_remote.AsyncSdoRecord):
    """A record or array of a remote node over SDO, for blocking code: ``[sub]`` gives its
    sub-objects (looked up in the calling thread: the dictionary is not protocol state)."""

    def __getitem__(self, subindex: Any) -> Any:
        return self._wrap(self.aio[subindex])


class RemoteNmt(BlockingTwin, twin_of=_nmt.AsyncRemoteNmt):
    """The NMT state of a remote node, commands to it and its heartbeat supervision, for
    blocking code (see :class:`cobus.runtime.nmt.AsyncRemoteNmt`)."""


class RemoteEmcy(BlockingTwin, twin_of=_emcy.AsyncRemoteEmcy):
    """The emergencies of a remote node, for blocking code (see
    :class:`cobus.runtime.emcy.AsyncRemoteEmcy`)."""


class RemotePdo(BlockingTwin, twin_of=_pdo.AsyncRemotePdo):
    """One PDO of a remote node, for blocking code (see
    :class:`cobus.runtime.pdo.AsyncRemotePdo`)."""


class PdoSet(BlockingTwin, twin_of=_pdo.AsyncPdoSet):
    """The TPDOs or RPDOs of a remote node, for blocking code (see
    :class:`cobus.runtime.pdo.AsyncPdoSet`)."""

    if TYPE_CHECKING:

        def __getitem__(self, number: int) -> RemotePdo: ...
        def __iter__(self) -> Iterator[RemotePdo]: ...


class RemoteNode(BlockingTwin, twin_of=AsyncRemoteNode):
    """A node on the bus that this network talks to as a client, for blocking code.

    ``sdo`` reads and writes its objects, ``nmt`` follows its state and commands it, ``emcy``
    keeps its emergencies, ``tpdo`` / ``rpdo`` receive and send its process data; every call
    returns once done (see :class:`cobus.runtime.remote.AsyncRemoteNode`)."""

    if TYPE_CHECKING:
        sdo: BlockingSdoChannel
        nmt: RemoteNmt
        emcy: RemoteEmcy
        tpdo: PdoSet
        rpdo: PdoSet


class BlockingNmtMaster(BlockingTwin, twin_of=NmtMaster):
    """NMT commands from blocking code (``net.nmt.start(2)``); each call returns once the
    frame is handed over."""


class NetworkLss(BlockingTwin, twin_of=AsyncNetworkLss):
    """The LSS master for blocking code (see :class:`cobus.runtime.lss.AsyncNetworkLss`)."""


class BlockingNetworkSync(BlockingTwin, twin_of=NetworkSync):
    """The SYNC producer from blocking code (``net.sync.start(0.01)``)."""


#: A blocking twin is X of AsyncX, or BlockingX of X (see :mod:`cobus`).
__getattr__ = renamed_names(
    __name__,
    {
        "BlockingSdo": ("BlockingSdoChannel", BlockingSdoChannel),
        "BlockingNmt": ("BlockingNmtMaster", BlockingNmtMaster),
        "BlockingSync": ("BlockingNetworkSync", BlockingNetworkSync),
    },
)
