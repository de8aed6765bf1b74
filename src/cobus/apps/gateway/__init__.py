"""The CiA 309-3 ASCII gateway: the network from any program, over TCP, a Unix socket or
HTTP, several clients at once (``cobus gateway``).

:mod:`~cobus.apps.gateway.grammar` reads the command language (sans-I/O),
:mod:`~cobus.apps.gateway.core` runs requests on cobus networks,
:mod:`~cobus.apps.gateway.pdo` keeps the gateway's own PDOs,
:mod:`~cobus.apps.gateway.server` serves them over TCP or a Unix socket (text or JSON lines),
:mod:`~cobus.apps.gateway.http` over HTTP in gocanopen's CiA 309-5 URLs,
:mod:`~cobus.apps.gateway.client` is a client of any 309-3 gateway.
"""

from cobus.apps._serving import is_loopback
from cobus.apps.gateway.client import GatewayClient, Reply
from cobus.apps.gateway.core import HELP, MAX_PENDING, GatewayCore, Session
from cobus.apps.gateway.grammar import ERRORS, TYPES, GatewayError, parse_line
from cobus.apps.gateway.server import MAX_LINE, GatewayServer, request_line

__all__ = [
    "ERRORS",
    "HELP",
    "MAX_LINE",
    "MAX_PENDING",
    "TYPES",
    "GatewayClient",
    "GatewayCore",
    "GatewayError",
    "GatewayServer",
    "Reply",
    "Session",
    "is_loopback",
    "parse_line",
    "request_line",
]
