"""What a simulation changes in a device to model a real one, in one place: the device's
:attr:`~cobus.device.Device.simulation` (a :class:`Simulation`).

- :attr:`Simulation.sdo_response_delay` — answers that come late, as from a slow device;
- :attr:`Simulation.heartbeat_muted` — a heartbeat that falls silent, the node running on;
- :attr:`Simulation.deviations` — the ways the device departs from CiA 301
  (:class:`Deviations`, given when the device is created).

A plain device follows CiA 301 and answers at once: nothing here is on by default. The
heartbeat producer reads its setting through a gate of :mod:`cobus.device._gates`; the SDO
server channels go behind theirs once a response delay is set (before, a request skips the
gate's calls). A change applies at once and holds through every rebuild of the
communication (resets, node-ID changes, new COB-IDs).
"""

from __future__ import annotations

from collections.abc import Callable, Collection
from dataclasses import dataclass, field

from cobus.device.errors import DeviceConfigError

__all__ = ["CobIdRule", "Deviations", "Simulation"]


#: ``rule(kind, number, value) -> value``: the CiA 301 form of a COB-ID parameter as the device
#: uses it (see :attr:`Deviations.cob_id_rule`).
CobIdRule = Callable[[str, int, int], int]


@dataclass(frozen=True)
class Deviations:
    """How a device departs from CiA 301, for models of real devices that do (all off by
    default; a plain :class:`Device` follows CiA 301).

    - ``send_bootup`` False: no boot-up message (the device still enters pre-operational).
    - ``error_control`` False: no heartbeat (1017h is kept but not produced) and no answer
      to node guarding (so no life guarding either).
    - ``tpdos_outside_operational``: numbers of TPDOs that transmit in pre-operational too
      (event timer, change, SYNC and RTR as in operational); stopped silences them.
    - ``store_on_subindex_0``: a write of "save" to 1010h sub 0 stores all parameters as
      sub 1 does (reading sub 0 still gives the highest sub-index).
    - ``padded_writes``: a download of up to 4 bytes to a shorter entry is accepted when the
      extra bytes are zero (expedited writes of 4 bytes to 8/16-bit objects).
    - ``generic_error_bit`` False: the error register (1001h and in emergencies) holds only
      the bits of the active errors, without the generic bit 0 CiA 301 sets with any error.
    - ``comm_error_emcy`` False: the device's own communication errors (RPDO length and
      timeout, SYNC, heartbeat, life guarding) are reported as events only, with no
      emergency, error register bit or 1003h entry: the application reports them its way.
      1029h still applies.
    - ``serve_sdo`` False: no SDO server channel; the owner serves :attr:`Device.sdo_backend`
      on channels of its own (for COB-ID rules or per-channel contexts of its own).
    - ``cob_id_rule``: ``rule(kind, number, value)`` turns the stored value of a COB-ID
      parameter into the CiA 301 form the device uses; ``kind`` is ``"emcy"`` (number 1),
      ``"tpdo"``, ``"rpdo"`` (PDO number) or ``"sdo_rx"``/``"sdo_tx"`` (SDO server channel
      number, 2 and up; channel 1 is fixed). The stored value is what a master reads back.
      E.g. a bare function code that means "plus the node-ID", or bit 31 read the other way.
    - ``pdo_params_while_valid``: the COB-ID, inhibit time and SYNC start value of a PDO
      may be written while the PDO is valid; the PDO is rebuilt with them.
    - ``direct_pdo_mapping``: mapping entries may be written at any time (the PDO is
      rebuilt at once; a zero entry is unused; a bit length 0 is filled in from the object);
      the mapping's sub 0 is then a constant count of entries, not written by a master.
    - ``partial_rpdos``: an RPDO shorter than its mapping writes the objects it covers
      completely and leaves the others; neither a shorter nor a longer RPDO is an error.
    - ``transmission_types``: the PDO transmission types the device accepts (others are
      refused with 06090030); None accepts all that CiA 301 allows.
    - ``emcy_in_stopped``: emergencies are sent in stopped too (CiA 301: only recorded).
    - ``reset_communication_keeps_values``: reset communication applies the communication
      parameters as they are (a master's changes take effect) instead of reloading the
      stored ones; reset node still reloads everything.
    """

    send_bootup: bool = True
    error_control: bool = True
    tpdos_outside_operational: Collection[int] = field(default_factory=frozenset)
    store_on_subindex_0: bool = False
    padded_writes: bool = False
    generic_error_bit: bool = True
    comm_error_emcy: bool = True
    serve_sdo: bool = True
    cob_id_rule: CobIdRule | None = None
    pdo_params_while_valid: bool = False
    direct_pdo_mapping: bool = False
    partial_rpdos: bool = False
    transmission_types: Collection[int] | None = None
    emcy_in_stopped: bool = False
    reset_communication_keeps_values: bool = False

    def __post_init__(self) -> None:
        early = frozenset(self.tpdos_outside_operational)
        bad = [n for n in early if not isinstance(n, int) or not 1 <= n <= 512]
        if bad:
            raise DeviceConfigError(
                f"tpdos_outside_operational names {bad!r}: TPDO numbers are 1..512"
            )
        object.__setattr__(self, "tpdos_outside_operational", early)
        if self.transmission_types is not None:
            types = frozenset(self.transmission_types)
            wrong = [t for t in types if not isinstance(t, int) or not 0 <= t <= 255]
            if wrong:
                raise DeviceConfigError(
                    f"transmission_types names {wrong!r}: transmission types are 0..255"
                )
            object.__setattr__(self, "transmission_types", types)


_CIA = Deviations()


class Simulation:
    """The simulation settings of one device (``device.simulation``)."""

    __slots__ = ("_deviations", "_heartbeat_muted", "_on_delay", "_sdo_delay")

    def __init__(
        self,
        deviations: Deviations | None = None,
        *,
        on_delay: Callable[[], None] | None = None,
    ) -> None:
        """``on_delay`` is called after each change of :attr:`sdo_response_delay` (the
        device's SDO servers put their channels behind a gate only once a delay is set)."""
        if deviations is not None and not isinstance(deviations, Deviations):
            raise DeviceConfigError(f"deviations {deviations!r} is not a cobus.device.Deviations")
        self._deviations = deviations or _CIA
        self._sdo_delay = 0.0
        self._heartbeat_muted = False
        self._on_delay = on_delay

    def __repr__(self) -> str:
        return (
            f"Simulation(sdo_response_delay={self._sdo_delay!r}, "
            f"heartbeat_muted={self._heartbeat_muted!r}, deviations={self._deviations!r})"
        )

    @property
    def deviations(self) -> Deviations:
        """How the device departs from CiA 301 (given when it was created; fixed)."""
        return self._deviations

    @property
    def sdo_response_delay(self) -> float:
        """Seconds each SDO request waits before the device takes it up (0, the default: at
        once), on the network's clock: every answer comes that much late, as from a slow
        device, and a client whose timeout is shorter gives up.

        The server channels take the requests up in the order they arrived (a shorter delay
        set later does not overtake those still waiting); their transfer timeout counts from
        when they take a request up. A change applies to the requests that arrive after it
        and holds through resets and node-ID changes; requests still waiting when the channels
        are rebuilt (reset, NMT stopped, new COB-IDs) are dropped with them. It acts on the
        channels the device serves itself, not on those of an owner that serves
        :attr:`Device.sdo_backend <cobus.device.Device.sdo_backend>`
        (``Deviations(serve_sdo=False)``).
        """
        return self._sdo_delay

    @sdo_response_delay.setter
    def sdo_response_delay(self, seconds: float) -> None:
        # On the network's loop only, like every change of a device (the blocking twin runs
        # it there): a delay puts the SDO channels behind their gates.
        if (
            not isinstance(seconds, int | float)
            or isinstance(seconds, bool)
            or not 0 <= seconds < float("inf")
        ):
            raise DeviceConfigError(
                f"SDO response delay {seconds!r} must be a number of seconds >= 0 (0: none)"
            )
        self._sdo_delay = float(seconds)
        if self._on_delay is not None:
            self._on_delay()

    @property
    def heartbeat_muted(self) -> bool:
        """Whether the heartbeat producer is silenced (False by default).

        While muted the producer keeps its period (1017h, which keeps its value and can be
        written) and sends nothing; un-muted, it sends again on that period, without a new
        start. The node runs on otherwise: boot-up messages, node guarding answers, SDO and
        PDOs are not affected. It holds through resets and node-ID changes.
        """
        return self._heartbeat_muted

    @heartbeat_muted.setter
    def heartbeat_muted(self, muted: bool) -> None:
        if not isinstance(muted, bool):
            raise DeviceConfigError(f"heartbeat_muted takes True or False, not {muted!r}")
        self._heartbeat_muted = muted
