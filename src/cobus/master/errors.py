"""Errors of the master and of the network description, each saying what to fix."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from cobus.errors import CobusError, clip, listing
from cobus.od import Severity  # one scale for every finding: errors stop loading

__all__ = [
    "BootStepError",
    "BootTimeoutError",
    "ConfigProblem",
    "MasterError",
    "MasterValueError",
    "NetworkConfigError",
    "NodeNotFoundError",
    "Severity",
    "SignalError",
    "SignalValueError",
]


@dataclass(frozen=True, slots=True)
class ConfigProblem:
    """One problem of a network description: where it is (file, line, node, key) and why."""

    path: str
    line: int | None
    node: str | None
    key: str | None
    severity: Severity
    reason: str

    def __str__(self) -> str:
        where = self.path if self.line is None else f"{self.path}:{self.line}"
        parts = [f"{where}:"]
        if self.node is not None:
            parts.append(f"node {clip(repr(self.node), 80)}:")
        if self.key is not None:
            parts.append(f"{clip(self.key, 80)}:")
        parts.append(f"{self.severity}: {clip(self.reason)}")
        return " ".join(parts)


class NetworkConfigError(CobusError):
    """A network description that cannot be used; ``problems`` lists every error found."""

    def __init__(self, problems: Sequence[ConfigProblem]) -> None:
        self.problems = list(problems)
        errors = [p for p in self.problems if p.severity is Severity.ERROR]
        shown = errors or self.problems
        head = f"the network description has {len(errors)} error(s):"
        super().__init__(listing(head, [str(p) for p in shown]))


class MasterError(CobusError):
    """An operation of the master that cannot be done in its present state."""


class MasterValueError(MasterError, ValueError):
    """An argument the master or its diagnostics cannot work with."""


class NodeNotFoundError(MasterError, KeyError):
    """A node named by node-ID or name that the network description does not have."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""


class BootTimeoutError(MasterError, TimeoutError):
    """The network did not reach "running" in time; the message names the nodes holding it
    back and why. The boot goes on in the background."""

    def __init__(self, timeout: float, blockers: Sequence[str]) -> None:
        self.timeout = timeout
        self.blockers = list(blockers)
        lines = "\n".join(f"  {b}" for b in self.blockers)
        super().__init__(
            f"the network is not running after {timeout:g} s; held back by:\n{lines}\n"
            "(the master keeps trying: fix or connect the node, or make it optional)"
        )


class SignalError(CobusError, KeyError, ValueError):
    """A signal name that does not exist — in a master's process image, or in a trace
    plotted (:mod:`cobus.trace.plot`); the message lists close names. A ``KeyError`` (a name
    not found) and a ``ValueError`` (bad input) both."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""


class SignalValueError(CobusError, ValueError):
    """A value an output signal cannot carry (type or range of its mapped object)."""


class BootStepError(MasterError):
    """A boot step (:meth:`Master.add_boot_step`) found the node unfit to start; the text
    says why and becomes the node's problem."""
