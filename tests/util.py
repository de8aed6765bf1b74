"""Helpers shared by the tests."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Coroutine, Iterator
from pathlib import Path
from typing import Any, TypeVar

from cobus.runtime import SimulatedEventLoop

T = TypeVar("T")


def simulate(coro: Coroutine[Any, Any, T]) -> T:
    """Run ``coro`` to the end on a fresh simulated-clock loop (time starts at 0.0)."""
    loop = SimulatedEventLoop()
    try:
        return loop.run_until_complete(coro)
    finally:
        loop.close()


def second_ctrl_c_on_abort(bus: Any) -> None:
    """Have ``bus`` (a network's python-can bus) send SIGINT to the main thread right after
    it sends the first SDO abort: a second Ctrl-C that lands while an interrupted transfer
    is being cancelled. Once only; the bus's own ``send`` is put back then."""
    import signal
    import threading

    send = bus.send
    main = threading.main_thread().ident
    assert main is not None

    def send_then_interrupt(msg: Any, timeout: float | None = None) -> None:
        send(msg, timeout)
        if msg.data[0] == 0x80:
            bus.send = send
            signal.pthread_kill(main, signal.SIGINT)

    bus.send = send_then_interrupt


def until(check: Callable[[], object], timeout: float = 2.0) -> None:
    """Wait in real time (polling every 5 ms) until ``check()`` holds; AssertionError after
    ``timeout`` seconds. For tests with python-canopen, which runs its own threads."""
    deadline = time.monotonic() + timeout
    while not check():
        if time.monotonic() > deadline:
            raise AssertionError("condition not reached in time")
        time.sleep(0.005)


class Terminal:
    """A pseudo-terminal for a command's output: ``file`` is what the command writes to (a
    tty), ``text()`` what the terminal received. Use it as a context manager."""

    def __init__(self) -> None:
        import os
        import pty
        import threading

        self._leader, follower = pty.openpty()
        self.file = open(follower, "w", buffering=1)  # noqa: SIM115 - closed in close()
        self._chunks: list[bytes] = []

        def read() -> None:
            while True:
                try:
                    got = os.read(self._leader, 65536)
                except OSError:
                    return
                if not got:
                    return
                self._chunks.append(got)

        self._reader = threading.Thread(target=read, daemon=True)
        self._reader.start()

    def close(self) -> None:
        import os

        if not self.file.closed:
            self.file.close()
            self._reader.join(5)
            os.close(self._leader)

    def text(self) -> str:
        return b"".join(self._chunks).decode(errors="replace")

    def __enter__(self) -> Terminal:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def ctrl_c_when(network: Any, wanted: Callable[[Any], bool]) -> Callable[[], None]:
    """Send SIGINT to the main thread once, when a frame ``wanted(frame)`` is seen on the
    async ``network`` (a Ctrl-C at a known point of a command); returns a function that arms
    it again."""
    import signal
    import threading

    main = threading.main_thread().ident
    assert main is not None
    fired = threading.Event()

    def look(frame: Any, now: float) -> None:
        if not fired.is_set() and wanted(frame):
            fired.set()
            signal.pthread_kill(main, signal.SIGINT)

    network.subscribe_all(look)
    return fired.clear


SERVO_RIG = """
bus: embedded
devices:
  - {node: 10, kind: cia402_drive, name: servo}
"""


@contextlib.contextmanager
def servo_bench(folder: Path, tag: str) -> Iterator[tuple[Any, Any, Path, list[str]]]:
    """The simulated CiA 402 servo (node 10) alone on a virtual bus of its own: the blocking
    network, the rig, the servo's EDS exported into ``folder``, and the command line's bus
    options for that bus."""
    import os

    from cobus.device import export_eds
    from cobus.runtime import Network
    from cobus.sim import Rig, start_rig

    channel = f"{tag}-{os.getpid()}"
    with Network(interface="virtual", channel=channel) as net:
        rig = start_rig(net, Rig.loads(SERVO_RIG))
        eds = folder / "servo.eds"
        eds.write_text(export_eds(rig.aio.devices[10].od))
        yield net, rig, eds, ["-i", "virtual", "-c", channel]


def bounded_python(
    code: str, *, memory_mb: int = 1500, seconds: float = 60.0, cwd: Path | None = None
) -> tuple[int, str, str]:
    """Run ``code`` in a child Python under an address-space cap and a time limit: what a
    hostile input could make run away (a regression costs a MemoryError or a timeout in the
    child, never the test run). (exit status, stdout, stderr); status -9 on a timeout."""
    import resource
    import subprocess
    import sys

    def cap() -> None:
        limit = memory_mb * 1024 * 1024
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

    try:
        done = subprocess.run(
            [sys.executable, "-c", code],
            capture_output=True,
            text=True,
            timeout=seconds,
            preexec_fn=cap,
            cwd=cwd,
            check=False,
        )
    except subprocess.TimeoutExpired as exc:
        out = exc.stdout.decode() if isinstance(exc.stdout, bytes) else (exc.stdout or "")
        return -9, out, f"timed out after {seconds:g} s"
    return done.returncode, done.stdout, done.stderr


def need(ok: object, reason: str) -> None:
    """Skip the test when ``ok`` is false - unless ``CI=true``: in CI a missing dependency
    (a program, a module, a working udp_multicast) fails the test, so that a green run never
    hides what it did not run."""
    import os

    import pytest

    if ok:
        return
    if os.environ.get("CI") == "true":
        pytest.fail(f"{reason} (CI=true: a missing dependency fails)")
    pytest.skip(reason)


def need_module(name: str, reason: str | None = None) -> Any:
    """``pytest.importorskip(name)`` that fails instead with ``CI=true`` (see :func:`need`)."""
    import importlib

    try:
        return importlib.import_module(name)
    except ImportError:
        need(False, reason or f"the module {name} is not installed")
        raise
