"""Debian's chromium for the panel's browser test and soak, kept from running away.

A browser cannot run under ``ulimit -v`` (V8 reserves terabytes of address space), so:

- this process (the server, the master, the rig) gets a soft address-space cap while the
  browser runs, ``capped``;
- chromium starts through a wrapper that lifts the soft cap for itself only, and a watchdog
  thread kills every chromium process of ours whose resident memory together passes
  ``max_rss_mb`` (``BrowserWatchdog``);
- the callers bound everything with timeouts.
"""

from __future__ import annotations

import contextlib
import os
import resource
import shutil
import signal
import stat
import tempfile
import threading
from pathlib import Path

CHROMIUM = os.environ.get("COBUS_CHROMIUM") or shutil.which("chromium") or "/usr/bin/chromium"
#: Chromium's own network off: on a closed machine its background requests are refused.
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-default-apps",
    "--disable-dev-shm-usage",
]


class capped:
    """A soft address-space cap on this process while in the ``with`` block: what it uses
    now plus ``headroom_mb`` (its children may lift it; the hard limit stays as it was)."""

    def __init__(self, headroom_mb: int = 2000) -> None:
        self.headroom_mb = headroom_mb
        self._old: tuple[int, int] | None = None

    def __enter__(self) -> capped:
        soft, hard = resource.getrlimit(resource.RLIMIT_AS)
        self._old = (soft, hard)
        limit = (_vm_kb(os.getpid(), "VmSize:") * 1024) + self.headroom_mb * 1024 * 1024
        if hard != resource.RLIM_INFINITY:
            limit = min(limit, hard)
        resource.setrlimit(resource.RLIMIT_AS, (limit, hard))
        return self

    def __exit__(self, *exc: object) -> None:
        if self._old is not None:
            resource.setrlimit(resource.RLIMIT_AS, self._old)


def chromium_wrapper(folder: Path) -> str:
    """An executable in ``folder`` that starts chromium with the soft address-space cap
    lifted (for it only)."""
    wrapper = folder / "chromium"
    wrapper.write_text(f'#!/bin/sh\nulimit -S -v unlimited\nexec "{CHROMIUM}" "$@"\n')
    wrapper.chmod(wrapper.stat().st_mode | stat.S_IXUSR)
    return str(wrapper)


def _descendants(root: int) -> list[int]:
    children: dict[int, list[int]] = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                parent = int(f.read().rsplit(")", 1)[1].split()[1])
        except (OSError, IndexError, ValueError):
            continue
        children.setdefault(parent, []).append(int(entry))
    found, todo = [], [root]
    while todo:
        for child in children.get(todo.pop(), []):
            found.append(child)
            todo.append(child)
    return found


def _vm_kb(pid: int, field: str = "VmRSS:") -> int:
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith(field):
                    return int(line.split()[1])
    except OSError:
        pass
    return 0


def _is_chromium(pid: int) -> bool:
    try:
        return "chrom" in Path(f"/proc/{pid}/comm").read_text()
    except OSError:
        return False


class BrowserWatchdog:
    """Kills our chromium processes when their resident memory together passes
    ``max_rss_mb`` (checked every ``period`` s); ``peak_mb`` is the most seen, ``killed``
    says whether it had to."""

    def __init__(self, max_rss_mb: int = 3000, period: float = 0.5) -> None:
        self.max_rss_mb = max_rss_mb
        self.period = period
        self.peak_mb = 0.0
        self.killed = False
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._watch, name="browser watchdog", daemon=True)

    def __enter__(self) -> BrowserWatchdog:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(5)

    def _watch(self) -> None:
        me = os.getpid()
        while not self._stop.wait(self.period):
            pids = [p for p in _descendants(me) if _is_chromium(p)]
            total = sum(_vm_kb(p) for p in pids) / 1024
            self.peak_mb = max(self.peak_mb, total)
            if total > self.max_rss_mb:
                self.killed = True
                for pid in pids:
                    with contextlib.suppress(OSError):
                        os.kill(pid, signal.SIGKILL)


def scratch() -> tempfile.TemporaryDirectory[str]:
    """A folder for the wrapper (and chromium's profile)."""
    return tempfile.TemporaryDirectory(prefix="cobus-browser-")
