"""python-can's ``udp_multicast`` without hearing ourselves: a sending socket of our own, whose
datagrams the kernel drops before they reach the bus's receiving socket.

Multicast loopback hands every datagram a host sends back to every socket of the group on
that host, the sender's included, so that processes on one host hear each other. A network
that sends through python-can's socket therefore wakes its reader for each of its own frames,
only to drop it (by the tag in ``channel``, see :func:`cobus.runtime.bus.own_echo`); a
blocking SDO caller then waits for the GIL behind that reader (``docs/realtime.md``).

:func:`echo_free_sender` sends from a second UDP socket connected to the group and attaches a
classic BPF filter (Linux ``SO_ATTACH_FILTER``) to the bus's receiving socket that drops the
datagrams whose source address and port are that socket's. Every other sender passes: another
process, another host, another network of this process, and what is sent through python-can's
own socket. The tag stays as the fallback, and is all there is off Linux or wherever the
filter cannot be attached. The filter also drops what was not sent to the group
(:func:`only_to`): python-can's socket listens on every interface at its port, so without it
a unicast datagram from anywhere to that port was a frame on the bus.

It reaches python-can's private ``bus._multicast._socket`` (python-can 4.x): when that is not
there, nothing changes. ``SO_ATTACH_FILTER`` replaces a classic filter the application put on
that socket itself; a socket that has cobus's filter already (two networks on one bus
object) is left as it is. Each datagram the filter drops counts in the socket's ``drops``
and the host's UDP ``InErrors`` (``/proc/net/udp``, ``netstat -su``).

A connected socket keeps the source address it had when it connected; python-can's
``sendto`` looks the route up for each datagram. When the host's address changes under a
running network (DHCP, an interface re-plumbed), the sender's next send fails: it then takes
its filter off and sends through python-can from then on, as before (logged once).
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import logging
import socket
import struct
import sys
import weakref
from collections.abc import Callable
from typing import Any

import can

from cobus.runtime.bus import _is_udp_multicast

__all__ = ["EchoFreeSender", "echo_free_sender"]

log = logging.getLogger(__name__)

# Linux's option numbers (asm-generic; x86, ARM, RISC-V, ...); Python's socket module has no name
# for them. Elsewhere there is no filter: the tag does the work.
_SO_ATTACH_FILTER = 26
_SO_DETACH_FILTER = 27
_SKF_NET_OFF = -0x100000  # a BPF load from the network (IP) header; offset 0 is the UDP header
_LDH_ABS, _LDW_ABS, _JEQ_K, _RET_K = 0x28, 0x20, 0x15, 0x06
_DROP, _ACCEPT = 0, 0xFFFFFFFF
# the kernel cannot take the datagram now: the network's backlog holds the frame, as before
_FULL = (errno.EAGAIN, errno.EWOULDBLOCK, errno.ENOBUFS)
# the receiving sockets that have cobus's filter
_FILTERED: weakref.WeakSet[socket.socket] = weakref.WeakSet()


def drop_from(address: str, port: int, family: int) -> bytes:
    """A classic BPF program for a UDP socket that drops datagrams from ``address``:``port``
    and accepts every other (``struct sock_filter`` entries, native byte order)."""
    raw = socket.inet_pton(family, address.split("%", 1)[0])  # (an IPv6 scope is not sent)
    source = 8 if family == socket.AF_INET6 else 12  # the source address in the IP header
    words = struct.unpack(f"!{len(raw) // 4}I", raw)
    # ldh [0] (the UDP source port); jeq port; then each word of the source address: ld, jeq.
    # A mismatch jumps to "accept", the last instruction; all equal falls through to "drop".
    program: list[tuple[int, int]] = [(_LDH_ABS, 0), (_JEQ_K, port)]
    for i, word in enumerate(words):
        program.append((_LDW_ABS, (_SKF_NET_OFF + source + 4 * i) & 0xFFFFFFFF))
        program.append((_JEQ_K, word))
    program += [(_RET_K, _DROP), (_RET_K, _ACCEPT)]
    accept = len(program) - 1
    out = bytearray()
    for pc, (code, k) in enumerate(program):
        jump_false = accept - pc - 1 if code == _JEQ_K else 0
        out += struct.pack("HBBI", code, 0, jump_false, k)
    return bytes(out)


def only_to(group: str, address: str, port: int, family: int) -> bytes:
    """:func:`drop_from`'s program behind a check of the destination: a datagram not sent
    to multicast ``group`` is dropped too. python-can's socket listens on every interface
    at its port, so a unicast datagram from anywhere to that port was a frame on the bus;
    now only what was sent to the group is."""
    tail = drop_from(address, port, family)
    raw = socket.inet_pton(family, group.split("%", 1)[0])
    destination = 24 if family == socket.AF_INET6 else 16  # in the IP header
    words = struct.unpack(f"!{len(raw) // 4}I", raw)
    drop = 2 * len(words) + len(tail) // 8 - 2  # drop_from's "drop", the one before last
    out = bytearray()
    for i, word in enumerate(words):
        pc = 2 * i
        out += struct.pack(
            "HBBI", _LDW_ABS, 0, 0, (_SKF_NET_OFF + destination + 4 * i) & 0xFFFFFFFF
        )
        out += struct.pack("HBBI", _JEQ_K, 0, drop - (pc + 1) - 1, word)
    return bytes(out) + tail


def _joined_on(group: str) -> int | None:
    """The index of the interface this host joined IPv6 multicast ``group`` on (Linux's
    /proc/net/igmp6; None when it is not there or not one interface)."""
    try:
        wanted = socket.inet_pton(socket.AF_INET6, group.split("%", 1)[0]).hex()
        with open("/proc/net/igmp6", encoding="ascii") as f:
            found = {int(fields[0]) for fields in map(str.split, f) if fields[2:3] == [wanted]}
    except (OSError, ValueError, IndexError):
        return None
    return found.pop() if len(found) == 1 else None


def _attach(sock: socket.socket, program: bytes) -> None:
    buffer = ctypes.create_string_buffer(program, len(program))
    fprog = struct.pack("HP", len(program) // 8, ctypes.addressof(buffer))  # struct sock_fprog
    sock.setsockopt(socket.SOL_SOCKET, _SO_ATTACH_FILTER, fprog)  # the kernel copies it


class EchoFreeSender:
    """Sends a ``udp_multicast`` bus's messages from a socket its receiving socket does not
    hear (see the module docstring). Non-blocking: a datagram the kernel cannot take now
    raises :class:`can.CanOperationError`, as python-can's ``send(msg, timeout=0)`` does."""

    def __init__(
        self,
        bus: can.BusABC,
        tx: socket.socket,
        rx: socket.socket,
        pack: Callable[[can.Message], bytes],
    ) -> None:
        self._bus = bus
        self._tx = tx
        self._rx = rx
        self._pack = pack
        self._send: Callable[[bytes], int] | None = tx.send

    @property
    def active(self) -> bool:
        """Whether this sender still sends from its own socket (False once it fell back to
        python-can's, see the module docstring, or was closed)."""
        return self._send is not None

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """Send ``msg`` to the group (``timeout`` is ignored: this never waits)."""
        send = self._send
        if send is None or msg.is_fd:  # (python-can decides whether the bus takes CAN FD)
            self._bus.send(msg, timeout)
            return
        data = self._pack(msg)
        try:
            sent = send(data)
        except OSError as exc:
            if exc.errno in _FULL:
                raise can.CanOperationError(f"failed to send via socket: {exc}") from exc
            log.warning(
                "udp_multicast: the sending socket failed (%s); sending through python-can's "
                "socket from now on",
                exc,
            )
            self.close()
            self._bus.send(msg, timeout)
            return
        if sent != len(data):
            raise can.CanOperationError(f"sent {sent} bytes of a {len(data)}-byte datagram")

    @property
    def address(self) -> tuple[str, int]:
        """The address and port this sender's datagrams come from."""
        name = self._tx.getsockname()
        return name[0], name[1]

    def close(self) -> None:
        """Take the filter off the bus's socket (when the bus outlives this sender, another
        socket may get this port) and close the sending socket; later sends go through
        python-can's. Calling it again does nothing."""
        if self._send is None:
            return
        self._send = None
        with contextlib.suppress(OSError):  # (the bus may have closed its socket already)
            self._rx.setsockopt(socket.SOL_SOCKET, _SO_DETACH_FILTER, 0)
        _FILTERED.discard(self._rx)
        self._tx.close()


def echo_free_sender(bus: can.BusABC) -> EchoFreeSender | None:
    """A sender for ``bus`` whose messages ``bus`` does not receive back, or None: not
    python-can's ``udp_multicast`` (python-can's ``ThreadSafeBus`` around it is seen
    through; a wrapper that injects faults, ``cobus.sim.FaultyBus``, must send through
    itself), not Linux, python-can's private attributes not as expected, or the socket or
    filter refused."""
    if not sys.platform.startswith("linux") or not _is_udp_multicast(bus):
        return None
    multicast: Any = getattr(bus, "_multicast", None)
    rx = getattr(multicast, "_socket", None)
    group, port = getattr(multicast, "group", None), getattr(multicast, "port", None)
    hops = getattr(multicast, "hop_limit", None)
    if (
        not isinstance(rx, socket.socket)
        or rx.family not in (socket.AF_INET, socket.AF_INET6)
        or not isinstance(group, str)
        or not isinstance(port, int)
        or not isinstance(hops, int)
        or rx in _FILTERED
    ):
        return None
    try:
        from can.interfaces.udp_multicast.utils import pack_message
    except ImportError:
        return None
    try:
        tx = socket.socket(rx.family, socket.SOCK_DGRAM)
    except OSError:
        return None
    try:
        if rx.family == socket.AF_INET6:
            tx.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_MULTICAST_HOPS, struct.pack("@I", hops))
        else:
            tx.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, struct.pack("@I", hops))
        try:
            tx.connect((group, port))  # fixes the source address and port the filter drops
        except OSError as exc:
            # An interface- or link-local group (cobus's host-only default) names no route:
            # connect on the interface python-can's socket joined the group on.
            index = _joined_on(group) if exc.errno == errno.EINVAL else None
            if index is None:
                raise
            tx.connect((group, port, 0, index))
        tx.setblocking(False)
        address, source_port = tx.getsockname()[:2]
        try:
            program = only_to(group, address, source_port, rx.family)
        except (OSError, ValueError):  # (a group given by name): the source check alone
            program = drop_from(address, source_port, rx.family)
        _attach(rx, program)
    except OSError as exc:
        log.debug("udp_multicast: no echo-free sending socket (%s); the tag does the work", exc)
        tx.close()
        return None
    _FILTERED.add(rx)
    return EchoFreeSender(bus, tx, rx, pack_message)
