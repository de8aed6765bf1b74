"""A CAN frame as a plain value.

Frames are what protocol machines take in and give out. Conversion to and from python-can
messages happens in the runtime's bus adapter only.
"""

from __future__ import annotations

from cobus.errors import CobusError

__all__ = ["Frame", "FrameError", "frame_bits"]

_MAX_STD = 0x7FF
_MAX_EXT = 0x1FFFFFFF


class FrameError(CobusError, ValueError):
    """A frame that cannot exist on a CAN bus (identifier or length out of range)."""


class Frame:
    """One classic CAN frame: identifier, data bytes, remote flag, identifier format.

    ``dlc`` is the length of ``data`` for a data frame; for a remote (RTR) frame, which carries
    no data, it is the requested length.
    """

    __slots__ = ("cob_id", "data", "dlc", "extended", "rtr")

    cob_id: int
    data: bytes
    rtr: bool
    extended: bool
    dlc: int

    def __init__(
        self,
        cob_id: int,
        data: bytes | bytearray = b"",
        *,
        rtr: bool = False,
        extended: bool = False,
        dlc: int | None = None,
    ) -> None:
        if (  # the common case, every frame a machine sends: a data frame of bytes, checked
            type(data) is bytes
            and len(data) <= 8
            and not rtr
            and dlc is None
            and 0 <= cob_id <= (_MAX_EXT if extended else _MAX_STD)
        ):
            self.cob_id = cob_id
            self.data = data
            self.rtr = rtr
            self.extended = extended
            self.dlc = len(data)
            return
        limit = _MAX_EXT if extended else _MAX_STD
        if not 0 <= cob_id <= limit:
            kind = "a 29-bit" if extended else "an 11-bit"
            raise FrameError(f"CAN identifier 0x{cob_id:X} does not fit {kind} identifier")
        if len(data) > 8:
            raise FrameError(
                f"CAN frame 0x{cob_id:X} has {len(data)} data bytes; a classic frame carries 0 to 8"
            )
        if rtr:
            if data:
                raise FrameError(f"remote frame 0x{cob_id:X} cannot carry data")
            if dlc is None:
                dlc = 0
            elif not 0 <= dlc <= 8:
                raise FrameError(f"remote frame 0x{cob_id:X}: DLC {dlc} is outside 0..8")
        else:
            if dlc is not None and dlc != len(data):
                raise FrameError(
                    f"CAN frame 0x{cob_id:X}: DLC {dlc} differs from its {len(data)} data bytes"
                )
            dlc = len(data)
        self.cob_id = cob_id
        self.data = bytes(data)
        self.rtr = rtr
        self.extended = extended
        self.dlc = dlc

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Frame):
            return NotImplemented
        return (
            self.cob_id == other.cob_id
            and self.data == other.data
            and self.rtr == other.rtr
            and self.extended == other.extended
            and self.dlc == other.dlc
        )

    def __hash__(self) -> int:
        return hash((self.cob_id, self.data, self.rtr, self.extended, self.dlc))

    def __repr__(self) -> str:
        ident = f"{self.cob_id:08X}" if self.extended else f"{self.cob_id:03X}"
        if self.rtr:
            return f"Frame({ident} [{self.dlc}] RTR)"
        return f"Frame({ident} [{self.dlc}] {self.data.hex(' ').upper()})".replace(" ]", "]")

    @classmethod
    def parse(cls, text: str) -> Frame:
        """Read the notation used in traces and the golden vectors: ``"605 [8] 40 00 10 00"``.

        The ``[n]`` DLC is optional for data frames; a trailing ``RTR`` makes a remote frame.
        An identifier of more than three hex digits is taken as a 29-bit identifier.
        """
        parts = text.split()
        if not parts:
            raise FrameError("empty frame text")
        ident = parts[0]
        rest = parts[1:]
        dlc: int | None = None
        if rest and rest[0].startswith("["):
            try:
                dlc = int(rest[0].strip("[]"))
            except ValueError:
                raise FrameError(f"bad DLC {rest[0]!r} in frame text {text!r}") from None
            rest = rest[1:]
        rtr = bool(rest) and rest[-1].upper() == "RTR"
        if rtr:
            rest = rest[:-1]
        try:
            cob_id = int(ident, 16)
            data = bytes(int(b, 16) for b in rest)
        except ValueError:
            raise FrameError(f"frame text {text!r} is not hex") from None
        return cls(cob_id, data, rtr=rtr, extended=len(ident) > 3, dlc=dlc)


# Bits of a classic frame without data and stuffing: SOF 1, identifier 11 (29 + SRR + IDE for
# extended), RTR 1, IDE/r1 + r0 2, DLC 4, CRC 15, CRC delimiter 1, ACK 2, EOF 7, IFS 3.
_STD_OVERHEAD = 47
_EXT_OVERHEAD = 67
# The part where stuffing applies: SOF through CRC.
_STD_STUFFED = 34
_EXT_STUFFED = 54


def frame_bits(frame: Frame) -> int:
    """Bits ``frame`` takes on the bus (start of frame to the end of the interframe space),
    with the worst-case number of stuff bits ISO 11898 allows: what a bus load counts."""
    data_bits = 0 if frame.rtr else 8 * len(frame.data)
    if frame.extended:
        stuffed = _EXT_STUFFED + data_bits
        return _EXT_OVERHEAD + data_bits + (stuffed - 1) // 4
    stuffed = _STD_STUFFED + data_bits
    return _STD_OVERHEAD + data_bits + (stuffed - 1) // 4
