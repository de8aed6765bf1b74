"""python-can's own ``SocketcanBus`` on a host without SocketCAN: socket pairs stand in for
the kernel's sockets.

This kernel has no ``PF_CAN``. Everything above the socket is python-can's real SocketCAN
code: the bus builds and parses the kernel's ``struct can_frame`` (timestamps from
``SO_TIMESTAMPNS``, error frames by ``CAN_ERR_FLAG``), waits with ``select`` for the socket
to take a frame, and hands a periodic sequence to the broadcast manager as ``TX_SETUP`` and
``TX_DELETE`` messages. Only the sockets are replaced: the raw socket and the broadcast
manager's socket are each one end of an ``AF_UNIX`` ``SOCK_SEQPACKET`` pair (one message per
read, as the kernel's), and the test holds the other end (:class:`KernelStandIn`).

What the kernel itself would do is the test's part: it reads what the bus sent and injects
what the bus would receive, or it runs :meth:`KernelStandIn.start_vcan`, a thread that plays
a ``vcan`` interface's kernel: every frame a bus sends goes to every other bus, and a
broadcast manager task sends its frames in turn, one per period, to every bus (the kernel
loops them back to all raw sockets of the host, the sending bus's own included). Each bus
opened while it is installed gets a raw pair of its own.

Without the vcan thread nothing takes what a bus sends until the test reads it (``sent``):
after about 70 unread frames the bus's socket is no longer writable, which python-can reports
as a full transmit buffer (the network then keeps frames in its backlog). A test that sends
more should read them, or run the vcan thread.
"""

from __future__ import annotations

import contextlib
import ctypes
import select
import socket
import threading
import time
from typing import Any, NamedTuple

import can
import pytest
from can.interfaces.socketcan import constants
from can.interfaces.socketcan import socketcan as pycan_socketcan

TX_SETUP = constants.CAN_BCM_TX_SETUP
TX_DELETE = constants.CAN_BCM_TX_DELETE
_HEAD = ctypes.sizeof(pycan_socketcan.BcmMsgHead)
_FRAME = 16  # struct can_frame


class BcmOp(NamedTuple):
    """One message a bus sent to the broadcast manager."""

    opcode: int
    flags: int
    ival1_count: int  # frames sent at the first interval (the header's count)
    ival1_us: int
    ival2_us: int
    task_id: int
    frames: tuple[can.Message, ...]


def _message(raw: bytes) -> can.Message:
    can_id, dlc, _flags, data = pycan_socketcan.dissect_can_frame(raw)
    extended = bool(can_id & constants.CAN_EFF_FLAG)
    return can.Message(
        arbitration_id=can_id & (0x1FFFFFFF if extended else 0x7FF),
        is_extended_id=extended,
        is_remote_frame=bool(can_id & constants.CAN_RTR_FLAG),
        is_error_frame=bool(can_id & constants.CAN_ERR_FLAG),
        dlc=dlc,
        data=data[:dlc],
    )


class _CanSocketEnd(socket.socket):
    """The bus's end of a pair: it takes the options of a CAN_RAW socket (the kernel's
    ``setsockopt`` would) and keeps them in :attr:`can_options`."""

    can_options: dict[int, bytes | int]

    def setsockopt(self, level: int, option: int, value: Any, *rest: Any) -> None:
        if level == constants.SOL_CAN_RAW:
            self.can_options[option] = value
            return
        super().setsockopt(level, option, value, *rest)


class KernelStandIn:
    """The test's ends of the sockets of every ``SocketcanBus`` opened while installed."""

    def __init__(self) -> None:
        #: the test's end of each bus's raw socket, in the order the buses were opened
        self.raw: list[socket.socket] = []
        #: the test's end of each broadcast manager socket python-can opened
        self.bcm: list[socket.socket] = []
        #: the interface names the buses were bound to
        self.bound: list[str] = []
        #: broadcast manager sockets found closed by :meth:`bcm_ops` (the kernel deletes the
        #: tasks of a socket closed)
        self.closed_bcm = 0
        #: what the vcan thread took from the broadcast manager sockets, in order
        self.ops: list[BcmOp] = []
        self._theirs: list[socket.socket] = []
        self._raw_theirs: list[_CanSocketEnd] = []
        self._vcan: threading.Thread | None = None
        self._stop = threading.Event()

    def install(self, monkeypatch: pytest.MonkeyPatch) -> KernelStandIn:
        monkeypatch.setattr(pycan_socketcan, "create_socket", self._create_raw)
        monkeypatch.setattr(pycan_socketcan, "bind_socket", self._bind)
        monkeypatch.setattr(pycan_socketcan, "create_bcm_socket", self._create_bcm)
        return self

    def close(self) -> None:
        self._stop.set()
        if self._vcan is not None:
            self._vcan.join()
        for sock in self.raw + self.bcm + self._theirs:
            sock.close()

    def _pair(self, keep: list[socket.socket]) -> _CanSocketEnd:
        pair_theirs, ours = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        theirs = _CanSocketEnd(fileno=pair_theirs.detach())
        theirs.can_options = {}
        # what the kernel queues for a bus: thousands of frames, as a CAN socket's receive
        # buffer holds (the bus's own end keeps the default: ~70 frames the kernel has not
        # taken make it unwritable, a transmit queue that is full)
        ours.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 1 << 22)
        keep.append(ours)
        self._theirs.append(theirs)
        return theirs

    def _create_raw(self) -> socket.socket:
        sock = self._pair(self.raw)
        self._raw_theirs.append(sock)
        return sock

    def can_options(self, bus: int = 0) -> dict[int, bytes | int]:
        """The CAN_RAW options bus number ``bus`` set on its socket (``SOL_CAN_RAW``)."""
        return self._raw_theirs[bus].can_options

    def _bind(self, sock: socket.socket, channel: str = "can0") -> None:
        self.bound.append(channel)

    def _create_bcm(self, channel: str) -> socket.socket:
        return self._pair(self.bcm)

    # -- the raw socket ------------------------------------------------------------------------
    def inject(self, msg: can.Message, bus: int = 0) -> None:
        """A frame the kernel hands to bus number ``bus`` (another node's, or one it looped
        back)."""
        self.raw[bus].send(pycan_socketcan.build_can_frame(msg))

    def sent(self, bus: int = 0, timeout: float = 1.0, most: int = 10_000) -> list[can.Message]:
        """The frames bus ``bus`` has sent: all that are there, waiting up to ``timeout`` for
        the first."""
        sock, out = self.raw[bus], []
        wait = timeout
        while len(out) < most and select.select([sock], [], [], wait)[0]:
            out.append(_message(sock.recv(64)))
            wait = 0
        return out

    # -- the broadcast manager -----------------------------------------------------------------
    def bcm_ops(self, timeout: float = 1.0) -> list[BcmOp]:
        """What the buses sent their broadcast managers, in order: all that are there,
        waiting up to ``timeout`` for the first."""
        out: list[BcmOp] = []
        wait = timeout
        open_ = [sock for sock in self.bcm if sock.fileno() >= 0]
        while open_ and (ready := select.select(open_, [], [], wait)[0]):
            for sock in ready:
                data = sock.recv(_HEAD + 257 * _FRAME)
                if not data:  # python-can closed it (the bus shut down)
                    open_.remove(sock)
                    sock.close()
                    self.closed_bcm += 1
                    continue
                out.append(_bcm_op(data))
            wait = 0
        return out

    # -- a vcan interface --------------------------------------------------------------------
    def start_vcan(self) -> None:
        """Play the kernel of a ``vcan`` interface in a thread, until :meth:`close`."""
        self._vcan = threading.Thread(target=self._run_vcan, name="vcan-standin", daemon=True)
        self._vcan.start()

    def _run_vcan(self) -> None:
        # per broadcast manager socket and task id: the frames, the next one's index, the
        # period and when the next is due
        tasks: dict[tuple[int, int], list[Any]] = {}
        while not self._stop.is_set():
            now = time.monotonic()
            for task in tasks.values():
                frames, index, period, due = task
                while due <= now:
                    self._to_all(frames[index], None)
                    index = (index + 1) % len(frames)
                    due += period
                task[1], task[3] = index, due
            wait = min([task[3] for task in tasks.values()] + [now + 0.01]) - now
            raw = [sock for sock in self.raw if sock.fileno() >= 0]
            bcm = [sock for sock in self.bcm if sock.fileno() >= 0]
            for sock in select.select(raw + bcm, [], [], max(wait, 0))[0]:
                try:
                    data = sock.recv(_HEAD + 257 * _FRAME)
                except OSError:
                    data = b""
                if sock in raw:
                    if data:
                        self._to_all(data, sock)
                    continue
                if not data:  # python-can closed it: the kernel deletes its tasks
                    sock.close()
                    for key in [key for key in tasks if key[0] == id(sock)]:
                        del tasks[key]
                    continue
                op = _bcm_op(data)
                self.ops.append(op)
                key = (id(sock), op.task_id)
                if op.opcode == TX_DELETE:
                    tasks.pop(key, None)
                elif op.opcode == TX_SETUP:
                    frames = [
                        data[_HEAD + i * _FRAME : _HEAD + (i + 1) * _FRAME]
                        for i in range(len(op.frames))
                    ]
                    period = op.ival2_us / 1e6
                    tasks[key] = [frames, 0, period, time.monotonic()]  # the first at once

    def _to_all(self, frame: bytes, source: socket.socket | None) -> None:
        """A frame to every bus but ``source`` (a full receive buffer drops it, as the kernel
        does)."""
        for sock in self.raw:
            if sock is not source and sock.fileno() >= 0:
                with contextlib.suppress(OSError):
                    sock.send(frame, socket.MSG_DONTWAIT)


def _bcm_op(data: bytes) -> BcmOp:
    head: Any = pycan_socketcan.BcmMsgHead.from_buffer_copy(data[:_HEAD])
    # (python-can's TX_DELETE says nframes=1 and carries none: the kernel reads no frames
    # for a delete)
    count = (len(data) - _HEAD) // _FRAME
    assert _HEAD + count * _FRAME == len(data), "a BCM message of a wrong length"
    if head.opcode == TX_SETUP:
        assert count == head.nframes, "TX_SETUP with another count of frames than it says"
    frames = tuple(
        _message(data[_HEAD + i * _FRAME : _HEAD + (i + 1) * _FRAME]) for i in range(count)
    )
    return BcmOp(
        head.opcode,
        head.flags,
        head.count,
        head.ival1_tv_sec * 1_000_000 + head.ival1_tv_usec,
        head.ival2_tv_sec * 1_000_000 + head.ival2_tv_usec,
        head.can_id,
        frames,
    )
