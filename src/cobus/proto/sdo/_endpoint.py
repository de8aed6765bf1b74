"""What the SDO client and server machines share (private).

SDO is symmetric in its data phase: each side sends the data of one direction and receives the
data of the other (the client receives uploads, the server downloads). :class:`Endpoint` holds
the per-transfer state and the steps that are the same whichever side runs them: receiving an
expedited value, segments and block segments (with the block end), sending sub-blocks and
taking their acknowledges. A machine derives from it and says how it differs:

- ``_ROLE``, ``_PEER`` and ``_INBOUND`` name it, its peer and the service whose data it
  receives, in error texts;
- it sends on ``rx_cob_id`` when it is the client (``_SENDS_ON_RX``), else on ``tx_cob_id``;
- ``_SEGMENT_ANSWER`` and ``_ANSWERS_LAST_SEGMENT`` say how it answers a segment it receives;
- ``_segment_out`` takes the frame (of service ``_SEGMENT_OUT_SERVICE``) that asks for or
  confirms a segment it sends;
- ``_violation`` reports a protocol error of the peer, ``_received`` takes a complete value,
  ``_on_command`` every other frame.

:meth:`Endpoint.on_frame` handles the frames of the data phases itself, so that they cost no
more calls than they did before the machines shared it.
"""

from __future__ import annotations

from typing import ClassVar

from cobus.proto._base import NOTHING, Out
from cobus.proto.frame import Frame
from cobus.proto.sdo import _wire as w
from cobus.proto.sdo.abort import SdoAbortCode
from cobus.proto.sdo.crc import crc16

# States both machines name alike; each numbers its own from OWN_STATES on.
IDLE = 0
SEGMENT_IN = 1  # segmented transfer: waiting for a segment
SEGMENT_OUT = 2  # segmented transfer: waiting for the request or confirmation of a segment
BLOCK_IN = 3  # receiving block segments
BLOCK_IN_END = 4  # last block segment acknowledged, waiting for the end request/end
BLOCK_OUT = 5  # sub-block sent, waiting for its acknowledge
BLOCK_OUT_END = 6  # block end sent, waiting for the end response
OWN_STATES = 7


class Endpoint:
    """One side of an SDO channel: the state and steps the client and server share."""

    __slots__ = (
        "_blksize",
        "_buf",
        "_crc",
        "_crc_used",
        "_data",
        "_expected",
        "_ext",
        "_in",
        "_index",
        "_limit",
        "_max_buf",
        "_out",
        "_pos",
        "_sent",
        "_sent_last",
        "_size",
        "_state",
        "_subindex",
        "_timeout",
        "_toggle",
        "block_size",
        "deadline",
    )

    _ROLE: ClassVar[str]  # "client" / "server"
    _PEER: ClassVar[str]  # "the server" / "the client"
    _INBOUND: ClassVar[str]  # the service whose data this side receives: "upload" / "download"
    _SENDS_ON_RX: ClassVar[bool]  # the client sends on the server's receive COB-ID
    # The answer to a segment received with toggle bit 0 / 1: the server confirms that segment
    # (same toggle), the client asks for the next one (the other toggle).
    _SEGMENT_ANSWER: ClassVar[tuple[bytes, bytes]]
    # Whether the last segment is answered too (the server confirms it; the client has nothing
    # more to ask for).
    _ANSWERS_LAST_SEGMENT: ClassVar[bool]
    # The service (command & E0h) of the frame that asks for / confirms a segment this side
    # sends: the client's download segments are confirmed with 20h/30h, the server's upload
    # segments asked for with 60h/70h.
    _SEGMENT_OUT_SERVICE: ClassVar[int]

    def __init__(
        self, rx_cob_id: int, tx_cob_id: int, *, timeout: float, block_size: int, crc: bool
    ) -> None:
        rx_ext = w.check_cob_id(f"SDO {self._ROLE} COB-ID rx_cob_id", rx_cob_id)
        tx_ext = w.check_cob_id(f"SDO {self._ROLE} COB-ID tx_cob_id", tx_cob_id)
        if self._SENDS_ON_RX:
            self._out, self._in, self._ext = rx_cob_id, tx_cob_id, rx_ext
        else:
            self._out, self._in, self._ext = tx_cob_id, rx_cob_id, tx_ext
        self._timeout = w.check_timeout(timeout)
        self.block_size = w.check_block_size(block_size)
        self._crc = crc
        self._state = IDLE
        #: When :meth:`on_timer` must be called next (None: never): a plain attribute, read
        #: after every step by the host that drives the machine. Read it, do not write it.
        self.deadline: float | None = None
        self._index = 0
        self._subindex = 0
        self._data = b""
        self._buf = bytearray()
        self._pos = 0
        self._size: int | None = None
        #: the most bytes taken when no size was indicated (None: no limit)
        self._limit: int | None = None
        self._max_buf = 0
        self._toggle = 0
        self._blksize = 0
        self._expected = 1
        self._sent = 0
        self._sent_last = False
        self._crc_used = False

    @property
    def rx_cob_id(self) -> int:
        """The COB-ID the server receives on (the client sends there)."""
        return self._out if self._SENDS_ON_RX else self._in

    @property
    def tx_cob_id(self) -> int:
        """The COB-ID the server transmits on (the client listens there)."""
        return self._in if self._SENDS_ON_RX else self._out

    @property
    def busy(self) -> bool:
        """True while a transfer runs: the client cannot start another; the server has one
        only while a segmented or block transfer runs."""
        return self._state != IDLE

    @property
    def progress(self) -> tuple[int, int | None]:
        """(bytes moved, bytes in all) of the transfer under way: what a progress bar shows.
        The total is None while unknown (an upload before the size came, or without one);
        (0, None) when idle."""
        if self._state == IDLE:
            return 0, None
        if self._data:  # this side sends
            return min(self._pos, len(self._data)), len(self._data)
        got = len(self._buf)  # (a block's last segment brings padding beyond the size)
        return (got if self._size is None else min(got, self._size)), self._size

    @property
    def timeout(self) -> float:
        return self._timeout

    @timeout.setter
    def timeout(self, value: float) -> None:
        """Change the timeout; it applies from the next frame sent."""
        self._timeout = w.check_timeout(value)

    # -- hooks ---------------------------------------------------------------------------------

    def _on_command(self, cmd: int, data: bytes, now: float) -> Out:
        """A frame on the receive COB-ID that :meth:`on_frame` does not take itself (``data``
        not empty)."""
        raise NotImplementedError

    def _segment_out(self, cmd: int, now: float) -> Out:
        """The peer asks for or confirms a segment this side sends (service checked)."""
        raise NotImplementedError

    def _violation(self, code: int, reason: str) -> Out:
        """The peer broke the protocol: abort the transfer with ``code`` (``reason`` says why)."""
        raise NotImplementedError

    def _received(self, value: bytes, reply: tuple[Frame, ...]) -> Out:
        """The whole ``value`` arrived; end the transfer, sending ``reply`` when it is taken."""
        raise NotImplementedError

    # -- inputs --------------------------------------------------------------------------------

    def on_frame(self, frame: Frame, now: float) -> Out:
        data = frame.data
        if frame.cob_id != self._in or frame.rtr or not data:
            return NOTHING
        cmd = data[0]
        state = self._state
        if state == BLOCK_IN and cmd != w.ABORT:
            # The hot path of block transfers: one segment received.
            seq = cmd & 0x7F
            if seq == self._expected:
                if len(data) < 8:
                    data = w.padded(data)
                buf = self._buf
                buf += data[1:]
                if len(buf) > self._max_buf:
                    return self._violation(SdoAbortCode.LENGTH_TOO_HIGH, self._too_long())
                if cmd & w.LAST_SEGMENT:
                    self._state = BLOCK_IN_END
                    return self._send(w.ACK.pack(w.BLOCK_ACK, seq, self._blksize), now)
                if seq == self._blksize:
                    self._expected = 1
                    return self._send(w.ACK.pack(w.BLOCK_ACK, seq, self._blksize), now)
                self._expected = seq + 1
                self.deadline = now + self._timeout
                return NOTHING
            return self._out_of_sequence(cmd, now)
        if state == SEGMENT_IN and not cmd & w.SERVICE_MASK:  # segments are ccs / scs 0
            return self._segment_in(data, now)
        if state == SEGMENT_OUT and cmd & w.SERVICE_MASK == self._SEGMENT_OUT_SERVICE:
            return self._segment_out(cmd, now)
        return self._on_command(cmd, data, now)

    # -- receiving -----------------------------------------------------------------------------

    def _expedited_in(self, data: bytes, reply: tuple[Frame, ...], what: str) -> Out:
        """The value of an expedited initiate frame (``what`` names it in errors)."""
        cmd = data[0]
        if cmd & w.SIZE:
            count = 4 - ((cmd >> 2) & 3)
            if len(data) < 4 + count:
                return self._short(data, f"{what} of {count} bytes")
            return self._received(data[4 : 4 + count], reply)
        return self._received(data[4:8], reply)

    def _segment_in(self, data: bytes, now: float) -> Out:
        """A segment of a segmented transfer."""
        cmd = data[0]
        toggle = cmd & w.TOGGLE
        if toggle != self._toggle:
            return self._violation(
                SdoAbortCode.TOGGLE_BIT,
                f"{self._INBOUND} segment with toggle bit {toggle >> 4}, "
                f"expected {self._toggle >> 4}",
            )
        end = 8 - ((cmd >> 1) & 7)
        if len(data) < end:
            article = "an" if self._INBOUND == "upload" else "a"
            return self._short(data, f"{article} {self._INBOUND} segment of {end - 1} bytes")
        buf = self._buf
        buf += data[1:end]
        size = self._size
        if size is not None and len(buf) > size:
            return self._violation(
                SdoAbortCode.LENGTH_TOO_HIGH,
                f"{self._PEER} sent more than the {size} bytes it announced",
            )
        if size is None and self._limit is not None and len(buf) > self._limit:
            return self._violation(SdoAbortCode.LENGTH_TOO_HIGH, self._too_long())
        answer = self._SEGMENT_ANSWER[toggle >> 4]
        if cmd & w.LAST:
            if size is not None and len(buf) < size:
                return self._violation(
                    SdoAbortCode.LENGTH_TOO_LOW,
                    f"{self._PEER} ended after {len(buf)} of the {size} bytes it announced",
                )
            reply = (self._frame(answer),) if self._ANSWERS_LAST_SEGMENT else ()
            return self._received(bytes(buf), reply)
        self._toggle = toggle ^ w.TOGGLE
        return self._send(answer, now)

    def _out_of_sequence(self, cmd: int, now: float) -> Out:
        seq = cmd & 0x7F
        blksize = self._blksize
        if seq == 0 or seq > blksize:
            return self._violation(
                SdoAbortCode.SEQUENCE_NUMBER,
                f"block segment with sequence number {seq} (valid: 1..{blksize})",
            )
        if cmd & w.LAST_SEGMENT or seq == blksize:
            # End of a sub-block with a gap: acknowledge what arrived in sequence.
            ackseq = self._expected - 1
            self._expected = 1
            return self._send(w.ACK.pack(w.BLOCK_ACK, ackseq, blksize), now)
        self.deadline = now + self._timeout
        return NOTHING  # a segment after a lost one: dropped, the peer sends it again

    def _block_end_in(self, data: bytes) -> Out:
        """The end of a block transfer received (its command checked by the caller)."""
        if self._crc_used and len(data) < 3:
            return self._short(data, f"a block {self._INBOUND} end with its CRC")
        buf = self._buf
        del buf[len(buf) - ((data[0] >> 2) & 7) :]
        size = self._size
        if size is not None and len(buf) != size:
            code = SdoAbortCode.LENGTH_TOO_HIGH if len(buf) > size else SdoAbortCode.LENGTH_TOO_LOW
            return self._violation(
                code,
                f"{self._PEER} sent {len(buf)} bytes in a block {self._INBOUND} "
                f"announced as {size}",
            )
        if self._crc_used:
            crc = w.U16.unpack_from(data, 1)[0]
            mine = crc16(buf)
            if crc != mine:
                return self._violation(
                    SdoAbortCode.CRC,
                    f"block {self._INBOUND} CRC {crc:04X}h from {self._PEER}, {mine:04X}h computed",
                )
        return self._received(bytes(buf), (self._frame(w.CODE_ONLY.pack(w.BLOCK5_END)),))

    # -- sending -------------------------------------------------------------------------------

    def _send_subblock(self, now: float) -> Out:
        frames, self._sent, self._sent_last = w.subblock(
            self._out, self._ext, self._data, self._pos, self._blksize
        )
        self.deadline = now + self._timeout
        return Out(frames)

    def _block_ack(self, data: bytes, now: float) -> Out:
        """A block acknowledge received (its command checked by the caller)."""
        if len(data) < 3:
            return self._short(data, "a block acknowledge")
        ackseq = data[1]
        blksize = data[2]
        if ackseq > self._sent:
            return self._violation(
                SdoAbortCode.SEQUENCE_NUMBER,
                f"{self._PEER} acknowledged segment {ackseq} of a sub-block of {self._sent}",
            )
        if not 1 <= blksize <= w.MAX_BLOCK_SIZE:
            return self._violation(
                SdoAbortCode.BLOCK_SIZE, f"{self._PEER} asked for sub-blocks of {blksize} segments"
            )
        self._pos += 7 * ackseq
        if self._sent_last and ackseq == self._sent:
            total = len(self._data)
            crc = crc16(self._data) if self._crc_used else 0
            cmd = w.BLOCK6_END | (w.unused_in_last(total) << 2)
            self._state = BLOCK_OUT_END
            return self._send(w.END_CRC.pack(cmd, crc), now)
        self._sent_last = False
        self._blksize = blksize
        return self._send_subblock(now)

    # -- helpers -------------------------------------------------------------------------------

    def _frame(self, payload: bytes) -> Frame:
        return Frame(self._out, payload, extended=self._ext)

    def _send(self, payload: bytes, now: float) -> Out:
        self.deadline = now + self._timeout
        return Out((Frame(self._out, payload, extended=self._ext),))

    def _short(self, data: bytes, what: str) -> Out:
        return self._violation(
            SdoAbortCode.INVALID_COMMAND,
            f"{self._PEER}'s frame {data.hex(' ').upper()} is too short for {what}",
        )

    def _too_long(self) -> str:
        if self._size is not None:
            return f"{self._PEER} sent more segments than the {self._size} bytes it announced"
        return (
            f"{self._PEER} sent more than the {self._limit} bytes the object takes (no size "
            "was indicated)"
        )

    def _reset(self) -> None:
        self._limit = None
        self._state = IDLE
        self.deadline = None
        self._data = b""
        self._buf = bytearray()
