"""The bus adapter: the only place where python-can messages and cobus frames meet.

It opens any interface python-can has (from arguments, from python-can's own configuration
files, or from ``CAN_INTERFACE`` / ``CAN_CHANNEL`` / ``CAN_BITRATE``), converts messages to and
from :class:`~cobus.proto.Frame`, and decodes error frames into bus-state events.

python-can's ``udp_multicast`` binds every interface of the host: whoever can send to its
group (and port) writes to the bus. Opened by cobus without a channel it uses
:data:`HOST_ONLY_GROUP`, an interface-local IPv6 group that the kernel never sends on the
wire (python-can's own default group reaches the site); a group that reaches beyond the host
is logged as a warning when the bus opens. A unicast datagram to the host's port reaches
python-can's socket too: on Linux a cobus network's socket filter drops it
(:func:`cobus.runtime.multicast.only_to`); elsewhere, or for a bare python-can bus, firewall
the port (43113 by default) on a host others can reach.
"""

from __future__ import annotations

import enum
import functools
import ipaddress
import logging
import select
import socket
import uuid
from collections.abc import Callable
from typing import Any, NamedTuple

import can

from cobus.proto import Event, Frame
from cobus.runtime.errors import BusOpenError
from cobus.runtime.events import BusErrorFrame, BusState, RxOverflow, TxBufferOverflow

__all__ = [
    "HOST_ONLY_GROUP",
    "BusOpenError",
    "LoopSource",
    "OwnEcho",
    "Readiness",
    "decode_error_frame",
    "error_frames_are_local",
    "frame_to_message",
    "loop_source",
    "message_to_frame",
    "open_bus",
    "own_echo",
    "websocket_readiness",
    "websocket_waiting",
]


log = logging.getLogger(__name__)

#: The multicast group cobus's ``udp_multicast`` buses use unless a channel is given:
#: python-can's default group with the interface-local scope (ff1\ *1*: transient,
#: interface-local), so that its datagrams never leave this host.
HOST_ONLY_GROUP = "ff11:7079:7468:6f6e:6465:6d6f:6d63:6173"


def open_bus(
    interface: str | None = None,
    channel: Any = None,
    bitrate: int | None = None,
    **kwargs: Any,
) -> can.BusABC:
    """Open a python-can bus.

    Arguments left out come from python-can's configuration: the environment variables
    ``CAN_INTERFACE``, ``CAN_CHANNEL``, ``CAN_BITRATE`` and its configuration files.
    """
    config: dict[str, Any] = dict(kwargs)
    if interface is not None:
        config["interface"] = interface
    if channel is not None:
        config["channel"] = channel
    if bitrate is not None:
        config["bitrate"] = bitrate
    if _udp_multicast_without_group(config):
        config["channel"] = HOST_ONLY_GROUP  # (python-can's default group reaches the site)
    try:
        bus = can.Bus(**config)
        if _is_udp_multicast(bus):
            _warn_if_reachable(bus)
        return bus
    except can.CanInterfaceNotImplementedError as exc:
        if config.get("interface") is None and '"None"' in str(exc):
            raise BusOpenError(
                "no CAN interface given, and python-can's configuration names none: give one "
                "(-i/--interface, interface=...) or set CAN_INTERFACE (e.g. socketcan, pcan, "
                "kvaser, virtual)"
            ) from exc
        raise BusOpenError(
            f"CAN interface not available: {exc}. Name one with interface=... or the "
            "CAN_INTERFACE environment variable (e.g. socketcan, pcan, kvaser, virtual)"
        ) from exc
    except (can.CanError, OSError, ValueError) as exc:
        iface, chan = config.get("interface", "?"), config.get("channel", "?")
        raise BusOpenError(f"cannot open CAN interface {iface} channel {chan}: {exc}") from exc


def _udp_multicast_without_group(config: dict[str, Any]) -> bool:
    """Whether ``config``, completed by python-can's configuration (CAN_INTERFACE,
    CAN_CHANNEL, ~/.canrc...), opens python-can's udp_multicast with no group named."""
    if config.get("channel") is not None:
        return False
    try:
        full = can.util.load_config(config=dict(config))
    except (can.CanError, ValueError, OSError):
        return False
    return full.get("interface") == "udp_multicast" and full.get("channel") is None


def multicast_reach(group: str) -> str | None:
    """Where datagrams to multicast ``group`` go beyond this host, in words (None: they stay
    on it: an IPv6 interface-local group)."""
    try:
        address = ipaddress.ip_address(group.split("%", 1)[0])
    except ValueError:
        return "wherever its name resolves to"
    if isinstance(address, ipaddress.IPv6Address) and address.is_multicast:
        scope = address.packed[1] & 0x0F
        if scope == 1:
            return None
        return "this link" if scope == 2 else f"beyond this link (scope {scope:X})"
    return "this link or beyond (IPv4 has no host-only group)"


def _warn_if_reachable(bus: can.BusABC) -> None:
    group = getattr(getattr(bus, "_multicast", None), "group", None)
    if not isinstance(group, str):
        return
    reach = multicast_reach(group)
    if reach is not None:
        port = getattr(getattr(bus, "_multicast", None), "port", "?")
        log.warning(
            "udp_multicast group %s reaches %s, and python-can listens on every interface "
            "(port %s): anyone who can send there writes to this bus. Leave the channel out "
            "(cobus then uses %s, this host only) or use a CAN interface",
            group,
            reach,
            port,
            HOST_ONLY_GROUP,
        )


def _message_by_init(frame: Frame) -> can.Message:
    """The python-can message of ``frame``, made by its constructor."""
    return can.Message(
        arbitration_id=frame.cob_id,
        data=frame.data,
        is_extended_id=frame.extended,
        is_remote_frame=frame.rtr,
        dlc=frame.dlc,
        check=False,
    )


#: The fields of a python-can message this module knows how to fill.
_MESSAGE_FIELDS = frozenset(
    (
        "arbitration_id",
        "bitrate_switch",
        "channel",
        "data",
        "dlc",
        "error_state_indicator",
        "is_error_frame",
        "is_extended_id",
        "is_fd",
        "is_remote_frame",
        "is_rx",
        "timestamp",
    )
)
_new_message = object.__new__


def _message_by_fields(frame: Frame) -> can.Message:
    """The python-can message of ``frame``: what ``can.Message(..., check=False)`` makes,
    its fields filled directly in half the time (every frame sent is one)."""
    msg: can.Message = _new_message(can.Message)
    msg.timestamp = 0.0
    msg.arbitration_id = frame.cob_id
    msg.is_extended_id = frame.extended
    msg.is_remote_frame = frame.rtr
    msg.is_error_frame = False
    msg.channel = None
    msg.dlc = frame.dlc
    msg.data = bytearray(frame.data)
    msg.is_fd = False
    msg.is_rx = True
    msg.bitrate_switch = False
    msg.error_state_indicator = False
    return msg


def _message_maker(message_class: type) -> Callable[[Frame], can.Message]:
    """Fill the fields directly while python-can's Message (``message_class``: the fields
    are read from it) has exactly the fields above and the constructor makes the same
    message of a probe frame; a version that adds, renames or defaults a field otherwise
    gets its own constructor."""
    fields = set(getattr(message_class, "__slots__", ())) - {"__weakref__"}
    if fields != _MESSAGE_FIELDS:
        return _message_by_init
    probe = Frame(0x123, b"\x01\x02")
    fast, slow = _message_by_fields(probe), _message_by_init(probe)
    for name in fields:
        mine, theirs = getattr(fast, name), getattr(slow, name)
        if mine != theirs or type(mine) is not type(theirs):
            return _message_by_init
    return _message_by_fields


#: The python-can message of a frame (:func:`_message_maker` picks how it is made).
frame_to_message: Callable[[Frame], can.Message] = _message_maker(can.Message)


_new_frame = object.__new__


def message_to_frame(msg: can.Message) -> Frame | None:
    """The frame carried by ``msg``; ``None`` for messages that are no classic CAN frame.

    CAN FD frames and frames with more than 8 bytes are not CANopen (CiA 301) frames.
    """
    if msg.is_fd or msg.is_error_frame:
        return None
    data = bytes(msg.data) if msg.data is not None else b""
    if len(data) > 8:
        return None
    # Trusted fast path: python-can already validated identifier and length.
    frame = _new_frame(Frame)
    frame.cob_id = msg.arbitration_id
    frame.extended = msg.is_extended_id
    if msg.is_remote_frame:
        frame.rtr = True
        frame.data = b""
        frame.dlc = min(msg.dlc, 8)
    else:
        frame.rtr = False
        frame.data = data
        frame.dlc = len(data)
    return frame


# SocketCAN error frame classes (linux/can/error.h), carried in the identifier.
_ERROR_CLASSES = (
    (0x001, "tx-timeout"),
    (0x002, "lost-arbitration"),
    (0x004, "controller"),
    (0x008, "protocol-violation"),
    (0x010, "transceiver"),
    (0x020, "no-ack"),
    (0x040, "bus-off"),
    (0x080, "bus-error"),
    (0x100, "restarted"),
)
_CRTL_RX_OVERFLOW = 0x01
_CRTL_TX_OVERFLOW = 0x02
_CRTL_WARNING = 0x04 | 0x08
_CRTL_PASSIVE = 0x10 | 0x20
_CRTL_ACTIVE = 0x40
_ERR_CNT = 0x200


ErrorFrameInfo = tuple[list[Event], BusState | None, int | None, int | None]


def decode_error_frame(msg: can.Message) -> ErrorFrameInfo:
    """Events, the new bus state (if the frame tells one) and the error counters of a frame."""
    ident = msg.arbitration_id
    data = bytes(msg.data or b"").ljust(8, b"\x00")
    classes = tuple(name for bit, name in _ERROR_CLASSES if ident & bit)
    events: list[Event] = [BusErrorFrame(classes, data)]
    state: BusState | None = None
    if ident & 0x040:
        state = BusState.BUS_OFF
    elif ident & 0x100:
        state = BusState.ACTIVE
    elif ident & 0x004:
        ctrl = data[1]
        if ctrl & _CRTL_RX_OVERFLOW:
            events.append(RxOverflow())
        if ctrl & _CRTL_TX_OVERFLOW:
            events.append(TxBufferOverflow())
        if ctrl & _CRTL_PASSIVE:
            state = BusState.PASSIVE
        elif ctrl & _CRTL_WARNING:
            state = BusState.WARNING
        elif ctrl & _CRTL_ACTIVE:
            state = BusState.ACTIVE
    tx = rx = None
    if ident & _ERR_CNT:
        tx, rx = data[6], data[7]
    return events, state, tx, rx


_PYCAN_STATE = {
    can.BusState.ACTIVE: BusState.ACTIVE,
    can.BusState.PASSIVE: BusState.PASSIVE,
    can.BusState.ERROR: BusState.BUS_OFF,
}


#: Interfaces that are software hubs: an error frame received there was sent by another
#: participant and says nothing about this side's controller.
_SHARED_MEDIA = ("can.interfaces.virtual", "can_remote", "can.interfaces.udp_multicast")


def error_frames_are_local(bus: can.BusABC) -> bool:
    """Whether an error frame received on ``bus`` reports this side's own CAN controller
    (SocketCAN, PCAN, Kvaser... report theirs). On python-can's ``virtual`` bus,
    python-can-remote and ``udp_multicast`` every participant sees the error frames the
    others inject: they must not flip this network's bus state."""
    # (cobus.sim.FaultyBus is local: it drops the error frames of others its inner bus
    # hears, and its own bus-off frames are its controller's)
    cls = bus.__class__  # (python-can's ThreadSafeBus is a proxy: this is the wrapped class)
    modules = [klass.__module__ for klass in cls.__mro__]
    if any(m.startswith("can_remote") for m in modules):
        # python-can-remote forwards what its server's bus sees: a real controller's error
        # frames (socketcan ...) are ours, a virtual bus's are other participants'.
        info = str(getattr(bus, "channel_info", "")).lower()
        return not info.startswith(("virtual", "udp"))
    return not any(m.startswith(_SHARED_MEDIA) for m in modules)


class Readiness(enum.Enum):
    """What a bus's descriptor holds when the loop finds it readable."""

    NOTHING = 0  #: no bytes wait (a spurious wake-up, or all was read): nothing to read
    WHOLE = 1  #: a whole frame, or an error or end of stream ``recv`` will report at once
    #: the start of a frame only, or control frames only (a ping): reading now would block
    #: until more arrives
    PART = 2
    #: the start of a frame longer than any CAN frame, maybe longer than the kernel's buffer:
    #: it cannot be waited for there, so a thread must read this connection
    HUGE = 3


class LoopSource(NamedTuple):
    """How the event loop reads a bus itself, without a reader thread.

    ``fd`` is watched with ``add_reader``; once it is readable, ``ready()`` (when given) tells
    whether ``bus.recv(0)`` returns without blocking, and how many times in a row (see
    :func:`websocket_waiting`). Without ``ready``, readable means a whole frame waits.
    """

    fd: int
    ready: Callable[[], tuple[Readiness, int]] | None


def loop_source(bus: can.BusABC) -> LoopSource | None:
    """How the loop can read ``bus`` through its file descriptor, or None (a thread reads it).

    - SocketCAN: the kernel hands over one frame per read and a readable socket never blocks.
    - python-can's ``udp_multicast``: one datagram is one message, whole once readable.
    - python-can-remote over plain ``ws://``: its client reads one websocket frame per
      ``recv``, with blocking socket calls. The loop peeks at the socket first
      (:func:`websocket_readiness`) and reads only when a whole frame is in the kernel's
      buffer, so a frame split over TCP segments never stalls the loop. (``wss://`` is read by
      a thread: TLS records cannot be peeked at.)

    Serial ports and most vendor drivers buffer frames behind their descriptor: a thread
    reads them.
    """
    cls = type(bus)
    if cls.__name__ == "SocketcanBus" or _is_udp_multicast(bus):
        fd = _fileno(bus)
        return LoopSource(fd, None) if fd is not None else None
    if cls.__name__ == "RemoteBus" and cls.__module__.startswith("can_remote"):
        sock = getattr(bus, "socket", None)
        if type(sock) is not socket.socket or _MSG_DONTWAIT is None or _POLLRDHUP is None:
            return None
        fd = _fileno(bus)
        if fd is None or fd != sock.fileno():
            return None
        return LoopSource(fd, functools.partial(websocket_waiting, sock))
    return None


def _is_udp_multicast(bus: can.BusABC) -> bool:
    cls = bus.__class__  # (python-can's ThreadSafeBus is a proxy: this is the wrapped class)
    return cls.__name__ == "UdpMulticastBus" and cls.__module__.startswith(
        "can.interfaces.udp_multicast"
    )


class OwnEcho(NamedTuple):
    """How this side's own messages come back from a bus, to be dropped: a network has
    delivered them to its own handlers when it sent them (local echo)."""

    #: they come back marked ``is_rx`` False, and only they do
    marked: bool
    #: they come back unmarked: put this in the ``channel`` of each message sent, and drop
    #: what comes back with it
    tag: str | None


def own_echo(bus: can.BusABC) -> OwnEcho:
    """Whether and how ``bus`` hands this side's own messages back (see :class:`OwnEcho`).

    - python-can's ``udp_multicast`` always does (multicast loopback, so that processes on
      one host hear each other), unmarked: a tag in ``channel``, which it carries.
    - ``virtual`` with ``receive_own_messages=True`` marks exactly its own (``is_rx`` False).
    - Elsewhere ``is_rx`` cannot be trusted to mean "ours": SocketCAN marks every frame sent
      from the same host, by any program, as not received (python-can issue 1274), and
      cobus never asks it for its own messages.

    A bus that wraps another (``cobus.sim.FaultyBus``) names it in ``inner``.
    """
    inner = getattr(bus, "inner", None)
    if isinstance(inner, can.BusABC):
        return own_echo(inner)
    if _is_udp_multicast(bus):
        return OwnEcho(False, f"cobus-{uuid.uuid4().hex}")
    cls = bus.__class__  # (seen through python-can's ThreadSafeBus, as above)
    if cls.__name__ == "VirtualBus" and cls.__module__.startswith("can.interfaces.virtual"):
        return OwnEcho(bool(getattr(bus, "receive_own_messages", False)), None)
    return OwnEcho(False, None)


def _fileno(bus: can.BusABC) -> int | None:
    try:
        fd = bus.fileno()
    except (NotImplementedError, OSError, ValueError):
        return None
    return fd if isinstance(fd, int) and fd >= 0 else None


_MSG_DONTWAIT: int | None = getattr(socket, "MSG_DONTWAIT", None)
_POLLRDHUP: int | None = getattr(select, "POLLRDHUP", None)  # Linux: the peer closed its side
_PEEK_FLAGS = int(socket.MSG_PEEK) | (_MSG_DONTWAIT or 0)  # (plain ints: IntFlag's | is slow)
_PEEK_FIRST = 4096  # bytes looked at first: a CAN frame's websocket frame is 20-250 bytes, and
# one look should see a burst (a batch reads what it found whole)
_PEEK_MAX = 1 << 20
# websocket opcodes (RFC 6455) after which python-can-remote's read() returns or raises;
# it answers a ping, skips a pong or continuation, and reads on
_WS_FINAL_OPCODES = frozenset((0x1, 0x2, 0x8))  # text, binary, close


def websocket_readiness(sock: socket.socket) -> Readiness:
    """Whether the websocket frames waiting in ``sock``'s receive buffer let python-can-remote's
    ``recv`` return without blocking: a whole data or close frame, after any whole control
    frames; or an end of stream or error, which ``recv`` reports at once. The bytes stay in
    the buffer (``MSG_PEEK``)."""
    return websocket_waiting(sock)[0]


def websocket_waiting(sock: socket.socket) -> tuple[Readiness, int]:
    """:func:`websocket_readiness`, and how many calls of python-can-remote's ``recv`` return
    without blocking, one after the other (at least 1 when ``WHOLE``; 0 otherwise): the
    whole data and close frames among the bytes peeked at. One look at the socket for a
    batch: a second one, to find it empty, would cost a failing system call per wake-up."""
    size = _PEEK_FIRST
    while True:
        try:
            data = sock.recv(size, _PEEK_FLAGS)
        except (BlockingIOError, InterruptedError):
            return Readiness.NOTHING, 0
        except OSError:
            return Readiness.WHOLE, 1  # recv() raises it, at once
        if not data:
            return Readiness.WHOLE, 1  # end of stream: recv() raises WebsocketClosed at once
        verdict, needed = _scan_websocket(data)
        if verdict is Readiness.WHOLE:
            return verdict, 1 + _whole_frames_after(data, needed)
        if needed > _PEEK_MAX:  # python-can-remote's CAN frames are 20-250 bytes
            return Readiness.HUGE, 0
        if len(data) < size:  # all that waits was seen, and it is not enough
            # unless nothing more can come: then recv() reads up to the end and raises
            return (Readiness.WHOLE, 1) if _stream_ended(sock) else (Readiness.PART, 0)
        size = max(needed, 2 * size)


def _whole_frames_after(data: bytes, pos: int) -> int:
    """How many more whole data or close frames ``data`` holds from ``pos`` on."""
    count = 0
    while pos < len(data):
        verdict, end = _scan_websocket(data, pos)
        if verdict is not Readiness.WHOLE:
            return count
        count += 1
        pos = end
    return count


def _stream_ended(sock: socket.socket) -> bool:
    """Whether the peer closed its side (or the socket failed): no more bytes will come."""
    assert _POLLRDHUP is not None  # (loop_source offers the peek only where it is known)
    poller = select.poll()
    poller.register(sock, _POLLRDHUP)
    return bool(poller.poll(0))


def _scan_websocket(data: bytes, pos: int = 0) -> tuple[Readiness, int]:
    """The readiness of peeked bytes from ``pos`` on, and where the frame a verdict of WHOLE
    saw ends, or how many bytes a verdict of PART would need."""
    end = len(data)
    while True:
        head = pos + 2
        if head > end:
            return Readiness.PART, head
        opcode, length = data[pos] & 0x0F, data[pos + 1] & 0x7F
        masked = data[pos + 1] & 0x80
        if length == 126:
            head += 2
            if head > end:
                return Readiness.PART, head
            length = int.from_bytes(data[head - 2 : head], "big")
        elif length == 127:
            head += 8
            if head > end:
                return Readiness.PART, head
            length = int.from_bytes(data[head - 8 : head], "big")
        frame_end = head + (4 if masked else 0) + length
        if frame_end > end:
            return Readiness.PART, frame_end
        if opcode in _WS_FINAL_OPCODES:
            return Readiness.WHOLE, frame_end
        pos = frame_end


def interface_reports_state(bus: can.BusABC) -> bool:
    """Whether the interface implements python-can's ``state`` property for real."""
    return type(bus).state is not can.BusABC.state


def read_state(bus: can.BusABC) -> BusState | None:
    try:
        return _PYCAN_STATE.get(bus.state)
    except Exception:  # a driver that cannot tell: no state, polling goes on
        return None
