"""LSS (CiA 305) frames in words, and the sessions they make as sentences.

:func:`describe` says what one frame asks or answers; :class:`LssSessions` follows a master's
requests and the slaves' answers and says what came of them: "serial 0x0000002A (vendor
0x00000360, product 0x00001234, revision 0x00010000) got node-ID 12", "fastscan found ...",
"... stored its configuration". The facts (command specifiers, layouts, error codes, the bit
timing table) are CiA 305's as the spec digest gives them.
"""

from __future__ import annotations

from dataclasses import dataclass

from cobus.proto.connection_set import LSS_MASTER_COB_ID as MASTER
from cobus.proto.lss import BIT_RATES

__all__ = ["LssSessions", "describe"]


_FIELDS = ("vendor-ID", "product code", "revision", "serial")
_ANSWERS = {  # a request's command -> the command of its answer
    0x11: 0x11,
    0x13: 0x13,
    0x17: 0x17,
    0x43: 0x44,
    0x4B: 0x4F,
    0x4C: 0x50,
    0x51: 0x4F,
    0x5A: 0x5A,
    0x5B: 0x5B,
    0x5C: 0x5C,
    0x5D: 0x5D,
    0x5E: 0x5E,
}
_ANSWER_WINDOW = 1.0  # seconds within which a slave frame answers the master's request
_STORE_ERRORS = {1: "storing is not supported", 2: "storage media access error"}


def _u32(data: bytes) -> int:
    return int.from_bytes(data[1:5].ljust(4, b"\0"), "little")


def _bit_timing(data: bytes) -> str:
    if data[1:2] != b"\x00":
        return f"table {data[1] if len(data) > 1 else 0}, index {data[2] if len(data) > 2 else 0}"
    index = data[2] if len(data) > 2 else 0
    if index == 9:
        return "automatic bit rate detection"
    kbits = BIT_RATES.get(index)
    return f"{kbits} kbit/s" if kbits else f"index {index} (reserved)"


def _error(data: bytes, texts: dict[int, str] | None = None) -> str | None:
    """None for success, else what the answer's error byte says."""
    code = data[1] if len(data) > 1 else 0
    if code == 0:
        return None
    if code == 0xFF:
        return f"manufacturer error {data[2] if len(data) > 2 else 0}"
    return (texts or {}).get(code, f"error {code}")


def describe(cob_id: int, data: bytes) -> str:
    """One LSS frame in words ("switch state global: configuration", "answer: node-ID 12")."""
    if not data:
        return "(no data)"
    cs = data[0]
    if len(data) < 8:  # CiA 305: always 8 bytes
        body = f" {data[1:].hex(' ')}" if len(data) > 1 else ""
        return f"cs {cs:02X}h{body} (a short frame: {len(data)} of 8 bytes)"
    if cob_id == MASTER:
        return _request(cs, data)
    return "answer: " + _answer(cs, data)


def _request(cs: int, data: bytes) -> str:
    if cs == 0x04:
        mode = data[1] if len(data) > 1 else 0
        which = {0: "waiting", 1: "configuration"}.get(mode, f"mode {mode}")
        return f"switch state global: {which}"
    if 0x40 <= cs <= 0x43:
        return f"switch state selective: {_FIELDS[cs - 0x40]} 0x{_u32(data):08X}"
    if cs == 0x11:
        node = data[1] if len(data) > 1 else 0
        return "configure node-ID " + ("FFh (unconfigured)" if node == 0xFF else str(node))
    if cs == 0x13:
        return f"configure bit timing: {_bit_timing(data)}"
    if cs == 0x15:
        return f"activate bit timing after {int.from_bytes(data[1:3], 'little')} ms"
    if cs == 0x17:
        return "store configuration"
    if 0x46 <= cs <= 0x4B:
        what = (
            "vendor-ID",
            "product code",
            "revision from",
            "revision to",
            "serial from",
            "serial to",
        )[cs - 0x46]
        return f"identify remote slave: {what} 0x{_u32(data):08X}"
    if cs == 0x4C:
        return "identify non-configured remote slaves"
    if cs == 0x51:
        if len(data) < 8:
            return "fastscan (short frame)"
        bit, sub, nxt = data[5], data[6], data[7]
        if bit == 0x80:
            return "fastscan: reset, every non-configured slave answer"
        field = _FIELDS[sub] if sub < 4 else f"field {sub}"
        if bit == 0 and nxt != sub:
            nxt_name = _FIELDS[nxt] if nxt < 4 else f"field {nxt}"
            return f"fastscan: confirm {field} 0x{_u32(data):08X} (next {nxt_name})"
        return f"fastscan: {field} 0x{_u32(data):08X}, bits 31..{bit}"
    if 0x5A <= cs <= 0x5D:
        return f"inquire {_FIELDS[cs - 0x5A]}"
    if cs == 0x5E:
        return "inquire node-ID"
    return f"cs {cs:02X}h {data[1:].hex(' ')}"


def _answer(cs: int, data: bytes) -> str:
    if cs == 0x44:
        return "selected (configuration state)"
    if cs == 0x11:
        problem = _error(data, {1: "node-ID out of range"})
        return "node-ID configured" if problem is None else f"node-ID refused: {problem}"
    if cs == 0x13:
        problem = _error(data, {1: "bit timing not supported"})
        return "bit timing accepted" if problem is None else f"bit timing refused: {problem}"
    if cs == 0x17:
        problem = _error(data, _STORE_ERRORS)
        return "configuration stored" if problem is None else f"not stored: {problem}"
    if cs == 0x4F:
        return "identity matches"
    if cs == 0x50:
        return "a non-configured slave is here"
    if 0x5A <= cs <= 0x5D:
        return f"{_FIELDS[cs - 0x5A]} 0x{_u32(data):08X}"
    if cs == 0x5E:
        node = data[1] if len(data) > 1 else 0
        return "node-ID " + ("FFh (unconfigured)" if node == 0xFF else str(node))
    return f"cs {cs:02X}h {data[1:].hex(' ')}"


@dataclass
class _Asked:
    command: int
    data: bytes
    time: float


class LssSessions:
    """Follows LSS requests and answers; :meth:`feed` returns the sentences they complete."""

    def __init__(self) -> None:
        self.identity: dict[int, int] = {}  # field (0..3) -> value of the slave being configured
        self._selecting: dict[int, int] = {}
        self._scanned: dict[int, int] = {}
        self._asked: _Asked | None = None

    def who(self) -> str:
        """The slave in configuration state, as far as the bus told its identity."""
        known = self.identity
        if not known:
            return "the slave in configuration state"
        parts = [f"{_FIELDS[f]} 0x{known[f]:08X}" for f in (0, 1, 2) if f in known]
        if 3 in known:
            head = f"serial 0x{known[3]:08X}"
            return f"{head} ({', '.join(parts)})" if parts else head
        return "slave " + ", ".join(parts)

    def feed(self, cob_id: int, data: bytes, now: float) -> list[str]:
        """The sentences this frame completes (mostly none)."""
        if len(data) < 8:  # a short frame: no part of a session
            return []
        cs = data[0]
        if cob_id == MASTER:
            self._request(cs, data)
            # (a request that expects no answer ends the wait for an earlier one's)
            self._asked = _Asked(cs, data, now) if cs in _ANSWERS else None
            return []
        asked = self._asked
        if asked is None or now - asked.time > _ANSWER_WINDOW or _ANSWERS[asked.command] != cs:
            return []
        if cs not in (0x4F, 0x50):  # (several slaves may answer an identify or a fastscan)
            self._asked = None
        return self._answered(asked, data)

    def _request(self, cs: int, data: bytes) -> None:
        if cs == 0x04:
            self.identity = {}  # a global switch: no single known slave any more
            self._selecting = {}
        elif 0x40 <= cs <= 0x43:
            if cs == 0x40:
                self._selecting = {}
            self._selecting[cs - 0x40] = _u32(data)
        elif cs == 0x51 and len(data) >= 8 and data[5] == 0x80:
            self._scanned = {}

    def _answered(self, asked: _Asked, data: bytes) -> list[str]:
        cs, req = asked.command, asked.data
        if cs == 0x43:
            self.identity = dict(self._selecting)
            return [f"{self.who()} selected (configuration state)"]
        if cs == 0x11:
            node = req[1] if len(req) > 1 else 0
            target = "no node-ID (unconfigured)" if node == 0xFF else f"node-ID {node}"
            problem = _error(data, {1: "out of range"})
            if problem is None:
                return [f"{self.who()} got {target}"]
            return [f"{self.who()} refused {target}: {problem}"]
        if cs == 0x13:
            problem = _error(data, {1: "not supported"})
            rate = _bit_timing(req)
            if problem is None:
                return [f"{self.who()} will use {rate} once activated"]
            return [f"{self.who()} refused {rate}: {problem}"]
        if cs == 0x17:
            problem = _error(data, _STORE_ERRORS)
            if problem is None:
                return [f"{self.who()} stored its configuration"]
            return [f"{self.who()} could not store its configuration: {problem}"]
        if 0x5A <= cs <= 0x5D:
            self.identity[cs - 0x5A] = _u32(data)
            return []
        if cs == 0x5E:
            node = data[1] if len(data) > 1 else 0
            has = "no node-ID (unconfigured)" if node == 0xFF else f"node-ID {node}"
            return [f"{self.who()} has {has}"]
        if cs == 0x51 and len(req) >= 8 and req[5] == 0 and req[6] < 4 and req[7] != req[6]:
            # A confirmation (LSSNext moves on; with LSSNext = LSSSub it is a scan of bit 0).
            self._scanned[req[6]] = _u32(req)
            if req[6] == 3 and req[7] < req[6]:  # the serial confirmed, LSSNext wrapped
                self.identity = dict(self._scanned)
                return [f"fastscan found {self.who()}, now in configuration state"]
        if cs == 0x4C:
            return ["a non-configured slave answered"]
        return []
