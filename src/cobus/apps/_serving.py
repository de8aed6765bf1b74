"""What cobus's servers (the panel, the gateway) share about where they listen and who may
write: loopback addresses, Unix socket paths, tokens compared in constant time."""

from __future__ import annotations

import hmac
import ipaddress
import os
import socket
import stat

__all__ = [
    "MIN_TOKEN",
    "free_unix_path",
    "gateway_token",
    "is_loopback",
    "token_is",
    "token_usable",
]

#: The shortest token a server takes.
MIN_TOKEN = 8

_LOOPBACK_NAMES = {"localhost", "127.0.0.1", "::1"}


def is_loopback(host: str) -> bool:
    """Whether ``host`` (a name or an address, ``[::1]`` too) names this machine only."""
    host = host.strip("[]")
    if host in _LOOPBACK_NAMES:
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def free_unix_path(path: str) -> str | None:
    """Make ``path`` free for a Unix socket: a stale socket left by a server that is gone is
    removed. Returns why it cannot be used (None: it can): it is no socket, or another live
    server listens there."""
    if not os.path.exists(path):
        return None
    if not stat.S_ISSOCK(os.stat(path).st_mode):
        return "it exists and is no socket"
    probe = socket.socket(socket.AF_UNIX)
    probe.settimeout(1.0)
    try:
        probe.connect(path)
    except ConnectionRefusedError:
        os.unlink(path)  # left behind by a server that is gone
        return None
    except OSError as exc:  # (no right to it, a server too busy to answer...: not ours)
        return f"cannot tell whether a server listens there ({exc.strerror or exc})"
    finally:
        probe.close()
    return "another server listens there"


def token_usable(token: str) -> bool:
    """Whether ``token`` can be a server's token: :data:`MIN_TOKEN` characters at least, no
    white space and no ``#`` (a gateway client gives it as one word of a request line)."""
    return len(token) >= MIN_TOKEN and not any(c.isspace() or c == "#" for c in token)


def gateway_token(given: str | None, hosts: list[str]) -> tuple[str | None, bool]:
    """The token a gateway serving ``hosts`` uses: ``given`` (``--token``), else
    ``COBUS_GATEWAY_TOKEN``, else a random one when a host is beyond this one (None: none
    needed); and whether it was drawn (to print). ValueError says what a bad one lacks."""
    import os
    import secrets

    token = given if given is not None else os.environ.get("COBUS_GATEWAY_TOKEN")
    if token is not None:
        if not token_usable(token):
            raise ValueError(f"give {MIN_TOKEN} characters at least, without spaces or #")
        return token, False
    if any(not is_loopback(host) for host in hosts):
        return secrets.token_urlsafe(18), True
    return None, False


def token_is(given: object, token: str) -> bool:
    """Whether ``given`` is ``token`` (compared in constant time)."""
    return isinstance(given, str) and hmac.compare_digest(
        given.encode("utf-8", "surrogatepass"), token.encode("utf-8", "surrogatepass")
    )
