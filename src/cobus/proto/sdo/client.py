"""The SDO client machine (CiA 301): expedited, segmented and block transfers, sans-I/O.

One :class:`SdoClient` drives one SDO channel: it sends on the server's receive COB-ID
(600h + node-ID by default) and listens on the server's transmit COB-ID (580h + node-ID). It
runs one transfer at a time; the transfer ends with exactly one event: :class:`UploadDone`,
:class:`DownloadDone` or :class:`TransferFailed`.

Choices where CiA 301 leaves room:

- Replies shorter than 8 bytes are accepted when everything the reply means is present (for
  example a download response ``60 idx idx sub`` of 4 bytes, or an expedited upload response
  that carries its data bytes). A reply missing bytes its command needs is a protocol error
  (abort 05040001). Empty frames on the response COB-ID are ignored.
- While the client waits for the answer to its initiate request, a reply that cannot be that
  answer is taken as stale and dropped (CiA 301 lets the client ignore it): an initiate
  response for another object, a reply of another service (a download response while an
  upload is asked for), an abort naming another index than the one requested or 0:0. Such
  replies come from a server answering a transfer the client already gave up (it answers
  late), or from a second client on the same channel; the transfer goes on waiting, and if
  it then times out the timeout says what was dropped. ``stale_replies`` counts them.
- An abort from the server naming the object or 0:0 (some servers send 0:0) ends the
  transfer; in the data phases any abort ends it.
- Data beyond an indicated size is refused with abort 06070012, missing data with 06070013.
- During the data phase of a block upload every frame except an abort (80h) is a block segment:
  the protocol gives no way to tell them apart. A segment out of sequence is ignored; at the
  end of the sub-block (its last sequence number or the segment flagged last) the client
  acknowledges the last segment received in sequence, and the server resends from there.
  A sequence number of 0 or above the block size is refused with abort 05040003.
- Frames outside a transfer, on other COB-IDs and remote frames are ignored.
"""

from __future__ import annotations

from dataclasses import dataclass

from cobus.proto._base import NOTHING, Event, Out
from cobus.proto.frame import Frame
from cobus.proto.sdo import _endpoint as ep
from cobus.proto.sdo import _wire as w
from cobus.proto.sdo.abort import SdoAbortCode
from cobus.proto.sdo.errors import (
    SdoAbortedError,
    SdoBusyError,
    SdoError,
    SdoParameterError,
    SdoProtocolError,
    SdoTimeoutError,
)

__all__ = ["DownloadDone", "SdoClient", "TransferFailed", "UploadDone"]


@dataclass(frozen=True, slots=True)
class UploadDone(Event):
    """An upload (read) ended well with ``data`` (padding of expedited frames removed)."""

    index: int
    subindex: int
    data: bytes


@dataclass(frozen=True, slots=True)
class DownloadDone(Event):
    """A download (write) was confirmed by the server."""

    index: int
    subindex: int


@dataclass(frozen=True, slots=True)
class TransferFailed(Event):
    """A transfer ended without success; ``error`` says why.

    :class:`SdoAbortedError`: the server aborted (``by_peer``) or :meth:`SdoClient.abort` was
    called; :class:`SdoProtocolError`: the server broke the protocol and the client aborted;
    :class:`SdoTimeoutError`: no answer in time and the client sent abort 05040000.
    """

    index: int
    subindex: int
    error: SdoError


# States of the client.
_IDLE = ep.IDLE
_DL_INIT = ep.OWN_STATES  # initiate download sent, waiting for 60h
_DL_SEG = ep.SEGMENT_OUT  # download segment sent, waiting for 20h/30h
_UL_INIT = ep.OWN_STATES + 1  # initiate upload sent, waiting for 4xh
_UL_SEG = ep.SEGMENT_IN  # upload segment request sent, waiting for a segment
_BUL_INIT = ep.OWN_STATES + 2  # initiate block upload sent, waiting for C0h.. (or 4xh: switch)
_BUL_DATA = ep.BLOCK_IN  # receiving block segments
_BUL_END = ep.BLOCK_IN_END  # last segment acknowledged, waiting for the end (C1h..)
_BDL_INIT = ep.OWN_STATES + 3  # initiate block download sent, waiting for A0h..
_BDL_ACK = ep.BLOCK_OUT  # sub-block sent, waiting for its acknowledge (A2h)
_BDL_END = ep.BLOCK_OUT_END  # end sent, waiting for A1h

_UPLOADS = (_UL_INIT, _UL_SEG, _BUL_INIT, _BUL_DATA, _BUL_END)
_INITIATING = (_UL_INIT, _DL_INIT, _BUL_INIT, _BDL_INIT)
# Command specifiers (bits 7..5) a server sends; 80h (abort) is taken before, E0h never is.
_SERVER_SERVICES = frozenset(
    (
        w.SCS_UPLOAD_SEGMENT,
        w.SCS_DOWNLOAD_SEGMENT,
        w.SCS_INITIATE_UPLOAD,
        w.SCS_INITIATE_DOWNLOAD,
        w.SCS_BLOCK_DOWNLOAD,
        w.SCS_BLOCK_UPLOAD,
    )
)

_BLOCK_HINT = (
    "the server may not support block transfers: retry without block, or check the "
    "server's sub-index of 1200h and the device's EDS"
)


class SdoClient(ep.Endpoint):
    """Client side of one SDO channel.

    ``rx_cob_id`` is the COB-ID the server receives on (the client sends there), ``tx_cob_id``
    the one it transmits on. ``timeout`` (seconds) applies to every wait for the server.
    ``block_size`` (1..127) is the sub-block size proposed for block uploads, ``pst`` the
    protocol switch threshold sent with them (0: the server must not switch; else it may answer
    objects of up to ``pst`` bytes with a normal upload), ``crc`` whether the client offers the
    block CRC. ``node`` names the node in error messages (derived from default COB-IDs).
    """

    __slots__ = ("_channel", "_last_stale", "_node", "_pst", "_stale", "stale_replies")

    _ROLE = "client"
    _PEER = "the server"
    _INBOUND = "upload"
    _SENDS_ON_RX = True
    _SEGMENT_ANSWER = (
        w.CODE_ONLY.pack(w.CCS_UPLOAD_SEGMENT | w.TOGGLE),
        w.CODE_ONLY.pack(w.CCS_UPLOAD_SEGMENT),
    )
    _ANSWERS_LAST_SEGMENT = False
    _SEGMENT_OUT_SERVICE = w.SCS_DOWNLOAD_SEGMENT

    def __init__(
        self,
        rx_cob_id: int,
        tx_cob_id: int,
        *,
        timeout: float = 1.0,
        block_size: int = w.MAX_BLOCK_SIZE,
        pst: int = 0,
        crc: bool = True,
        node: int | None = None,
    ) -> None:
        super().__init__(rx_cob_id, tx_cob_id, timeout=timeout, block_size=block_size, crc=crc)
        if not 0 <= pst <= 0xFF:
            raise SdoParameterError(f"protocol switch threshold {pst} does not fit a byte (0..255)")
        self._pst = pst
        self._node = node if node is not None else w.node_of(rx_cob_id, tx_cob_id)
        self._channel = f"0x{rx_cob_id:X}/0x{tx_cob_id:X}"
        #: Replies dropped as stale since the client was made (see the module's notes).
        self.stale_replies = 0
        self._stale = 0  # ... during the transfer under way
        self._last_stale = ""

    # -- properties --------------------------------------------------------------------------

    @property
    def node(self) -> int | None:
        """The node-ID named in error messages (``None``: the channel's COB-IDs are named)."""
        return self._node

    # -- starting and aborting ---------------------------------------------------------------

    def start_upload(self, index: int, subindex: int, now: float, *, block: bool = False) -> Out:
        """Read ``index:subindex`` from the server; ends with :class:`UploadDone` or a failure.

        ``block=True`` asks for a block upload (the server may switch to a normal upload when
        the object has at most ``pst`` bytes).
        """
        self._begin(index, subindex)
        self._buf = bytearray()
        self._size = None
        if block:
            self._state = _BUL_INIT
            self._blksize = self.block_size
            cmd = w.CCS_BLOCK_UPLOAD | (w.BLOCK_CRC if self._crc else 0)
            payload = w.BLOCK_UPLOAD_INIT.pack(cmd, index, subindex, self._blksize, self._pst)
        else:
            self._state = _UL_INIT
            payload = w.WITH_U32.pack(w.CCS_INITIATE_UPLOAD, index, subindex, 0)
        return self._send(payload, now)

    def start_download(
        self,
        index: int,
        subindex: int,
        data: bytes | bytearray | memoryview,
        now: float,
        *,
        block: bool = False,
        size_indicated: bool = True,
        expedited: bool = True,
    ) -> Out:
        """Write ``data`` to ``index:subindex``; ends with :class:`DownloadDone` or a failure.

        Up to 4 bytes go expedited unless ``expedited=False`` or ``block=True``; more go
        segmented, or as a block download with ``block=True``. ``size_indicated=False`` leaves
        the size out of the initiate frame (an expedited download is then sent as ``22h`` with
        the data padded to 4 bytes with zeros), for servers that want it so.
        """
        payload_data = bytes(data)
        size = len(payload_data)
        if size > 0xFFFFFFFF:
            raise SdoParameterError(f"{size} bytes do not fit an SDO transfer (at most 4 GiB - 1)")
        self._begin(index, subindex)
        self._data = payload_data
        self._pos = 0
        if block:
            self._state = _BDL_INIT
            self._sent_last = False
            cmd = w.CCS_BLOCK_DOWNLOAD | (w.BLOCK_CRC if self._crc else 0)
            if size_indicated:
                cmd |= w.BLOCK_SIZE_FLAG
            payload = w.WITH_U32.pack(cmd, index, subindex, size if size_indicated else 0)
        elif expedited and 1 <= size <= 4:
            self._state = _DL_INIT
            if size_indicated:
                cmd = w.CCS_INITIATE_DOWNLOAD | ((4 - size) << 2) | w.EXPEDITED | w.SIZE
            else:
                cmd = w.CCS_INITIATE_DOWNLOAD | w.EXPEDITED
            payload = w.WITH_4S.pack(cmd, index, subindex, payload_data)
            self._sent_last = True  # nothing follows the initiate
        else:
            self._state = _DL_INIT
            self._sent_last = False
            self._toggle = 0
            cmd = w.CCS_INITIATE_DOWNLOAD | (w.SIZE if size_indicated else 0)
            payload = w.WITH_U32.pack(cmd, index, subindex, size if size_indicated else 0)
        return self._send(payload, now)

    def abort(self, code: int, now: float) -> Out:
        """Abort the running transfer with ``code``: sends the abort and ends the transfer with
        :class:`TransferFailed` (an :class:`SdoAbortedError` with ``by_peer=False``).
        Does nothing when no transfer runs."""
        if not 0 <= code <= 0xFFFFFFFF:
            raise SdoParameterError(f"SDO abort code {code} does not fit 32 bits")
        if self._state == _IDLE:
            return NOTHING
        error = SdoAbortedError(
            code,
            index=self._index,
            subindex=self._subindex,
            node=self._node,
            channel=self._channel,
            by_peer=False,
        )
        return self._fail(error, code)

    # -- inputs -------------------------------------------------------------------------------

    def on_timer(self, now: float) -> Out:
        deadline = self.deadline
        if deadline is None or now < deadline:
            return NOTHING
        stale = None
        if self._stale:
            stale = (
                f"{self._stale} stale repl{'y' if self._stale == 1 else 'ies'} dropped, the "
                f"last {self._last_stale}: the server answers late or another client uses this "
                "channel"
            )
        error = SdoTimeoutError(
            index=self._index,
            subindex=self._subindex,
            timeout=self._timeout,
            node=self._node,
            channel=self._channel,
            stale=stale,
        )
        return self._fail(error, SdoAbortCode.TIMEOUT)

    def _on_command(self, cmd: int, data: bytes, now: float) -> Out:
        state = self._state
        if state == _IDLE:
            return NOTHING
        if cmd == w.ABORT:
            if state in _INITIATING and not self._abort_ours(data):
                return self._drop_stale(data)
            return self._peer_abort(data)
        if state == _UL_SEG:  # an upload segment goes to _segment_in
            return self._unexpected(cmd, "an upload segment (0xh/1xh)")
        if state == _DL_SEG:  # a download segment response goes to _segment_out
            return self._unexpected(cmd, "a download segment response (20h/30h)")
        if state == _BDL_ACK:
            if cmd & w.BLOCK5_MASK != w.BLOCK_ACK:
                return self._unexpected(cmd, "a block acknowledge (A2h)")
            return self._block_ack(data, now)
        if state == _UL_INIT:
            return self._upload_response(data, now)
        if state == _DL_INIT:
            return self._download_response(data, now)
        if state == _BUL_INIT:
            return self._block_upload_response(data, now)
        if state == _BUL_END:
            if cmd & w.BLOCK6_MASK != w.BLOCK6_END:
                return self._unexpected(cmd, "a block upload end (C1h..DDh)")
            return self._block_end_in(data)
        if state == _BDL_INIT:
            return self._block_download_response(data, now)
        # _BDL_END
        if cmd & w.BLOCK5_MASK != w.BLOCK5_END:
            return self._unexpected(cmd, "a block download end response (A1h)")
        return self._succeed(DownloadDone(self._index, self._subindex))

    # -- expedited and segmented ---------------------------------------------------------------

    def _upload_response(self, data: bytes, now: float) -> Out:
        cmd = data[0]
        if cmd & w.SERVICE_MASK != w.SCS_INITIATE_UPLOAD:
            return self._other(data, "an upload response (4xh)")
        if not self._mux_ok(data):
            return self._mux_error(data)
        if cmd & w.EXPEDITED:
            return self._expedited_in(data, (), "an expedited upload response")
        if cmd & w.SIZE:
            if len(data) < 8:
                return self._short(data, "an upload response with its size")
            self._size = w.U32.unpack_from(data, 4)[0]
        else:
            self._size = None
        self._state = _UL_SEG
        self._toggle = 0
        return self._send(w.CODE_ONLY.pack(w.CCS_UPLOAD_SEGMENT), now)

    def _download_response(self, data: bytes, now: float) -> Out:
        cmd = data[0]
        if cmd & w.SERVICE_MASK != w.SCS_INITIATE_DOWNLOAD:
            return self._other(data, "a download response (60h)")
        if not self._mux_ok(data):
            return self._mux_error(data)
        if self._sent_last:  # expedited: done
            return self._succeed(DownloadDone(self._index, self._subindex))
        self._state = _DL_SEG
        return self._next_download_segment(now)

    def _next_download_segment(self, now: float) -> Out:
        pos = self._pos
        chunk = self._data[pos : pos + 7]
        self._pos = pos + 7
        last = self._pos >= len(self._data)
        self._sent_last = last
        cmd = self._toggle | ((7 - len(chunk)) << 1) | (w.LAST if last else 0)
        return self._send(w.SEGMENT.pack(cmd, chunk), now)

    def _segment_out(self, cmd: int, now: float) -> Out:
        """A download segment response."""
        toggle = cmd & w.TOGGLE
        if toggle != self._toggle:
            return self._violation(
                SdoAbortCode.TOGGLE_BIT,
                f"download segment response with toggle bit {toggle >> 4}, "
                f"expected {self._toggle >> 4}",
            )
        if self._sent_last:
            return self._succeed(DownloadDone(self._index, self._subindex))
        self._toggle = toggle ^ w.TOGGLE
        return self._next_download_segment(now)

    # -- block upload ------------------------------------------------------------------------

    def _block_upload_response(self, data: bytes, now: float) -> Out:
        cmd = data[0]
        if cmd & w.SERVICE_MASK == w.SCS_INITIATE_UPLOAD:
            # Protocol switch: the server answers with a normal upload (CiA 301 allows it when
            # the size is at most pst; accepted whatever pst was, the data is the same).
            return self._upload_response(data, now)
        if cmd & w.BLOCK6_MASK != w.SCS_BLOCK_UPLOAD:
            return self._other(data, "a block upload response (C0h..C6h) or upload response")
        if not self._mux_ok(data):
            return self._mux_error(data)
        if cmd & w.BLOCK_SIZE_FLAG:
            if len(data) < 8:
                return self._short(data, "a block upload response with its size")
            self._size = w.U32.unpack_from(data, 4)[0]
        self._max_buf = w.block_room(self._size)
        self._crc_used = self._crc and bool(cmd & w.BLOCK_CRC)
        self._state = _BUL_DATA
        self._expected = 1
        return self._send(w.CODE_ONLY.pack(w.BLOCK_UPLOAD_START), now)

    # -- block download -------------------------------------------------------------------------

    def _block_download_response(self, data: bytes, now: float) -> Out:
        cmd = data[0]
        if cmd & w.BLOCK5_MASK != w.SCS_BLOCK_DOWNLOAD:
            return self._other(data, "a block download response (A0h/A4h)")
        if not self._mux_ok(data):
            return self._mux_error(data)
        if len(data) < 5:
            return self._short(data, "a block download response with its block size")
        blksize = data[4]
        if not 1 <= blksize <= w.MAX_BLOCK_SIZE:
            return self._violation(
                SdoAbortCode.BLOCK_SIZE, f"the server asked for sub-blocks of {blksize} segments"
            )
        self._blksize = blksize
        self._crc_used = self._crc and bool(cmd & w.BLOCK_CRC)
        self._state = _BDL_ACK
        return self._send_subblock(now)

    # -- helpers -------------------------------------------------------------------------------

    def _begin(self, index: int, subindex: int) -> None:
        if self._state != _IDLE:
            kind = "upload" if self._state in _UPLOADS else "download"
            raise SdoBusyError(
                f"SDO channel {self._channel} is busy with the {kind} of "
                f"0x{self._index:04X}:{self._subindex:02X}; wait for its completion event or "
                "abort it first (one transfer at a time per channel)",
                index=index,
                subindex=subindex,
                node=self._node,
            )
        w.check_object(index, subindex)
        self._index = index
        self._subindex = subindex
        self._stale = 0

    def _succeed(self, event: Event) -> Out:
        self._reset()
        return Out((), (event,))

    def _received(self, value: bytes, reply: tuple[Frame, ...]) -> Out:
        event = UploadDone(self._index, self._subindex, value)
        self._reset()
        return Out(reply, (event,))

    def _fail(self, error: SdoError, code: int) -> Out:
        frame = self._frame(w.WITH_U32.pack(w.ABORT, self._index, self._subindex, code))
        event = TransferFailed(self._index, self._subindex, error)
        self._reset()
        return Out((frame,), (event,))

    def _violation(self, code: int, reason: str) -> Out:
        error = SdoProtocolError(
            code,
            reason,
            index=self._index,
            subindex=self._subindex,
            node=self._node,
            channel=self._channel,
        )
        return self._fail(error, code)

    def _unexpected(self, cmd: int, wanted: str) -> Out:
        return self._violation(
            SdoAbortCode.INVALID_COMMAND, f"the server sent command {cmd:02X}h, not {wanted}"
        )

    def _mux_ok(self, data: bytes) -> bool:
        return (
            len(data) >= 4
            and (data[1] | (data[2] << 8)) == self._index
            and data[3] == self._subindex
        )

    def _mux_error(self, data: bytes) -> Out:
        if len(data) < 4:
            return self._short(data, "an initiate response (command, index, sub-index)")
        return self._drop_stale(data)

    def _other(self, data: bytes, wanted: str) -> Out:
        """An initiate response of another service than the one asked for: a stale reply of
        an earlier transfer, unless no server sends that command at all."""
        cmd = data[0]
        if cmd & w.SERVICE_MASK in _SERVER_SERVICES:
            return self._drop_stale(data)
        return self._unexpected(cmd, wanted)

    def _abort_ours(self, data: bytes) -> bool:
        """Whether an abort names the index asked for (any sub-index: some servers name
        another), 0:0, or nothing (a short frame)."""
        if len(data) < 4:
            return True
        _, index, subindex = w.MUX.unpack_from(data)
        return index == self._index or (index, subindex) == (0, 0)

    def _drop_stale(self, data: bytes) -> Out:
        self._stale += 1
        self.stale_replies += 1
        what = f"command {data[0]:02X}h"
        if len(data) >= 4:
            _, index, subindex = w.MUX.unpack_from(data)
            what += f" for 0x{index:04X}:{subindex:02X}"
        self._last_stale = what
        return NOTHING

    def _peer_abort(self, data: bytes) -> Out:
        code = w.U32.unpack_from(w.padded(data), 4)[0]
        initiating_block = self._state in (_BUL_INIT, _BDL_INIT)
        hint = _BLOCK_HINT if initiating_block and code == SdoAbortCode.INVALID_COMMAND else None
        error = SdoAbortedError(
            code,
            index=self._index,
            subindex=self._subindex,
            node=self._node,
            channel=self._channel,
            hint=hint,
        )
        event = TransferFailed(self._index, self._subindex, error)
        self._reset()
        return Out((), (event,))
