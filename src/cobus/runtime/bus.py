"""The bus adapter: the only place where python-can messages and cobus frames meet.

It opens any interface python-can has (from arguments, from python-can's own configuration
files, or from ``CAN_INTERFACE`` / ``CAN_CHANNEL`` / ``CAN_BITRATE``), converts messages to and
from :class:`~cobus.proto.Frame`, and decodes error frames into bus-state events.
"""

from __future__ import annotations

from typing import Any

import can

from cobus.proto import Event, Frame
from cobus.runtime.errors import BusOpenError
from cobus.runtime.events import BusErrorFrame, BusState, RxOverflow, TxBufferOverflow

__all__ = [
    "BusOpenError",
    "decode_error_frame",
    "error_frames_are_local",
    "frame_to_message",
    "message_to_frame",
    "open_bus",
]


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
    try:
        return can.Bus(**config)
    except can.CanInterfaceNotImplementedError as exc:
        raise BusOpenError(
            f"CAN interface not available: {exc}. Name one with interface=... or the "
            "CAN_INTERFACE environment variable (e.g. socketcan, pcan, kvaser, virtual)"
        ) from exc
    except (can.CanError, OSError, ValueError) as exc:
        iface, chan = config.get("interface", "?"), config.get("channel", "?")
        raise BusOpenError(f"cannot open CAN interface {iface} channel {chan}: {exc}") from exc


def frame_to_message(frame: Frame) -> can.Message:
    """The python-can message of ``frame``."""
    return can.Message(
        arbitration_id=frame.cob_id,
        data=frame.data,
        is_extended_id=frame.extended,
        is_remote_frame=frame.rtr,
        dlc=frame.dlc,
        check=False,
    )


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


def readable_fd(bus: can.BusABC) -> int | None:
    """A file descriptor that is readable exactly when ``bus.recv(0)`` has a frame, or None.

    Only SocketCAN guarantees that: its kernel socket hands over one frame per read, and a
    read never blocks once it is readable. Other interfaces with a descriptor are read by a
    thread: serial ports and most vendor drivers buffer frames behind it, and
    python-can-remote's client, although it reads one websocket frame per ``recv``, reads it
    with blocking calls (a frame split over TCP segments, or a ping, would stall the loop) and
    raises on a dropped connection while its socket stays readable.
    """
    if type(bus).__name__ not in _FD_EXACT:
        return None
    try:
        fd = bus.fileno()
    except (NotImplementedError, OSError, ValueError):
        return None
    return fd if isinstance(fd, int) and fd >= 0 else None


#: The bus classes whose descriptor is readable exactly when a frame waits.
_FD_EXACT = frozenset(("SocketcanBus",))


def interface_reports_state(bus: can.BusABC) -> bool:
    """Whether the interface implements python-can's ``state`` property for real."""
    return type(bus).state is not can.BusABC.state


def read_state(bus: can.BusABC) -> BusState | None:
    try:
        return _PYCAN_STATE.get(bus.state)
    except Exception:  # a driver that cannot tell: no state, polling goes on
        return None
