"""The SDO server machine (CiA 301): expedited, segmented and block transfers, sans-I/O.

An :class:`SdoServer` answers one SDO channel: it receives on ``rx_cob_id`` (600h + node-ID by
default) and answers on ``tx_cob_id`` (580h + node-ID). What the objects hold is the business
of its back end (:class:`SdoServerBackend`), which reads and writes whole values and refuses a
request by raising :class:`~cobus.proto.sdo.errors.SdoAbort`. :class:`DictBackend` is a small
one for tests and simple devices.

Choices where CiA 301 leaves room:

- Short frames (CiA 301 wants 8 bytes): a request is served when every byte its command needs
  is present (``40 idx idx sub`` of 4 bytes is a complete upload request; an expedited download
  without size indication takes the data bytes present, up to 4). A request missing bytes its
  command needs is answered with abort 05040001 (missing index bytes read as 0). Empty frames
  and remote frames are ignored.
- A new initiate request while a transfer runs ends the running transfer and starts the new one
  (the client evidently gave up on the old one). No abort frame is sent for the old transfer,
  because the client would take it as the answer to its new request; the device layer is told
  with :class:`ServerAborted` (code 08000000, ``by_peer=True``). During the data phase of a
  block download every frame except an abort is a block segment (the protocol cannot tell
  them apart): an initiate there is taken as a segment out of sequence (ignored), or refused
  with 05040003 when its first byte names a sequence number beyond the block size.
- An abort from the client ends the transfer silently (:class:`ServerAborted` with
  ``by_peer=True``). Outside a transfer it is ignored.
- A segment or block sub-command outside a transfer is answered with abort 05040001 naming
  object 0000h:00.
- Block download: a segment out of sequence is ignored; at the end of the sub-block (its last
  sequence number or the segment flagged last) the server acknowledges the last segment
  received in sequence and the client resends from there. Sequence number 0 or above the block
  size: abort 05040003.
- Size checks: more data than indicated is refused with 06070012 as soon as it arrives, less
  with 06070013 at the end. Without a size indication the download may bring at most the
  object's size (the back end's ``size_hint``) or, for objects of no fixed size,
  ``max_download`` bytes (1 MiB by default, or the back end's ``download_limit`` for that
  object): more is refused with 06070012 as soon as it arrives, so a hostile client cannot
  make the server buffer without end. An indicated size above that limit is refused at once
  with 05040005 (out of memory): 0xFFFFFFFF announced into a domain buffers nothing.
- A stalled segmented or block transfer is aborted with 05040000 after ``timeout`` seconds.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Protocol, cast

from cobus.proto._base import NOTHING, Event, Out
from cobus.proto.frame import Frame
from cobus.proto.sdo import _endpoint as ep
from cobus.proto.sdo import _wire as w
from cobus.proto.sdo.abort import SdoAbortCode, as_code
from cobus.proto.sdo.errors import SdoAbort

__all__ = [
    "DictBackend",
    "SdoServer",
    "SdoServerBackend",
    "ServerAborted",
    "ServerDownloaded",
    "ServerUploaded",
]

#: ``Out(frames, events)`` as ``_out(Out, (frames, events))``: one C call where the
#: NamedTuple's constructor is a Python function (on every expedited request's path).
_out = tuple.__new__


class SdoServerBackend(Protocol):
    """What an :class:`SdoServer` serves: whole values by index and sub-index.

    Both methods raise :class:`~cobus.proto.sdo.errors.SdoAbort` to refuse (for example
    ``SdoAbort(SdoAbortCode.NO_OBJECT)``); any other exception escapes to the caller of the
    server.

    A back end may also define ``size_hint(index, subindex) -> int | None``. The server calls it
    when a segmented or block download starts, before any data arrives: it may raise
    :class:`SdoAbort` to refuse early (no such object, read only), and an int it returns is the
    size the value must have, so an indicated size that differs is refused with 06070012 or
    06070013 at once; ``None`` accepts any size up to the server's ``max_download``.

    And ``download_limit(index, subindex) -> int | None``: the most bytes a download into an
    object of no fixed size may bring (None: the server's ``max_download``).
    """

    def upload(self, index: int, subindex: int) -> bytes:
        """The current value of ``index:subindex`` (read by the client)."""
        ...

    def download(self, index: int, subindex: int, data: bytes) -> None:
        """Store ``data`` (written by the client) into ``index:subindex``."""
        ...


_SizeHint = Callable[[int, int], "int | None"]


class DictBackend:
    """A back end over a dict ``{(index, subindex): bytes}``, with read-only and write-only
    entries. Unknown entries are refused with 06020000 (no such index) or 06090011 (the index
    exists, the sub-index does not); downloads store the bytes as they arrive."""

    def __init__(
        self,
        entries: Mapping[tuple[int, int], bytes] | None = None,
        *,
        read_only: Iterable[tuple[int, int]] = (),
        write_only: Iterable[tuple[int, int]] = (),
    ) -> None:
        self.entries: dict[tuple[int, int], bytes] = dict(entries or {})
        self.read_only: set[tuple[int, int]] = set(read_only)
        self.write_only: set[tuple[int, int]] = set(write_only)

    def _check(self, key: tuple[int, int]) -> None:
        if key not in self.entries:
            if any(k[0] == key[0] for k in self.entries):
                raise SdoAbort(SdoAbortCode.NO_SUBINDEX)
            raise SdoAbort(SdoAbortCode.NO_OBJECT)

    def upload(self, index: int, subindex: int) -> bytes:
        """The bytes of ``index:subindex``; :class:`SdoAbort` if there is no such entry."""
        key = (index, subindex)
        self._check(key)
        if key in self.write_only:
            raise SdoAbort(SdoAbortCode.READ_WRITE_ONLY)
        return self.entries[key]

    def download(self, index: int, subindex: int, data: bytes) -> None:
        """Store ``data`` at ``index:subindex``; :class:`SdoAbort` if it is read-only or unknown."""
        key = (index, subindex)
        self.size_hint(index, subindex)
        self.entries[key] = bytes(data)

    def size_hint(self, index: int, subindex: int) -> int | None:
        """Always None (any size is taken); aborts for a read-only or unknown entry."""
        key = (index, subindex)
        self._check(key)
        if key in self.read_only:
            raise SdoAbort(SdoAbortCode.WRITE_READ_ONLY)
        return None


@dataclass(frozen=True, slots=True)
class ServerDownloaded(Event):
    """The client wrote ``size`` bytes into ``index:subindex`` and the back end accepted them."""

    index: int
    subindex: int
    size: int


@dataclass(frozen=True, slots=True)
class ServerUploaded(Event):
    """The client read ``size`` bytes of ``index:subindex`` to the end of the transfer."""

    index: int
    subindex: int
    size: int


@dataclass(frozen=True, slots=True)
class ServerAborted(Event):
    """A transfer of ``index:subindex`` ended with ``code``: sent by the client (``by_peer``,
    or superseded by a new request, code 08000000) or by this server (refusal, protocol error
    of the client, timeout)."""

    index: int
    subindex: int
    code: SdoAbortCode | int
    by_peer: bool


# States of the server.
_IDLE = ep.IDLE
_DL_SEG = ep.SEGMENT_IN  # segmented download: waiting for a segment
_UL_SEG = ep.SEGMENT_OUT  # segmented upload: waiting for a segment request
_BDL_DATA = ep.BLOCK_IN  # block download: receiving segments
_BDL_END = ep.BLOCK_IN_END  # block download: all segments acknowledged, waiting for the end request
_BUL_START = ep.OWN_STATES  # block upload: initiate answered, waiting for the start (A3h)
_BUL_ACK = ep.BLOCK_OUT  # block upload: sub-block sent, waiting for its acknowledge
_BUL_END = ep.BLOCK_OUT_END  # block upload: end sent, waiting for the end response (A1h)

_SUPERSEDED = SdoAbortCode.GENERAL_ERROR


class SdoServer(ep.Endpoint):
    """Server side of one SDO channel (see the module text for the choices it makes).

    ``block_size`` (1..127) is the sub-block size the server asks for in block downloads;
    ``crc`` whether it offers the block CRC; ``timeout`` (seconds) how long it waits for the
    next frame of a segmented or block transfer before aborting with 05040000;
    ``reports=False`` builds no events (see :attr:`reports`).
    """

    __slots__ = (
        "_backend",
        "_cap",
        "_download_limit",
        "_hint",
        "_size_hint",
        "max_download",
        "node",
        "reports",
    )

    _ROLE = "server"
    _PEER = "the client"
    _INBOUND = "download"
    _SENDS_ON_RX = False
    _SEGMENT_ANSWER = (
        w.CODE_ONLY.pack(w.SCS_DOWNLOAD_SEGMENT),
        w.CODE_ONLY.pack(w.SCS_DOWNLOAD_SEGMENT | w.TOGGLE),
    )
    _ANSWERS_LAST_SEGMENT = True
    _SEGMENT_OUT_SERVICE = w.CCS_UPLOAD_SEGMENT

    def __init__(
        self,
        rx_cob_id: int,
        tx_cob_id: int,
        backend: SdoServerBackend,
        *,
        timeout: float = 1.0,
        block_size: int = w.MAX_BLOCK_SIZE,
        crc: bool = True,
        max_download: int = 1 << 20,
        reports: bool = True,
    ) -> None:
        super().__init__(rx_cob_id, tx_cob_id, timeout=timeout, block_size=block_size, crc=crc)
        self._backend = backend
        #: Whether transfers are reported as events (:class:`ServerUploaded`,
        #: :class:`ServerDownloaded`, :class:`ServerAborted`). A host that drops them anyway
        #: (a device, whose back end sees every read and write) passes ``reports=False``: no
        #: event is built, one per request saved. The frames are the same either way.
        self.reports = reports
        #: The most bytes a download without size indication may bring into an object of no
        #: fixed size (a domain); objects of a fixed size take at most that size.
        self.max_download = max_download
        self._hint: int | None = None
        self._cap = max_download  # the limit of the object of the download under way
        hint = getattr(backend, "size_hint", None)
        self._size_hint = cast("_SizeHint | None", hint if callable(hint) else None)
        limit = getattr(backend, "download_limit", None)
        self._download_limit = cast("_SizeHint | None", limit if callable(limit) else None)
        self.node = w.node_of(rx_cob_id, tx_cob_id)
        self._index = -1  # -1: no object named yet
        self._subindex = -1

    # -- inputs -------------------------------------------------------------------------------

    def on_timer(self, now: float) -> Out:
        deadline = self.deadline
        if deadline is None or now < deadline:
            return NOTHING
        return self._abort(SdoAbortCode.TIMEOUT)

    def _on_command(self, cmd: int, data: bytes, now: float) -> Out:
        state = self._state
        if cmd == w.ABORT:
            if state == _IDLE:
                return NOTHING
            if not self.reports:
                self._reset()
                return NOTHING
            event = ServerAborted(
                self._index, self._subindex, as_code(self._peer_code(data)), by_peer=True
            )
            self._reset()
            return Out((), (event,))
        service = cmd & w.SERVICE_MASK
        if service == w.CCS_INITIATE_UPLOAD:
            if state == _IDLE:  # the common case, without an empty Out to add
                return self._initiate_upload(data, now)
            return self._superseding(state) + self._initiate_upload(data, now)
        if service == w.CCS_INITIATE_DOWNLOAD:
            if state == _IDLE:
                return self._initiate_download(data, now)
            return self._superseding(state) + self._initiate_download(data, now)
        if service == w.CCS_BLOCK_UPLOAD and cmd & 0x03 == 0:
            return self._superseding(state) + self._initiate_block_upload(data, now)
        if service == w.CCS_BLOCK_DOWNLOAD and cmd & 0x01 == 0:
            return self._superseding(state) + self._initiate_block_download(data, now)
        if state == _BUL_ACK and cmd & w.BLOCK5_MASK == w.BLOCK_ACK:
            return self._block_ack(data, now)
        if state == _BUL_START and cmd & w.BLOCK5_MASK == w.BLOCK_UPLOAD_START:
            self._state = _BUL_ACK
            return self._send_subblock(now)
        if state == _BUL_END and cmd & w.BLOCK5_MASK == w.BLOCK5_END:
            if not self.reports:
                self._reset()
                return NOTHING
            done = ServerUploaded(self._index, self._subindex, len(self._data))
            self._reset()
            return Out((), (done,))
        if state == _BDL_END and cmd & w.BLOCK6_MASK == w.BLOCK6_END:
            return self._block_end_in(data)
        # Anything else: not a valid request here.
        return self._abort(SdoAbortCode.INVALID_COMMAND)

    # -- initiate requests ---------------------------------------------------------------------

    def _superseding(self, state: int) -> Out:
        if state == _IDLE:
            return NOTHING
        if not self.reports:
            self._reset()
            return NOTHING
        event = ServerAborted(self._index, self._subindex, _SUPERSEDED, by_peer=True)
        self._reset()
        return Out((), (event,))

    def _take_mux(self, data: bytes) -> bool:
        """Remember the object a request names; ``False`` when the frame is too short for it."""
        if len(data) < 4:
            self._index, self._subindex = w.MUX.unpack_from(w.padded(data))[1:]
            return False
        self._index, self._subindex = w.MUX.unpack_from(data)[1:]
        return True

    def _initiate_upload(self, data: bytes, now: float) -> Out:
        if len(data) < 4:
            self._take_mux(data)  # the object the abort names, as far as the frame tells
            return self._abort(SdoAbortCode.INVALID_COMMAND)
        _, index, subindex = w.MUX.unpack_from(data)  # _take_mux, inline on every read's path
        self._index = index
        self._subindex = subindex
        try:
            value = bytes(self._backend.upload(index, subindex))
        except SdoAbort as refusal:
            return self._abort(refusal.code)
        return self._upload_response(value, now)

    def _upload_response(self, value: bytes, now: float) -> Out:
        size = len(value)
        if 1 <= size <= 4:
            cmd = w.SCS_INITIATE_UPLOAD | ((4 - size) << 2) | w.EXPEDITED | w.SIZE
            payload = w.WITH_4S.pack(cmd, self._index, self._subindex, value)
            frame = Frame(self._out, payload, extended=self._ext)
            index, subindex = self._index, self._subindex
            # Idle before and after (an expedited upload sets nothing else of a transfer, and
            # a superseded one was reset): only the object named goes, no full _reset.
            self._index = self._subindex = -1
            if not self.reports:
                return _out(Out, ((frame,), ()))
            return Out((frame,), (ServerUploaded(index, subindex, size),))
        self._data = value
        self._pos = 0
        self._toggle = 0
        self._state = _UL_SEG
        cmd = w.SCS_INITIATE_UPLOAD | w.SIZE
        return self._send(w.WITH_U32.pack(cmd, self._index, self._subindex, size), now)

    def _initiate_download(self, data: bytes, now: float) -> Out:
        if len(data) < 4:
            self._take_mux(data)  # the object the abort names, as far as the frame tells
            return self._abort(SdoAbortCode.INVALID_COMMAND)
        cmd, index, subindex = w.MUX.unpack_from(data)  # _take_mux, inline on every write's path
        self._index = index
        self._subindex = subindex
        if cmd & w.EXPEDITED:
            payload = w.WITH_U32.pack(w.SCS_INITIATE_DOWNLOAD, index, subindex, 0)
            reply = (Frame(self._out, payload, extended=self._ext),)
            if cmd & w.SIZE:  # _expedited_in's common case, inline on every write's path
                end = 8 - ((cmd >> 2) & 3)
                if len(data) >= end:
                    return self._received(data[4:end], reply)
            return self._expedited_in(data, reply, "an expedited download request")
        refused = self._take_size(data, w.SIZE)
        if refused is not None:
            return self._abort(refused)
        self._limit = self._no_size_limit()
        self._buf = bytearray()
        self._toggle = 0
        self._state = _DL_SEG
        return self._send(self._mux_frame(w.SCS_INITIATE_DOWNLOAD), now)

    def _initiate_block_upload(self, data: bytes, now: float) -> Out:
        if not self._take_mux(data) or len(data) < 6:
            return self._abort(SdoAbortCode.INVALID_COMMAND)
        blksize = data[4]
        if not 1 <= blksize <= w.MAX_BLOCK_SIZE:
            return self._abort(SdoAbortCode.BLOCK_SIZE)
        pst = data[5]
        try:
            value = bytes(self._backend.upload(self._index, self._subindex))
        except SdoAbort as refusal:
            return self._abort(refusal.code)
        if pst and len(value) <= pst:  # pst 0: the client does not allow a switch
            return self._upload_response(value, now)  # protocol switch to a normal upload
        self._data = value
        self._pos = 0
        self._blksize = blksize
        self._sent_last = False
        self._crc_used = self._crc and bool(data[0] & w.BLOCK_CRC)
        self._state = _BUL_START
        cmd = w.SCS_BLOCK_UPLOAD | (w.BLOCK_CRC if self._crc else 0) | w.BLOCK_SIZE_FLAG
        return self._send(w.WITH_U32.pack(cmd, self._index, self._subindex, len(value)), now)

    def _initiate_block_download(self, data: bytes, now: float) -> Out:
        if not self._take_mux(data):
            return self._abort(SdoAbortCode.INVALID_COMMAND)
        cmd = data[0]
        refused = self._take_size(data, w.BLOCK_SIZE_FLAG)
        if refused is not None:
            return self._abort(refused)
        self._limit = self._no_size_limit()
        self._max_buf = w.block_room(self._size if self._size is not None else self._limit)
        self._buf = bytearray()
        self._expected = 1
        self._blksize = self.block_size
        self._crc_used = self._crc and bool(cmd & w.BLOCK_CRC)
        self._state = _BDL_DATA
        response = w.SCS_BLOCK_DOWNLOAD | (w.BLOCK_CRC if self._crc else 0)
        return self._send(
            w.BLOCK_INIT_RESPONSE.pack(response, self._index, self._subindex, self._blksize), now
        )

    def _take_size(self, data: bytes, flag: int) -> int | None:
        """Take the size a download initiate request indicates (``flag`` set in its command)
        once the back end accepts it; else the abort code that refuses the request."""
        size: int | None = None
        if data[0] & flag:
            if len(data) < 8:
                return SdoAbortCode.INVALID_COMMAND
            size = w.U32.unpack_from(data, 4)[0]
        refused = self._check_size(size)
        if refused is None:
            self._size = size
        return refused

    def _no_size_limit(self) -> int | None:
        """The most bytes a download without size indication may bring: the object's size,
        else :attr:`max_download` (None when a size was indicated: that one applies)."""
        if self._size is not None:
            return None
        return self._hint if self._hint is not None else self._cap

    def _check_size(self, size: int | None) -> int | None:
        """Ask the back end about a download before its data arrives; the abort code or None."""
        self._hint = None
        expected: int | None = None
        if self._size_hint is not None:
            try:
                expected = self._size_hint(self._index, self._subindex)
            except SdoAbort as refusal:
                return refusal.code
            self._hint = expected
        if expected is not None:
            if size is None or size == expected:
                return None
            return SdoAbortCode.LENGTH_TOO_HIGH if size > expected else SdoAbortCode.LENGTH_TOO_LOW
        cap = self.max_download
        if self._download_limit is not None:
            try:
                own = self._download_limit(self._index, self._subindex)
            except SdoAbort as refusal:
                return refusal.code
            if own is not None:
                cap = own
        self._cap = cap
        if size is not None and size > cap:
            return SdoAbortCode.OUT_OF_MEMORY  # (announced: nothing buffered, nothing waited)
        return None

    # -- segmented -----------------------------------------------------------------------------

    def _segment_out(self, cmd: int, now: float) -> Out:
        """An upload segment request."""
        toggle = cmd & w.TOGGLE
        if toggle != self._toggle:
            return self._abort(SdoAbortCode.TOGGLE_BIT)
        pos = self._pos
        value = self._data
        chunk = value[pos : pos + 7]
        pos += 7
        if pos >= len(value):
            frame = self._frame(w.SEGMENT.pack(toggle | ((7 - len(chunk)) << 1) | w.LAST, chunk))
            if not self.reports:
                self._reset()
                return Out((frame,))
            event = ServerUploaded(self._index, self._subindex, len(value))
            self._reset()
            return Out((frame,), (event,))
        self._pos = pos
        self._toggle = toggle ^ w.TOGGLE
        return self._send(w.SEGMENT.pack(toggle, chunk), now)

    # -- helpers -------------------------------------------------------------------------------

    def _mux_frame(self, cmd: int) -> bytes:
        return w.WITH_U32.pack(cmd, self._index, self._subindex, 0)

    def _received(self, value: bytes, reply: tuple[Frame, ...]) -> Out:
        """Hand a complete download to the back end; answer ``reply`` when it accepts."""
        try:
            self._backend.download(self._index, self._subindex, value)
        except SdoAbort as refusal:
            return self._abort(refusal.code)
        events: tuple[Event, ...] = ()
        if self.reports:
            events = (ServerDownloaded(self._index, self._subindex, len(value)),)
        if self._state == _IDLE:  # expedited: nothing else of a transfer was set
            self._index = self._subindex = -1
        else:
            self._reset()
        return _out(Out, (reply, events))

    def _violation(self, code: int, reason: str) -> Out:
        return self._abort(code)  # the server reports the code only (ServerAborted)

    def _abort(self, code: int) -> Out:
        """Send abort ``code`` for the current object and end the transfer, if any."""
        if self._index < 0:  # outside a transfer: name no object
            self._index = self._subindex = 0
        frame = self._frame(w.WITH_U32.pack(w.ABORT, self._index, self._subindex, code))
        if not self.reports:
            self._reset()
            return Out((frame,))
        event = ServerAborted(self._index, self._subindex, as_code(code), by_peer=False)
        self._reset()
        return Out((frame,), (event,))

    def _reset(self) -> None:
        super()._reset()
        self._index = -1
        self._subindex = -1

    @staticmethod
    def _peer_code(data: bytes) -> int:
        return int(w.U32.unpack_from(w.padded(data), 4)[0])
