"""The control channel of a running ``cobus sim``: faults injected, the status read, from
another shell.

    cobus sim thesis -i remote -c ws://127.0.0.1:54701/      # says where its control socket is
    cobus sim inject 10 drive_fault code=0x7305              # from another shell
    cobus sim inject bus frame_loss rate=0.1
    cobus sim status --json

A Unix socket, readable and writable by its owner only (mode 0600, nothing on the network):
``$XDG_RUNTIME_DIR/cobus-sim.sock``, else ``cobus-sim-UID.sock`` in the temporary folder, or
``--control PATH``. One JSON request per connection, one JSON answer::

    {"op": "inject", "node": 10, "fault": "drive_fault", "params": {"code": 29445}}
    {"op": "status"}        {"op": "faults", "node": 10}
    -> {"ok": true, ...} or {"ok": false, "error": "..."}
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import socket
import tempfile
from pathlib import Path
from typing import Any

from cobus.errors import CobusError

__all__ = ["ControlError", "ask", "default_path", "parse_value", "serve"]

_MAX_REQUEST = 64 * 1024


class ControlError(CobusError):
    """No simulation answers on the control socket, or it refused the request
    (``refused``: the request was wrong - an unknown fault, a bad parameter)."""

    def __init__(self, message: str, *, refused: bool = False) -> None:
        super().__init__(message)
        self.refused = refused


#: The longest path a Unix socket takes (sun_path, less its terminating byte).
_MAX_PATH = 107


def _check_path(path: Path) -> None:
    if len(os.fsencode(path)) > _MAX_PATH:
        raise ControlError(
            f"{path}: a control socket's path is at most {_MAX_PATH} bytes: give a shorter one"
        )


def default_path() -> Path:
    """Where ``cobus sim`` listens unless told otherwise."""
    runtime = os.environ.get("XDG_RUNTIME_DIR")
    if runtime and os.path.isdir(runtime):
        return Path(runtime) / "cobus-sim.sock"
    return Path(tempfile.gettempdir()) / f"cobus-sim-{os.getuid()}.sock"


def parse_value(text: str) -> Any:
    """A fault parameter from the command line: a number (0x7305, 5, 0.5), true/false, or
    text."""
    low = text.strip().lower()
    if low in ("true", "yes", "on"):
        return True
    if low in ("false", "no", "off"):
        return False
    try:
        return int(text, 0)
    except ValueError:
        pass
    try:
        return float(text)
    except ValueError:
        return text


def _alive(path: Path) -> bool:
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as probe:
        probe.settimeout(1.0)
        try:
            probe.connect(str(path))
        except OSError:
            return False
    return True


async def serve(rig: Any, path: Path) -> Any:
    """Listen on ``path`` for requests about ``rig``; the server (close it to stop). A
    stale socket file of a simulation that ended is replaced; a live one is not
    (:class:`ControlError`, as for a path that cannot be used)."""
    _check_path(path)
    if not path.parent.is_dir():
        raise ControlError(f"{path}: there is no folder {path.parent}")
    if path.exists() or path.is_symlink():
        if not path.is_socket():
            raise ControlError(f"{path} exists and is no socket: give --control another path")
        if _alive(path):
            raise ControlError(f"another cobus sim listens on {path}: give --control another path")
        path.unlink()

    async def handle(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            line = await asyncio.wait_for(reader.readline(), 5.0)
            answer = _answer(rig, line)
        except (TimeoutError, ValueError, asyncio.LimitOverrunError) as exc:
            answer = {"ok": False, "error": f"bad request: {exc}"}
        with contextlib.suppress(ConnectionError):
            writer.write(json.dumps(answer, default=str).encode() + b"\n")
            await writer.drain()
        writer.close()
        with contextlib.suppress(ConnectionError):
            await writer.wait_closed()

    old = os.umask(0o177)  # the socket: its owner's only
    try:
        return await asyncio.start_unix_server(handle, str(path), limit=_MAX_REQUEST)
    except OSError as exc:
        raise ControlError(f"{path}: {exc.strerror or exc}") from None
    finally:
        os.umask(old)


def _answer(rig: Any, line: bytes) -> dict[str, Any]:
    try:
        request = json.loads(line)
    except ValueError:
        return {"ok": False, "error": "bad request: not JSON"}
    if not isinstance(request, dict):
        return {"ok": False, "error": "bad request: give a JSON object"}
    op = request.get("op")
    try:
        if op == "status":
            return {"ok": True, "devices": rig.status(), "bus": rig.bus_status()}
        if op == "faults":
            return {"ok": True, "faults": rig.faults(request.get("node"))}
        if op == "inject":
            node, fault = request.get("node"), request.get("fault")
            params = request.get("params") or {}
            if not isinstance(fault, str) or not isinstance(params, dict):
                return {"ok": False, "error": "bad request: give fault (text) and params"}
            rig.inject(node, fault, **params)
            where = "the bus" if node is None else f"node {node}"
            return {"ok": True, "text": f"{fault} injected into {where}"}
    except (CobusError, ValueError, TypeError, KeyError) as exc:
        return {"ok": False, "error": str(exc)}
    return {"ok": False, "error": f"bad request: op {op!r} (inject, status, faults)"}


def ask(path: Path, request: dict[str, Any], timeout: float = 5.0) -> dict[str, Any]:
    """Send ``request`` to the simulation on ``path``; its answer. :class:`ControlError`
    when none answers, or when it refused (the answer's error; ``refused``)."""
    _check_path(path)
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as conn:
        conn.settimeout(timeout)
        try:
            conn.connect(str(path))
            conn.sendall(json.dumps(request).encode() + b"\n")
            data = b""
            while not data.endswith(b"\n"):
                chunk = conn.recv(65536)
                if not chunk:
                    break
                data += chunk
        except (FileNotFoundError, ConnectionRefusedError):
            raise ControlError(
                f"no cobus sim runs with the control socket {path} (start one: cobus sim RIG)"
            ) from None
        except OSError as exc:
            raise ControlError(f"the simulation on {path} did not answer: {exc}") from None
    try:
        answer: dict[str, Any] = json.loads(data)
    except ValueError:
        raise ControlError(f"the simulation on {path} answered no JSON") from None
    if not answer.get("ok"):
        raise ControlError(str(answer.get("error", "refused")), refused=True)
    return answer
