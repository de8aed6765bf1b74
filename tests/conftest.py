"""Shared test fixtures: where the shared corpus lives; a python-can-remote bus server."""

from __future__ import annotations

import contextlib
import os
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SHARED = Path(os.environ.get("COBUS_SHARED", ROOT.parent / "shared"))
EDS_DIR = SHARED / "eds"
VECTORS_DIR = SHARED / "vectors"


def corpus_files() -> list[Path]:
    """Every EDS/DCF file of the shared corpus, sorted."""
    return sorted(p for p in EDS_DIR.iterdir() if p.suffix.lower() in (".eds", ".dcf"))


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    if not SHARED.is_dir():
        pytest.fail(f"the shared folder is missing at {SHARED} (set COBUS_SHARED)")
    return SHARED


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def wait_for_port(port: int, deadline: float) -> None:
    while time.monotonic() < deadline:
        with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", port), 0.2):
            return
        time.sleep(0.05)
    raise TimeoutError(f"python-can-remote did not listen on 127.0.0.1:{port}")


@pytest.fixture
def remote_bus_url() -> Iterator[str]:
    """A python-can-remote server on 127.0.0.1 (a virtual bus behind it): its URL."""
    port = free_port()
    server = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "can_remote",
            "-i",
            "virtual",
            "-c",
            f"mp{port}",
            "-H",
            "127.0.0.1",
            "-p",
            str(port),
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        wait_for_port(port, time.monotonic() + 15)
        yield f"ws://127.0.0.1:{port}/"
    finally:
        server.terminate()
        server.wait(10)
