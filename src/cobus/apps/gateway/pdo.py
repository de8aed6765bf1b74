"""The gateway's own PDOs, as Lely's gateway has them (CiA 309-3 PDO access).

A client configures them per net - ``set rpdo N COB-ID TRANS COUNT [INDEX SUB] TYPE ...``,
``set tpdo N ...`` (``set tpdox`` adds the SYNC start value; an inhibit time or event
timer other than 0 is refused: a TPDO goes when written) -
then reads what an RPDO last brought (``r p N`` → ``[seq] NET pdo COUNT 0xV ...``) and sends
values in a TPDO (``w p N COUNT V ...``). Subscribed clients hear every RPDO as it comes in
(``NET pdo N COUNT 0xV ...``). TRANS is ``event``, ``rtr`` or ``syncN`` (N 0..240): an RPDO
with ``sync`` is taken at the next SYNC after it came, a TPDO with ``sync0`` goes out at the
next SYNC after a write, with ``syncN`` every N-th SYNC once written, with ``rtr`` when a
remote frame asks for it, with ``event`` at once. Values are the mapped fields as unsigned
numbers (two's complement for signed types), fields packed least significant bit first.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from cobus.apps.gateway.grammar import TYPES, GatewayError, parse_number
from cobus.proto import Frame
from cobus.proto.connection_set import SYNC_COB_ID

if TYPE_CHECKING:
    from cobus.runtime import AsyncNetwork, Subscription

__all__ = ["PdoConfig", "PdoTable", "parse_pdo_config"]

#: The most values one PDO maps (and a ``w p`` gives).
MAX_VALUES = 64
_EVENT, _RTR = 0xFF, 0xFD


@dataclass
class PdoConfig:
    """One PDO of the gateway: its number, COB-ID (bit 31 set: not valid, bit 29: a 29-bit
    identifier), transmission type and the bit length of each mapped field."""

    number: int
    cob_id: int
    transmission: int
    lengths: list[int]
    inhibit_ms: int = 0
    event_ms: int = 0
    sync_start: int = 0

    @property
    def valid(self) -> bool:
        """Whether the PDO is in use (bit 31 of its COB-ID clear)."""
        return not self.cob_id & 0x8000_0000

    @property
    def can_id(self) -> int:
        """The frame identifier."""
        return self.cob_id & (0x1FFF_FFFF if self.cob_id & 0x2000_0000 else 0x7FF)

    @property
    def extended(self) -> bool:
        """Whether the frame has a 29-bit identifier."""
        return bool(self.cob_id & 0x2000_0000)


def _transmission(word: str) -> tuple[int, int | None]:
    """The transmission type of ``word`` and the number written onto ``event`` (Lely's
    ``set tpdox``: ``event<inhibit ms>``), None: none."""
    low = word.lower()
    if low == "event" or (low.startswith("event") and low[5:].isdigit()):
        return _EVENT, int(low[5:]) if low[5:] else None
    if low == "rtr":
        return _RTR, None
    if low.startswith("sync") and low[4:].isdigit() and int(low[4:]) <= 240:
        return int(low[4:]), None
    raise GatewayError(101, f"transmission {word!r}: event, rtr or sync0..sync240")


def parse_pdo_config(words: list[str], *, extended: bool = False) -> PdoConfig:
    """``N COB-ID TRANS [INHIBIT EVENT | SYNC-START] COUNT [INDEX SUB] TYPE ...`` (the
    middle values for ``set tpdox`` only) as a :class:`PdoConfig`."""
    it = iter(words)

    def take(what: str) -> str:
        word = next(it, None)
        if word is None:
            raise GatewayError(101, f"the PDO's {what} is missing")
        return word

    number = parse_number(take("number"), "PDO number")
    if not 1 <= number <= 512:
        raise GatewayError(101, f"PDO {number}: numbers are 1..512")
    cob_id = parse_number(take("COB-ID"), "COB-ID")
    if not 0 <= cob_id <= 0xFFFF_FFFF:
        raise GatewayError(101, f"COB-ID {cob_id:#x} does not fit 32 bits")
    transmission, attached = _transmission(take("transmission type"))
    if attached is not None and not extended:
        raise GatewayError(101, "event<inhibit ms> is set tpdox's: set tpdo takes event")
    config = PdoConfig(number, cob_id, transmission, [])
    if not cob_id & 0x2000_0000 and cob_id & 0x1FFF_F800:
        raise GatewayError(101, f"COB-ID {cob_id:#x}: an 11-bit identifier is 0..0x7FF")
    if extended and transmission >= 0xFE:  # (Lely's event<ms>, or the ms as a word)
        config.inhibit_ms = (
            attached if attached is not None else parse_number(take("inhibit time"), "ms")
        )
    if extended and transmission >= 0xFD:
        config.event_ms = parse_number(take("event timer"), "event timer")
    if config.inhibit_ms or config.event_ms:
        raise GatewayError(
            100,
            "cobus's gateway sends a TPDO when it is written (w p): no inhibit time or "
            "event timer (give 0)",
        )
    elif extended and transmission <= 240:
        config.sync_start = parse_number(take("SYNC start value"), "SYNC start value")
    count = parse_number(take("number of values"), "number of values")
    if not 0 <= count <= MAX_VALUES:
        raise GatewayError(101, f"{count} values: a PDO maps 0..{MAX_VALUES}")
    for _ in range(count):
        word = take("mapped type")
        if word.lower() not in TYPES:  # (an index and sub-index first: informative only)
            parse_number(word, "index or type")
            parse_number(take("sub-index"), "sub-index")
            word = take("mapped type")
        data_type = TYPES.get(word.lower())
        size = None if data_type is None else data_type.size
        if size is None or word.lower() == "hex":
            raise GatewayError(101, f"type {word}: only types of a fixed size map to PDOs")
        config.lengths.append(8 * size)
    if sum(config.lengths) > 64:
        raise GatewayError(401, f"{sum(config.lengths)} bits mapped: a PDO carries 64")
    extra = next(it, None)
    if extra is not None:
        raise GatewayError(101, f"{extra!r} after the PDO's {count} mapped types")
    return config


def unpack(lengths: list[int], data: bytes) -> list[int] | None:
    """The fields of ``data`` (None: too short for them)."""
    total = sum(lengths)
    if len(data) * 8 < total:
        return None
    bits = int.from_bytes(data, "little")
    values = []
    for length in lengths:
        values.append(bits & ((1 << length) - 1))
        bits >>= length
    return values


def pack(lengths: list[int], values: list[int]) -> bytes:
    """The frame data of ``values`` (each checked against its field)."""
    bits = 0
    offset = 0
    for length, value in zip(lengths, values, strict=True):
        if not 0 <= value < (1 << length):
            raise GatewayError(101, f"{value:#x} does not fit a field of {length} bits")
        bits |= value << offset
        offset += length
    return bits.to_bytes((offset + 7) // 8, "little")


@dataclass
class _Rpdo:
    config: PdoConfig
    values: list[int]
    pending: list[int] | None = None  # (a synchronous RPDO's values until the next SYNC)
    subscription: Subscription | None = None


@dataclass
class _Tpdo:
    config: PdoConfig
    values: list[int] | None = None
    due: bool = False  # (sync0: to go at the next SYNC)
    syncs: int = 0
    started: bool = False  # (syncN with a SYNC start value: the counter has reached it)
    subscription: Subscription | None = None


@dataclass
class PdoTable:
    """The gateway's RPDOs and TPDOs on one net; ``tell(line)`` hands an RPDO indication
    to the subscribed clients."""

    net: int
    network: AsyncNetwork
    tell: Callable[[str], None]
    rpdos: dict[int, _Rpdo] = field(default_factory=dict)
    tpdos: dict[int, _Tpdo] = field(default_factory=dict)
    _sync: Subscription | None = None

    def configure_rpdo(self, config: PdoConfig) -> None:
        """Set RPDO ``config.number`` (again): its values start at 0."""
        clash = [
            r.config.number
            for r in self.rpdos.values()
            if r.config.valid
            and config.valid
            and r.config.number != config.number
            and (r.config.can_id, r.config.extended) == (config.can_id, config.extended)
        ]
        if clash:
            raise GatewayError(400, f"RPDO {clash[0]} of net {self.net} has that COB-ID")
        self._drop(self.rpdos.pop(config.number, None))
        rpdo = _Rpdo(config, [0] * len(config.lengths))
        if config.valid:
            rpdo.subscription = self.network.subscribe(
                config.can_id,
                lambda frame, now: self._received(rpdo, frame),
                extended=config.extended,
            )
        self.rpdos[config.number] = rpdo
        self._watch_sync()

    def configure_tpdo(self, config: PdoConfig) -> None:
        """Set TPDO ``config.number`` (again): nothing is sent until values are written."""
        self._drop(self.tpdos.pop(config.number, None))
        tpdo = _Tpdo(config)
        if config.valid and config.transmission == _RTR:
            tpdo.subscription = self.network.subscribe(
                config.can_id, lambda frame, now: self._asked(tpdo, frame), extended=config.extended
            )
        self.tpdos[config.number] = tpdo
        self._watch_sync()

    def read(self, number: int) -> list[int]:
        """The values RPDO ``number`` last brought (0 before the first)."""
        rpdo = self.rpdos.get(number)
        if rpdo is None:
            raise GatewayError(102, f"RPDO {number} of net {self.net} is not set: set rpdo ...")
        return list(rpdo.values)

    def write(self, number: int, values: list[int]) -> None:
        """Send ``values`` in TPDO ``number`` (now, or when its transmission type says)."""
        tpdo = self.tpdos.get(number)
        if tpdo is None:
            raise GatewayError(102, f"TPDO {number} of net {self.net} is not set: set tpdo ...")
        config = tpdo.config
        if len(values) != len(config.lengths):
            raise GatewayError(
                101, f"TPDO {number} maps {len(config.lengths)} values, not {len(values)}"
            )
        if not config.valid:
            raise GatewayError(102, f"TPDO {number}: its COB-ID {config.cob_id:#x} is not valid")
        pack(config.lengths, values)  # (each value checked now)
        tpdo.values = list(values)
        if config.transmission >= 0xFE:
            self._send(tpdo)
        elif config.transmission == 0:
            tpdo.due = True

    def close(self) -> None:
        """Forget every PDO (the gateway stops)."""
        for rpdo in self.rpdos.values():
            self._drop(rpdo)
        for tpdo in self.tpdos.values():
            self._drop(tpdo)
        self.rpdos.clear()
        self.tpdos.clear()
        if self._sync is not None:
            self._sync.cancel()
            self._sync = None

    # ------------------------------------------------------------------ the bus

    @staticmethod
    def _drop(pdo: _Rpdo | _Tpdo | None) -> None:
        if pdo is not None and pdo.subscription is not None:
            pdo.subscription.cancel()
            pdo.subscription = None

    def _watch_sync(self) -> None:
        configs = [r.config for r in self.rpdos.values()]
        configs += [t.config for t in self.tpdos.values()]
        synchronous = any(c.valid and c.transmission <= 240 for c in configs)
        if synchronous and self._sync is None:
            self._sync = self.network.subscribe(SYNC_COB_ID, self._on_sync)
        elif not synchronous and self._sync is not None:
            self._sync.cancel()
            self._sync = None

    def _received(self, rpdo: _Rpdo, frame: Frame) -> None:
        if frame.rtr:
            return
        values = unpack(rpdo.config.lengths, frame.data)
        if values is None:
            return  # (too short for its mapping: not taken, as CiA 301 has it)
        if rpdo.config.transmission <= 240:
            rpdo.pending = values
        else:
            self._take(rpdo, values)

    def _take(self, rpdo: _Rpdo, values: list[int]) -> None:
        rpdo.values = values
        shown = " ".join(f"0x{v:x}" for v in values)
        self.tell(f"{self.net} pdo {rpdo.config.number} {len(values)}{' ' if shown else ''}{shown}")

    def _asked(self, tpdo: _Tpdo, frame: Frame) -> None:
        if frame.rtr and tpdo.values is not None:
            self._send(tpdo)

    def _on_sync(self, frame: Frame, now: float) -> None:
        if frame.rtr:
            return
        for rpdo in self.rpdos.values():
            if rpdo.pending is not None:
                values, rpdo.pending = rpdo.pending, None
                self._take(rpdo, values)
        for tpdo in self.tpdos.values():
            transmission = tpdo.config.transmission
            if tpdo.values is None or not tpdo.config.valid or transmission > 240:
                continue
            if transmission == 0:
                if tpdo.due:
                    tpdo.due = False
                    self._send(tpdo)
                continue
            start = tpdo.config.sync_start
            if start and not tpdo.started:  # (CiA 301: the first at the SYNC counting start)
                if len(frame.data) == 1 and frame.data[0] == start:
                    tpdo.started = True
                    tpdo.syncs = 0
                    self._send(tpdo)
                continue
            tpdo.syncs += 1
            if tpdo.syncs >= transmission:
                tpdo.syncs = 0
                self._send(tpdo)

    def _send(self, tpdo: _Tpdo) -> None:
        assert tpdo.values is not None
        config = tpdo.config
        data = pack(config.lengths, tpdo.values)
        self.network.send(Frame(config.can_id, data, extended=config.extended))
