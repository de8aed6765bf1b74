"""The EC motor's CAN dialect (seed 002), sans-I/O: "based on CANopen" but not CiA 301.

Frames (``a`` = motor address 1-15, little-endian data):

- SDO, expedited only: write ``600+a: 22 ii ii ss d0..d3`` -> ``580+a: 60 ii ii ss`` (reply
  DLC 4); read ``600+a: 40 ii ii ss [request data]`` -> ``580+a: 40 ii ii ss d0 d1 [d2 d3]``
  (reply command byte 40h, DLC 6 for 16-bit, 8 for 32-bit values). The request DLC is not
  checked: missing bytes read as 0. Refused requests get no SDO reply: the motor reports them
  with its emergency.
- Status poll: ``200+a`` with DLC 0 (a data frame) -> ``180+a [8] h_poz(I32) m_eci m_ssm``.
- Emergency: ``080+a [8] 10 00 m_sss c_sss m_ssm`` (as printed: the first word is 0010h and
  there is no error register).
- NMT: ``000: 82 a`` resets the motor; no reply.

:class:`EcDialect` is the motor's side: it parses requests, asks an :class:`EcBackend` and
answers; what is not a reply (status poll, reset, a refused request) it reports as an event
for its owner. Each departure from CiA 301 can be switched back (its ``cia_*`` options) for
the simulator's quirks.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Protocol

from cobus.errors import CobusError
from cobus.proto import NOTHING, Event, Frame, Out
from cobus.proto.connection_set import EMCY_BASE, RPDO_BASE, SDO_RX_BASE, SDO_TX_BASE, TPDO_BASE
from cobus.proto.sdo import SdoAbortCode
from cobus.sim.base import SimulationError

__all__ = [
    "EcBackend",
    "EcDialect",
    "EcRefusal",
    "FrameRejected",
    "RequestRefused",
    "ResetRequested",
    "StatusRequested",
    "emcy_frame",
    "status_frame",
]

READ = 0x40
WRITE = 0x22
WRITE_REPLY = 0x60
NMT_RESET = 0x82


class EcRefusal(CobusError):
    """A request the motor refuses; ``code`` is the CiA 301 abort code a CiA device would
    answer with (used only when the dialect sends aborts)."""

    def __init__(self, code: SdoAbortCode, reason: str, *, unused_index: bool = False) -> None:
        super().__init__(reason)
        self.code = code
        self.reason = reason
        self.unused_index = unused_index


class EcBackend(Protocol):
    """What the dialect serves. Both raise :class:`EcRefusal` to refuse."""

    def read(self, index: int, subindex: int, request: bytes) -> tuple[int, int]:
        """The value of ``index:subindex`` and its size in bytes (2 or 4); ``request`` is the
        request's data bytes 4-7 (2040h reads the address there)."""
        ...

    def write(self, index: int, subindex: int, data: bytes) -> None:
        """Write the request's data bytes 4-7 (zero-filled) to ``index:subindex``."""
        ...


@dataclass(frozen=True, slots=True)
class StatusRequested(Event):
    """A status poll arrived (RPDO1 with DLC 0): send :func:`status_frame`."""


@dataclass(frozen=True, slots=True)
class ResetRequested(Event):
    """NMT reset (82h) for this motor (or all motors) arrived."""


@dataclass(frozen=True, slots=True)
class RequestRefused(Event):
    """A request was refused (bad command, unused index, access, value): the motor reports it
    by its emergency."""

    index: int
    subindex: int
    reason: str
    unused_index: bool


@dataclass(frozen=True, slots=True)
class FrameRejected(Event):
    """A frame on the SDO identifier too short to name an object (a format error)."""

    data: bytes


def status_frame(address: int, h_poz: int, m_eci: int, m_ssm: int) -> Frame:
    """The status reply ``180+a [8] h_poz(I32) m_eci(B16) m_ssm(B16)``."""
    return Frame(TPDO_BASE + address, struct.pack("<iHH", h_poz, m_eci & 0xFFFF, m_ssm & 0xFFFF))


def emcy_frame(
    address: int, m_sss: int, c_sss: int, m_ssm: int, *, code_as_printed: bool = True
) -> Frame:
    """The emergency ``080+a [8]``: generic error code, then m_sss, c_sss, m_ssm.

    ``code_as_printed`` sends the code bytes as the document prints them (``10 00``); False
    sends CiA 301's generic error 1000h little-endian (``00 10``)."""
    code = b"\x10\x00" if code_as_printed else b"\x00\x10"
    return Frame(EMCY_BASE + address, code + struct.pack("<HHH", m_sss, c_sss, m_ssm))


class EcDialect:
    """The motor's side of the dialect for motor ``address`` (1-15).

    ``cia_replies`` answers reads as CiA 301 does (command byte 4Bh/43h by size) instead of
    40h; ``cia_length`` pads every reply to 8 bytes; ``cia_aborts`` answers a refused request
    with an SDO abort (80h) besides the event; ``cia_requests`` ignores requests shorter than
    8 bytes.
    """

    __slots__ = (
        "address",
        "backend",
        "cia_aborts",
        "cia_length",
        "cia_replies",
        "cia_requests",
        "rx_cob_id",
        "status_cob_id",
        "tx_cob_id",
    )

    def __init__(
        self,
        address: int,
        backend: EcBackend,
        *,
        cia_replies: bool = False,
        cia_length: bool = False,
        cia_aborts: bool = False,
        cia_requests: bool = False,
    ) -> None:
        if not isinstance(address, int) or not 1 <= address <= 15:
            raise SimulationError(f"EC motor address {address!r} is out of range: use 1..15")
        self.address = address
        self.backend = backend
        self.cia_replies = cia_replies
        self.cia_length = cia_length
        self.cia_aborts = cia_aborts
        self.cia_requests = cia_requests
        self.rx_cob_id = SDO_RX_BASE + address
        self.tx_cob_id = SDO_TX_BASE + address
        self.status_cob_id = RPDO_BASE + address

    @property
    def deadline(self) -> float | None:
        return None

    def on_timer(self, now: float) -> Out:
        return NOTHING

    def on_frame(self, frame: Frame, now: float) -> Out:
        if frame.extended or frame.rtr:
            return NOTHING
        if frame.cob_id == 0x000:
            data = frame.data
            if len(data) == 2 and data[0] == NMT_RESET and data[1] in (0, self.address):
                return Out((), (ResetRequested(),))
            return NOTHING
        if frame.cob_id == self.status_cob_id:
            return Out((), (StatusRequested(),)) if not frame.data else NOTHING
        if frame.cob_id == self.rx_cob_id:
            return self._request(frame.data)
        return NOTHING

    def _reply(self, data: bytes) -> Frame:
        if self.cia_length:
            data = data.ljust(8, b"\x00")
        return Frame(self.tx_cob_id, data)

    def _request(self, data: bytes) -> Out:
        if self.cia_requests and len(data) != 8:
            return NOTHING
        if len(data) < 4:
            return Out((), (FrameRejected(bytes(data)),))
        command = data[0]
        index = data[1] | data[2] << 8
        subindex = data[3]
        payload = bytes(data[4:8]).ljust(4, b"\x00")
        head = data[1:4]
        try:
            if command == READ:
                value, size = self.backend.read(index, subindex, payload)
                value_bytes = (value & (1 << size * 8) - 1).to_bytes(size, "little")
                cs = (0x43 | (4 - size) << 2) if self.cia_replies else READ
                return Out((self._reply(bytes((cs,)) + head + value_bytes),), ())
            if command & 0xE0 == 0x20 and command & 0x02:  # initiate download, expedited
                self.backend.write(index, subindex, payload)
                return Out((self._reply(bytes((WRITE_REPLY,)) + head),), ())
            raise EcRefusal(
                SdoAbortCode.INVALID_COMMAND,
                f"command 0x{command:02X}: the motor knows expedited write 22h and read 40h",
            )
        except EcRefusal as refusal:
            event = RequestRefused(index, subindex, refusal.reason, refusal.unused_index)
            if not self.cia_aborts:
                return Out((), (event,))
            abort = bytes((0x80,)) + head + struct.pack("<I", int(refusal.code))
            return Out((Frame(self.tx_cob_id, abort),), (event,))
