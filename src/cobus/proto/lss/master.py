"""The LSS master's services (CiA 305), one request at a time.

Each service method returns the frames to send and, when the service has an answer, arms a
deadline: the answer is reported by :meth:`LssMaster.on_frame` (:class:`LssConfirmed`,
:class:`LssInquired`, :class:`LssSelected`, :class:`LssIdentified`), its absence by
:meth:`LssMaster.on_timer` (:class:`LssNoAnswer`). Switch state global and activate bit
timing have no answer. An answer nobody waits for is reported as :class:`LssStrayAnswer`.
Fastscan is :class:`~cobus.proto.lss.fastscan.Fastscan`.
"""

from __future__ import annotations

from dataclasses import dataclass

from cobus.proto._base import NOTHING, Event, Out
from cobus.proto.frame import Frame
from cobus.proto.lss import _wire as w
from cobus.proto.lss._wire import (
    AUTO_BIT_RATE,
    BIT_RATES,
    FIELDS,
    LssError,
    LssIdentity,
)
from cobus.proto.lss.slave import LssState

__all__ = [
    "LssConfirmed",
    "LssIdentified",
    "LssInquired",
    "LssMaster",
    "LssNoAnswer",
    "LssSelected",
    "LssStrayAnswer",
    "error_text",
]

_ERRORS = {
    "configure node-ID": {1: "node-ID out of range"},
    "configure bit timing": {1: "bit timing not supported"},
    "store configuration": {1: "storing is not supported", 2: "storage media access error"},
}


def error_text(service: str, error: int, spec: int = 0) -> str:
    """What an answer's error byte means (``""`` for success)."""
    if error == 0:
        return ""
    if error == 0xFF:
        return f"manufacturer-specific error {spec} (FFh)"
    return _ERRORS.get(service, {}).get(error, f"error {error} (reserved)")


@dataclass(frozen=True, slots=True)
class LssConfirmed(Event):
    """A configuration service was answered: ``error`` 0 is success, else ``text`` says why."""

    service: str
    error: int
    spec: int
    text: str

    @property
    def ok(self) -> bool:
        """Whether the slave did it (error 0)."""
        return self.error == 0


@dataclass(frozen=True, slots=True)
class LssInquired(Event):
    """An inquiry's answer: ``what`` (vendor, product, revision, serial, node_id) is ``value``."""

    what: str
    value: int


@dataclass(frozen=True, slots=True)
class LssSelected(Event):
    """The slave with ``identity`` answered switch state selective: it is in configuration."""

    identity: LssIdentity


@dataclass(frozen=True, slots=True)
class LssIdentified(Event):
    """At least one slave answered an identify request (``service``: remote or unconfigured)."""

    service: str


@dataclass(frozen=True, slots=True)
class LssNoAnswer(Event):
    """No slave answered ``service`` within ``timeout`` seconds."""

    service: str
    timeout: float


@dataclass(frozen=True, slots=True)
class LssStrayAnswer(Event):
    """An LSS answer no request waits for (late, duplicated, or another master's)."""

    data: bytes


class LssMaster:
    """Requests of an LSS master and the answers to them (sans-I/O)."""

    def __init__(self, timeout: float = 0.1) -> None:
        self.timeout = _seconds(timeout)
        self._service: str | None = None
        self._expects: int | None = None
        self._deadline: float | None = None
        self._asked: LssIdentity | None = None
        self._what = ""

    @property
    def busy(self) -> bool:
        """Whether a request waits for its answer."""
        return self._service is not None

    @property
    def deadline(self) -> float | None:
        return self._deadline

    # ---------------------------------------------------------------- services

    def switch_global(self, state: LssState | int) -> Out:
        """Every slave to waiting (0) or configuration (1); there is no answer."""
        if state not in (LssState.WAITING, LssState.CONFIGURATION):
            raise LssError(f"LSS state {state!r}: give 0 (waiting) or 1 (configuration)")
        return Out((w.request(w.SWITCH_GLOBAL, bytes((int(state),))),))

    def switch_selective(self, identity: LssIdentity, now: float) -> Out:
        """The one slave with ``identity`` to configuration (answer: :class:`LssSelected`)."""
        if not isinstance(identity, LssIdentity):
            raise LssError(f"identity {identity!r}: give an LssIdentity")
        frames = tuple(
            w.request(cs, w.le32(v))
            for cs, v in zip(w.SWITCH_SELECTIVE, identity.fields, strict=True)
        )
        out = self._ask("switch state selective", w.SELECTED, now, frames)
        self._asked = identity
        return out

    def configure_node_id(self, node_id: int, now: float) -> Out:
        """The slave in configuration takes ``node_id`` (1..127, or FFh: none)."""
        w.check_node_id(node_id)
        frame = w.request(w.CONFIGURE_NODE_ID, bytes((node_id,)))
        return self._ask("configure node-ID", w.CONFIGURE_NODE_ID, now, (frame,))

    def configure_bit_timing(self, index: int, now: float) -> Out:
        """The slaves in configuration take bit timing ``index`` of table 0 (see
        :func:`~cobus.proto.lss.bit_timing_index`)."""
        if (
            not isinstance(index, int)
            or isinstance(index, bool)
            or (index not in BIT_RATES and index != AUTO_BIT_RATE)
        ):
            raise LssError(f"bit timing index {index!r}: give 0..4, 6..8 (or 9: automatic)")
        frame = w.request(w.CONFIGURE_BIT_TIMING, bytes((0, index)))
        return self._ask("configure bit timing", w.CONFIGURE_BIT_TIMING, now, (frame,))

    def activate_bit_timing(self, delay: float) -> Out:
        """The slaves in configuration switch after ``delay`` seconds (to the ms, up to
        65.535 s); there is no answer."""
        ms = round(_seconds(delay) * 1000)
        if ms > 0xFFFF:
            raise LssError(f"switch delay {delay} s: at most 65.535 s")
        return Out((w.request(w.ACTIVATE_BIT_TIMING, ms.to_bytes(2, "little")),))

    def store(self, now: float) -> Out:
        """The slave in configuration stores its pending node-ID and bit timing."""
        return self._ask("store configuration", w.STORE, now, (w.request(w.STORE),))

    def inquire(self, what: str, now: float) -> Out:
        """Ask the slave in configuration for ``what``: vendor, product, revision, serial or
        node_id (answer: :class:`LssInquired`)."""
        if what == "node_id":
            cs = w.INQUIRE_NODE_ID
        elif what in FIELDS:
            cs = w.INQUIRE[FIELDS.index(what)]
        else:
            raise LssError(f"inquire {what!r}: give one of {', '.join(FIELDS)}, node_id")
        out = self._ask(f"inquire {what}", cs, now, (w.request(cs),))
        self._what = what
        return out

    def identify_remote(
        self,
        vendor: int,
        product: int,
        revisions: tuple[int, int],
        serials: tuple[int, int],
        now: float,
    ) -> Out:
        """Is there a slave with this vendor and product whose revision and serial lie in the
        ranges (bounds included)?"""
        if len(revisions) != 2 or len(serials) != 2:
            raise LssError("identify remote slave: give revisions and serials as (low, high)")
        values = (vendor, product, *revisions, *serials)
        names = "vendor, product, lowest revision, highest revision, lowest serial, highest serial"
        for name, value in zip(names.split(", "), values, strict=True):
            w.u32(value, name)
        if revisions[0] > revisions[1] or serials[0] > serials[1]:
            raise LssError("identify remote slave: a range's low bound is above its high one")
        frames = tuple(
            w.request(cs, w.le32(v)) for cs, v in zip(w.IDENTIFY_REMOTE, values, strict=True)
        )
        return self._ask("identify remote slave", w.IDENTIFIED, now, frames)

    def identify_unconfigured(self, now: float) -> Out:
        """Is there a slave without a node-ID?"""
        frame = w.request(w.IDENTIFY_UNCONFIGURED)
        return self._ask("identify non-configured slave", w.UNCONFIGURED_IDENTIFIED, now, (frame,))

    # ---------------------------------------------------------------- the machine

    def on_frame(self, frame: Frame, now: float) -> Out:
        data = frame.data
        if frame.cob_id != w.SLAVE or frame.rtr or len(data) != 8:
            return NOTHING
        service = self._service
        if service is None or data[0] != self._expects:
            return Out((), (LssStrayAnswer(bytes(data)),))
        self._done()
        cs = data[0]
        event: Event
        if cs in (w.CONFIGURE_NODE_ID, w.CONFIGURE_BIT_TIMING, w.STORE):
            event = LssConfirmed(service, data[1], data[2], error_text(service, data[1], data[2]))
        elif cs in w.INQUIRE:
            event = LssInquired(self._what, w.read_u32(data))
        elif cs == w.INQUIRE_NODE_ID:
            event = LssInquired("node_id", data[1])
        elif cs == w.SELECTED:
            assert self._asked is not None
            event = LssSelected(self._asked)
        elif cs == w.IDENTIFIED:
            event = LssIdentified("remote")
        else:
            event = LssIdentified("unconfigured")
        return Out((), (event,))

    def on_timer(self, now: float) -> Out:
        if self._deadline is None or now < self._deadline or self._service is None:
            return NOTHING
        service = self._service
        self._done()
        return Out((), (LssNoAnswer(service, self.timeout),))

    def cancel(self) -> None:
        """Forget the request under way (its answer, if it comes, is a stray one)."""
        self._done()

    def _ask(self, service: str, expects: int, now: float, frames: tuple[Frame, ...]) -> Out:
        if self._service is not None:
            raise LssError(f"{service}: the LSS request {self._service!r} is under way")
        self._service, self._expects, self._deadline = service, expects, now + self.timeout
        return Out(frames)

    def _done(self) -> None:
        self._service = self._expects = self._deadline = None


def _seconds(value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not 0 <= value < 3600:
        raise LssError(f"{value!r}: give seconds (0 or more)")
    return float(value)
