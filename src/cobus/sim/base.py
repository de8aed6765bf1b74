"""What every simulated device shares: power, status, fault injection, switchable quirks and
physics ticks on the network's clock (virtual time on a simulated loop).

A simulated device is built on :class:`cobus.device.Device` (or, for a device whose protocol
is not standard CANopen, directly on the runtime and the protocol machines) and adds a model of
the real device's behaviour. Subclasses set :attr:`kind` (the name used in rig files),
:attr:`QUIRKS` (each documented deviation of the real device from CiA 301, on by default and
switchable off) and :attr:`FAULTS` (what :meth:`inject` accepts).
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Mapping
from typing import Any, ClassVar

from cobus.errors import CobusError
from cobus.runtime.network import AsyncNetwork

__all__ = ["SimulatedDevice", "SimulationError", "UnknownFaultError", "UnknownQuirkError"]


class SimulationError(CobusError):
    """A simulated device was configured or driven in a way it cannot follow."""


class UnknownQuirkError(SimulationError, ValueError):
    """A quirk name that the device does not have."""


class UnknownFaultError(SimulationError, ValueError):
    """A fault name that the device cannot inject."""


class SimulatedDevice:
    """Base class of the simulated devices (see the module docstring)."""

    kind: ClassVar[str] = "device"
    #: Whether the device can be an LSS slave (a rig's ``node: unconfigured``).
    LSS: ClassVar[bool] = False
    QUIRKS: ClassVar[Mapping[str, str]] = {}
    FAULTS: ClassVar[Mapping[str, str]] = {}
    #: Per fault, its parameters and their kinds ("int", "node_id", "number", "seconds", "rate",
    #: "bool", "any"; "?" when optional): :func:`cobus.sim.faults.check_fault_parameters`
    #: checks a rig file's faults against it when the file loads.
    FAULT_PARAMS: ClassVar[Mapping[str, Mapping[str, str]]] = {
        "power_loss": {},
        "power_return": {},
    }

    def __init__(
        self,
        network: AsyncNetwork,
        node_id: int,
        *,
        quirks: Mapping[str, bool] | None = None,
        name: str | None = None,
    ) -> None:
        self.network = network
        self.node_id = node_id
        self.name = name or f"{self.kind}{node_id}"
        self.quirks: dict[str, bool] = dict.fromkeys(self.QUIRKS, True)
        for key, on in (quirks or {}).items():
            if key not in self.QUIRKS:
                known = ", ".join(sorted(self.QUIRKS)) or "none"
                raise UnknownQuirkError(
                    f"{self.kind} has no quirk {key!r}; its quirks are: {known}"
                )
            self.quirks[key] = bool(on)
        self.powered = False
        self._timers: dict[object, asyncio.TimerHandle] = {}

    # -- life cycle, overridden by subclasses (call super())
    def start(self) -> None:
        """Power the device on (boot)."""
        self.powered = True

    def close(self) -> None:
        """Take the device off the network for good."""
        self.power_off()

    def power_off(self) -> None:
        """Cut the power: the device falls silent and forgets its volatile state."""
        self.powered = False
        for handle in self._timers.values():
            handle.cancel()
        self._timers.clear()

    def power_on(self) -> None:
        """Power returns: the device boots again with its stored parameters."""
        if not self.powered:
            self.start()

    # -- what a monitor or operator panel shows
    def status(self) -> dict[str, Any]:
        """A flat summary (node, kind, power, state, and model values such as speed)."""
        return {
            "node_id": self.node_id,
            "kind": self.kind,
            "name": self.name,
            "powered": self.powered,
        }

    # -- fault injection
    def inject(self, fault: str, **params: Any) -> None:
        """Inject ``fault`` (one of :attr:`FAULTS`); subclasses handle their own faults and
        call ``super().inject`` for the common ones."""
        if fault == "power_loss":
            self.power_off()
        elif fault == "power_return":
            self.power_on()
        else:
            known = ", ".join(sorted({"power_loss", "power_return", *self.FAULTS}))
            raise UnknownFaultError(f"{self.kind} cannot inject {fault!r}; it knows: {known}")

    # -- physics
    def every(self, period: float, tick: Callable[[float], None]) -> None:
        """Call ``tick(dt)`` every ``period`` seconds of network time while powered."""
        loop = self.network.loop
        last = [loop.time()]
        key = object()

        def fire() -> None:
            now = loop.time()
            if not self.network.connected:
                # The network is closed: the model rests (no tick on a closed network) and
                # goes on when it connects again on this loop.
                last[0] = now
                if self.powered and key in self._timers and not loop.is_closed():
                    self._timers[key] = loop.call_later(period, fire)
                return
            dt, last[0] = now - last[0], now
            try:
                tick(dt)
            except Exception as exc:  # a model bug must not stop the network
                self.network.report_failure(f"{self.name} model", exc)
            if self.powered and key in self._timers:
                self._timers[key] = loop.call_later(period, fire)

        self._timers[key] = loop.call_later(period, fire)
