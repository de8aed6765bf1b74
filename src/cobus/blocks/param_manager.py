"""The parameter manager: a node's parameters brought to a :class:`ParameterSet`.

The sequence is the thesis's PLC block: **read** every parameter → **compare** with the
set-points → **write** the ones that differ → **save** (1010h, as the set says) → **read
back** what was written → **verify**. Each transfer that times out is retried (``retries``);
a step that still fails, or a verify that finds a value other than written, restarts the
sequence (``restarts`` times); a refusal (SDO abort) is final for its parameter and is
reported, the others go on, and the set is then not saved (a half-applied set is not made
permanent). :meth:`AsyncParameterManager.abort` stops between two transfers.

Every failure is a :class:`ParameterFailure` with a numeric code (step × 10 + fault, the way
a PLC shows it: 32 = a write was refused) and a text naming the object and the value; the
:class:`ParameterReport` says what differed, what was written, saved, verified and failed.

:class:`Parameterise` hooks a manager into a :class:`~cobus.master.Master`: before the master
starts a node it brings the node's parameters up to date (a swapped, factory-fresh device is
re-parameterised) and reports it by a :class:`~cobus.master.BootStepDone` event.
"""

from __future__ import annotations

import asyncio
import logging
import os
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

from cobus._enum import NamedIntEnum
from cobus.blocks.parameters import (
    Parameter,
    ParameterFileError,
    ParameterSet,
    SaveCommand,
    load_parameters,
    parameters_of,
    show,
)
from cobus.errors import CobusError
from cobus.master.errors import BootStepError
from cobus.od import CommandObjects, DataType, ObjectDictionary, Variable, process_data_of
from cobus.runtime.twin import BlockingTwin

log = logging.getLogger(__name__)

__all__ = [
    "AsyncParameterManager",
    "CommandsInSetError",
    "ParameterFailure",
    "ParameterFault",
    "ParameterManager",
    "ParameterReport",
    "ParameterStep",
    "Parameterise",
    "SdoPort",
]


class SdoPort(Protocol):
    """What the manager needs of a node: bytes up and down by index and sub-index."""

    async def upload(self, index: int, subindex: int) -> bytes:
        """The object's bytes (raises an error with a ``code`` when the node refuses,
        TimeoutError when it does not answer)."""

    async def download(self, index: int, subindex: int, data: bytes) -> None:
        """Write the object's bytes (errors as :meth:`upload`)."""


class CommandsInSetError(CobusError, ValueError):
    """A set that would write commands (a controlword, a mode, a set-point, an output), refused
    before anything is written; ``commands`` lists each parameter with why it is a command."""

    def __init__(self, node: str, commands: list[tuple[Parameter, str]]) -> None:
        self.node = node
        self.commands = commands
        super().__init__(self.describe("allow_commands=True"))

    def describe(self, how: str) -> str:
        """The message, with ``how`` the caller allows commands (``--allow-commands``)."""
        listed = "; ".join(
            f"{p.address}{' ' + p.name if p.name else ''}: {why}" for p, why in self.commands
        )
        return (
            f"{self.node}: the set writes {len(self.commands)} command(s), not parameters - "
            f"{listed}. Writing them makes the device act (a drive switched on or moved, "
            "outputs switched, its parameters stored or restored): leave them out of the set, "
            f"or allow them explicitly ({how})"
        )


class ParameterStep(NamedIntEnum):
    """The steps of the sequence (the number a PLC shows)."""

    IDLE = 0
    READ = 1
    COMPARE = 2
    WRITE = 3
    SAVE = 4
    READ_BACK = 5
    VERIFY = 6
    DONE = 7


class ParameterFault(NamedIntEnum):
    """What went wrong in a step."""

    TIMEOUT = 1  # no answer, after the retries
    REFUSED = 2  # the node aborted the transfer
    BAD_ANSWER = 3  # an answer of a length the type does not have
    MISMATCH = 4  # read back other than written
    ABORTED = 5  # abort() was called


_FAULT_TEXT = {
    ParameterFault.TIMEOUT: "no answer",
    ParameterFault.REFUSED: "refused",
    ParameterFault.BAD_ANSWER: "answer does not fit the type",
    ParameterFault.MISMATCH: "reads back a different value",
    ParameterFault.ABORTED: "aborted",
}


@dataclass(frozen=True)
class ParameterFailure:
    """One failure: in which step, what kind, on which parameter (None: the save command or
    the whole sequence), why in words, the SDO abort code, and the value read (verify)."""

    step: ParameterStep
    fault: ParameterFault
    parameter: Parameter | None
    reason: str
    abort_code: int | None = None
    actual: Any = None

    @property
    def code(self) -> int:
        """step × 10 + fault: 12 a read refused, 31 a write unanswered, 64 a verify mismatch."""
        return int(self.step) * 10 + int(self.fault)

    def __str__(self) -> str:
        what = {
            ParameterStep.READ: "read",
            ParameterStep.WRITE: "write",
            ParameterStep.SAVE: "save",
            ParameterStep.READ_BACK: "read back",
            ParameterStep.VERIFY: "verify",
        }.get(self.step, self.step.name.lower())
        target = f" {self.parameter}" if self.parameter is not None else ""
        return f"[{self.code}] {what}{target}: {_FAULT_TEXT[self.fault]}: {self.reason}"


@dataclass
class ParameterReport:
    """What one run found and did."""

    node: str
    #: How many parameters the set has.
    checked: int = 0
    #: Each parameter that differed, with the value the node held (None: unreadable).
    differences: list[tuple[Parameter, Any]] = field(default_factory=list)
    written: list[Parameter] = field(default_factory=list)
    #: Whether the save command was sent and taken (None: nothing to save / no command).
    saved: bool | None = None
    verified: bool = False
    failures: list[ParameterFailure] = field(default_factory=list)
    #: Runs of the sequence (1 + restarts used).
    attempts: int = 0
    aborted: bool = False
    #: Seconds the run took (on the network's clock).
    duration: float = 0.0
    #: Only compared (diff), nothing written.
    dry_run: bool = False

    @property
    def ok(self) -> bool:
        """Whether the node now holds the whole set (diff: whether it already did)."""
        if self.failures or self.aborted:
            return False
        return not self.differences if self.dry_run else self.verified or not self.differences

    @property
    def up_to_date(self) -> bool:
        """Whether the node held every set-point before anything was written."""
        return not self.failures and not self.aborted and not self.differences

    @property
    def code(self) -> int:
        """0 when ok, else the code of the first failure (5 aborted, 99 differs on a diff)."""
        if self.failures:
            return self.failures[0].code
        if self.aborted:
            return int(ParameterFault.ABORTED)
        return 99 if self.dry_run and self.differences else 0

    @property
    def summary(self) -> str:
        """One line: what happened."""
        if self.aborted:
            return f"{self.node}: aborted"
        if self.failures:
            return f"{self.node}: failed, {len(self.failures)} problem(s): {self.failures[0]}"
        if not self.differences:
            plural = "" if self.checked == 1 else "s"
            return f"{self.node}: up to date ({self.checked} parameter{plural})"
        if self.dry_run:
            differ = "differs" if len(self.differences) == 1 else "differ"
            return f"{self.node}: {len(self.differences)} of {self.checked} parameters {differ}"
        saved = {True: ", saved", False: ", NOT saved", None: ", not saved (no save command)"}[
            self.saved
        ]
        return (
            f"{self.node}: re-parameterised, {len(self.written)} of {self.checked} written"
            f"{saved} and verified"
        )

    def __str__(self) -> str:
        lines = [self.summary]
        for param, actual in self.differences:
            held = "unreadable" if actual is None else show(actual)
            lines.append(f"  differs: {param} (held {held})")
        lines.extend(f"  failed: {f}" for f in self.failures)
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        """The report as plain data (``--json``)."""

        def plain(value: Any) -> Any:
            return value.hex() if isinstance(value, bytes) else value

        return {
            "node": self.node,
            "ok": self.ok,
            "code": self.code,
            "summary": self.summary,
            "checked": self.checked,
            "differences": [
                {"object": p.address, "name": p.name, "set": plain(p.value), "held": plain(a)}
                for p, a in self.differences
            ],
            "written": [p.address for p in self.written],
            "saved": self.saved,
            "verified": self.verified,
            "failures": [
                {
                    "code": f.code,
                    "step": f.step.name,
                    "fault": f.fault.name,
                    "object": None if f.parameter is None else f.parameter.address,
                    "text": str(f),
                    "abort_code": f.abort_code,
                }
                for f in self.failures
            ],
            "attempts": self.attempts,
            "aborted": self.aborted,
            "duration": self.duration,
        }


class _Restart(Exception):
    """A step failed in a way that a new run may cure."""


class _Aborted(Exception):
    pass


#: progress(step, done, total)
Progress = Callable[[ParameterStep, int, int], object]


def sdo_port(node: Any) -> SdoPort:
    """The SDO port of ``node``: an SDO channel itself, or a node with ``.sdo`` (a remote
    node, a master's node), or an EC motor drive (its own SDO dialect)."""
    from cobus.profiles.ecmotor import AsyncEcMotorDrive

    if isinstance(node, AsyncEcMotorDrive):
        return _EcPort(node)
    if hasattr(node, "upload") and hasattr(node, "download"):
        return node  # type: ignore[no-any-return]
    sdo = getattr(node, "sdo", None)
    if sdo is not None and hasattr(sdo, "upload"):
        return sdo  # type: ignore[no-any-return]
    raise TypeError(
        f"{node!r} has no SDO: give a remote node, a master's node, an SDO channel or an EC "
        "motor drive"
    )


class _EcPort:
    """The EC motor's dialect as an SDO port (sub 0: 16-bit access, 1: 32-bit)."""

    def __init__(self, drive: Any) -> None:
        self.drive = drive

    async def upload(self, index: int, subindex: int) -> bytes:
        obj = self.drive._object(index, subindex)
        value = await self.drive.read(index, subindex)
        return int(value & ((1 << obj.size * 8) - 1)).to_bytes(obj.size, "little")

    async def download(self, index: int, subindex: int, data: bytes) -> None:
        obj = self.drive._object(index, subindex)
        value = int.from_bytes(data[: obj.size], "little", signed=obj.signed)
        await self.drive.write(index, value, subindex)


def _node_name(node: Any) -> str:
    node_id = getattr(node, "node_id", None)
    if node_id is None:
        node_id = getattr(node, "address", None)
    name = getattr(node, "name", None)
    text = f"node {node_id}" if node_id is not None else "the node"
    return f"{text} {name!r}" if isinstance(name, str) and name else text


def _od_of(node: Any) -> ObjectDictionary | None:
    for holder in (node, getattr(node, "sdo", None), getattr(node, "config", None)):
        od = getattr(holder, "od", None)
        if isinstance(od, ObjectDictionary):
            return od
    return None


def _clock(node: Any) -> Callable[[], float]:
    network = getattr(node, "network", None) or getattr(
        getattr(node, "master", None), "network", None
    )
    now = getattr(network, "time", None)
    return now if callable(now) else time.monotonic


class AsyncParameterManager:
    """Brings ``node`` to ``parameters`` (a :class:`ParameterSet` or a file to read one
    from, with the node's EDS for names).

    ``retries``: transfers tried again after a timeout; ``restarts``: runs of the whole
    sequence after a step failed; ``save``: False never saves (even if the set says how);
    ``progress(step, done, total)`` is called as it goes; ``od``: names for
    :meth:`snapshot` (default: the set's or the node's dictionary).

    A parameter is configuration. :meth:`apply` refuses, with :class:`CommandsInSetError` and
    before any transfer, a set that holds a command - an object whose write makes the node
    act (a CiA 402 controlword, mode or set-point, a CiA 401 output, what the EDS maps to an
    RPDO; see :class:`~cobus.od.CommandObjects`) - unless ``allow_commands`` is True.
    """

    def __init__(
        self,
        node: Any,
        parameters: ParameterSet | str | os.PathLike[str] | None = None,
        *,
        retries: int = 2,
        restarts: int = 1,
        save: bool = True,
        progress: Progress | None = None,
        od: ObjectDictionary | None = None,
        allow_commands: bool = False,
    ) -> None:
        for what, value in (("retries", retries), ("restarts", restarts)):
            if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 100:
                raise ValueError(f"{what}={value!r}: give a whole number 0..100")
        self.port = sdo_port(node)
        self.node_name = _node_name(node)
        self.od = od if od is not None else _od_of(node)
        if parameters is not None and not isinstance(parameters, ParameterSet):
            parameters = load_parameters(parameters, od=self.od)
        self.parameters = parameters
        if self.od is None and parameters is not None:
            self.od = parameters.od
        self.retries = retries
        self.restarts = restarts
        self.save = save
        self.progress = progress
        self.allow_commands = allow_commands
        #: The objects the last :meth:`snapshot` left out as commands or process data, each
        #: with why (name them to capture them).
        self.left_out: list[tuple[Variable, str]] = []
        #: Whether the last :meth:`snapshot` stopped early: the node did not answer (at its
        #: first object, or several in a row); what it holds is then no image of the node.
        self.stopped = False
        #: The step the sequence is in (IDLE before and after a run).
        self.step = ParameterStep.IDLE
        #: The report of the last run (None before the first).
        self.last_report: ParameterReport | None = None
        self._abort = False
        self._running = False
        self._failures: list[ParameterFailure] = []
        self._written: dict[tuple[int, int], Parameter] = {}
        self._unsaved = False
        #: The step and parameter of the transfer a cancellation cut short (None: none was):
        #: in the WRITE step, a value that may or may not have reached the node.
        self.cut_short: tuple[ParameterStep, Parameter] | None = None
        self._now = _clock(node)

    @property
    def written(self) -> list[Parameter]:
        """What the running (or last) :meth:`apply` has written so far - also when it was
        interrupted or cancelled."""
        return list(self._written.values())

    @property
    def unsaved(self) -> bool:
        """Whether values written by the running (or last) :meth:`apply` are not saved yet
        (the node loses them at its next power-up)."""
        return self._unsaved

    def abort(self) -> None:
        """Stop the running sequence before its next transfer (its report says aborted)."""
        self._abort = True

    # ------------------------------------------------------------------ public runs

    async def diff(self) -> ParameterReport:
        """Read and compare only: the report's ``differences`` (nothing is written)."""
        return await self._run(apply=False)

    async def apply(self) -> ParameterReport:
        """The whole sequence: read, compare, write what differs, save, read back, verify."""
        return await self._run(apply=True)

    async def snapshot(
        self,
        objects: Iterable[int | tuple[int, int] | str] | None = None,
        *,
        communication: bool = False,
    ) -> tuple[ParameterSet, list[ParameterFailure]]:
        """Read the node's parameters into a set (to write to a file): ``objects`` by name,
        index or (index, sub); by default every readable and writable object of the
        dictionary from 2000h on (``communication``: from 1000h on, without the 1010h/1011h
        commands and the PDO parameters the master configures). Objects the node refuses
        or does not answer are left out and listed.

        By default a snapshot holds configuration only: commands and process data
        (:func:`~cobus.od.process_data_of`: controlwords, modes, set-points, outputs, what
        the EDS maps to an RPDO or marks ``rww``) are left out and listed in
        :attr:`left_out`; an object named in ``objects`` is read all the same."""
        od = self.od
        if od is None:
            raise ValueError("a snapshot needs the node's EDS for names and types: give od=")
        self.left_out = []
        self.stopped = False
        chosen = list(_chosen(od, objects, communication, self.left_out))
        if not chosen:
            raise ValueError("none of those objects is a readable and writable parameter")
        if self._running:
            raise RuntimeError(f"the parameter manager of {self.node_name} runs already")
        values: list[tuple[Variable, Any]] = []
        self._running = True
        self._abort = False
        self._failures = []
        self.cut_short = None
        silent = 0  # reads in a row the node did not answer
        try:
            for done, var in enumerate(chosen):
                self._report_progress(ParameterStep.READ, done, len(chosen))
                probe = Parameter(var.index, var.subindex, None, var.data_type, var.name)
                try:
                    data = await self._transfer(ParameterStep.READ, probe, None)
                except _Restart:  # no answer after the retries (its failure is listed)
                    silent += 1
                    if not values or silent >= _SILENT_READS:
                        self._failures.append(
                            ParameterFailure(
                                ParameterStep.READ,
                                ParameterFault.TIMEOUT,
                                None,
                                f"{self.node_name} does not answer: the snapshot stopped "
                                f"after {done + 1} of {len(chosen)} object(s)",
                            )
                        )
                        self.stopped = True
                        break
                    continue
                except _Refused:
                    silent = 0
                    continue  # (its failure is listed)
                silent = 0
                try:
                    values.append((var, probe.decode(data)))
                except ValueError as exc:
                    self._failures.append(
                        ParameterFailure(
                            ParameterStep.READ, ParameterFault.BAD_ANSWER, probe, str(exc)
                        )
                    )
            self._report_progress(ParameterStep.READ, len(chosen), len(chosen))
        except _Aborted:
            self._failures.append(
                ParameterFailure(ParameterStep.READ, ParameterFault.ABORTED, None, "abort()")
            )
        finally:
            self.step = ParameterStep.IDLE
            self._running = False
        return parameters_of(od, values), list(self._failures)

    # ------------------------------------------------------------------ the sequence

    async def _run(self, *, apply: bool) -> ParameterReport:
        params = self.parameters
        if params is None:
            raise ValueError("no parameter set: give one to the manager")
        if self._running:
            raise RuntimeError(f"the parameter manager of {self.node_name} runs already")
        if apply and not self.allow_commands:
            commands = self.commands_in(params)
            if commands:
                raise CommandsInSetError(self.node_name, commands)
        report = ParameterReport(self.node_name, checked=len(params), dry_run=not apply)
        began = self._now()
        self._running = True
        self._abort = False
        self._failures = []
        self._written = {}
        self._unsaved = False
        self.cut_short = None
        try:
            for attempt in range(self.restarts + 1):
                report.attempts = attempt + 1
                self._failures = []
                try:
                    await self._sequence(params, report, apply, first=attempt == 0)
                    break
                except _Restart:
                    continue
        except _Aborted:
            report.aborted = True
            self._failures.append(
                ParameterFailure(self.step, ParameterFault.ABORTED, None, "abort() was called")
            )
        finally:
            self.step = ParameterStep.IDLE
            self._running = False
        report.written = list(self._written.values())
        if report.written and report.saved is None and self._unsaved and self._save_command:
            report.saved = False  # written, then the run ended before the save went through
        report.failures = self._failures
        report.duration = self._now() - began
        self.last_report = report
        return report

    def commands_in(self, params: Iterable[Parameter]) -> list[tuple[Parameter, str]]:
        """The parameters of ``params`` that are commands for this node, each with why."""
        if isinstance(self.port, _EcPort):
            from cobus.profiles.ecmotor import COMMANDS

            commands = CommandObjects(table=COMMANDS)
        else:
            commands = CommandObjects(self.od)
        found = []
        for param in params:
            why = commands.reason(param.index, param.subindex)
            if why is not None:
                found.append((param, why))
        return found

    @property
    def _save_command(self) -> SaveCommand | None:
        if not self.save or self.parameters is None or isinstance(self.port, _EcPort):
            return None  # (the EC motor's dialect has no save command)
        return self.parameters.save

    async def _sequence(
        self, params: ParameterSet, report: ParameterReport, apply: bool, *, first: bool
    ) -> None:
        # READ (refused or odd answers are differences with an unknown value: writing them
        # is the way to bring them to their set-point; a write-only object is not read)
        held: dict[int, Any] = {}
        readable: dict[int, bool] = {}
        for n, param in enumerate(params):
            self._report_progress(ParameterStep.READ, n, len(params))
            if param.readable:
                held[n], readable[n] = await self._read(ParameterStep.READ, param)
            else:
                held[n], readable[n] = None, False
        self._report_progress(ParameterStep.READ, len(params), len(params))
        # COMPARE (the differences reported are those the node had before the first write)
        self.step = ParameterStep.COMPARE
        differences = [
            (param, held[n] if readable[n] else None)
            for n, param in enumerate(params)
            if not readable[n] or not param.holds(held[n])
        ]
        if first:
            report.differences = differences
        if not apply:
            self.step = ParameterStep.DONE
            return
        todo = [param for param, _ in differences]
        # what could not be read is written: its read problems are not failures now
        self._failures = [f for f in self._failures if f.step is not ParameterStep.READ]
        # WRITE
        refused = 0
        written_now = []
        for n, param in enumerate(todo):
            self._report_progress(ParameterStep.WRITE, n, len(todo))
            try:
                await self._transfer(ParameterStep.WRITE, param, param.encode())
            except _Refused:
                refused += 1
                continue
            written_now.append(param)
            self._written[(param.index, param.subindex)] = param
            self._unsaved = True
        if todo:
            self._report_progress(ParameterStep.WRITE, len(todo), len(todo))
        # SAVE (also what an earlier attempt wrote and could not save)
        command = self._save_command
        if command is not None and self._unsaved:
            if refused:
                report.saved = False  # a half-applied set is not made permanent
            else:
                self._report_progress(ParameterStep.SAVE, 0, 1)
                report.saved = await self._save(command)
                self._unsaved = not report.saved
                self._report_progress(ParameterStep.SAVE, 1, 1)
        # READ BACK and VERIFY what was written now
        mismatched = False
        checked = [p for p in written_now if p.readable]
        for n, param in enumerate(checked):
            self._report_progress(ParameterStep.READ_BACK, n, len(checked))
            value, ok = await self._read(ParameterStep.READ_BACK, param)
            self.step = ParameterStep.VERIFY
            if ok and not param.holds(value):
                mismatched = True
                self._failures.append(
                    ParameterFailure(
                        ParameterStep.VERIFY,
                        ParameterFault.MISMATCH,
                        param,
                        f"reads {show(value)}",
                        actual=value,
                    )
                )
        if checked:
            self._report_progress(ParameterStep.READ_BACK, len(checked), len(checked))
        if mismatched:
            raise _Restart()
        self.step = ParameterStep.DONE
        report.verified = not self._failures

    async def _read(self, step: ParameterStep, param: Parameter) -> tuple[Any, bool]:
        """The value the node holds (False: refused or not decodable, reported)."""
        try:
            data = await self._transfer(step, param, None)
        except _Refused:
            return None, False
        try:
            return param.decode(data), True
        except ValueError as exc:
            self._failures.append(
                ParameterFailure(step, ParameterFault.BAD_ANSWER, param, f"{data.hex(' ')}: {exc}")
            )
            return None, False

    async def _save(self, command: SaveCommand) -> bool:
        probe = Parameter(command.index, command.subindex, command.signature, _U32, "save")
        try:
            await self._transfer(ParameterStep.SAVE, probe, command.signature)
        except _Refused:
            return False
        return True

    async def _transfer(self, step: ParameterStep, param: Parameter, data: bytes | None) -> bytes:
        """One upload (``data`` None) or download, retried after a timeout. A refusal is
        reported and raises :class:`_Refused`; no answer after the retries :class:`_Restart`."""
        self.step = step
        last = ""
        for _attempt in range(self.retries + 1):
            if self._abort:
                raise _Aborted()
            try:
                if data is None:
                    return await self.port.upload(param.index, param.subindex)
                await self.port.download(param.index, param.subindex, data)
                return data
            except asyncio.CancelledError:
                self.cut_short = (step, param)
                raise
            except TimeoutError as exc:
                last = str(exc) or "timeout"
                continue
            except (CobusError, ValueError) as exc:
                code = getattr(exc, "code", None)
                self._failures.append(
                    ParameterFailure(
                        step,
                        ParameterFault.REFUSED,
                        param,
                        str(exc),
                        int(code) if isinstance(code, int) else None,
                    )
                )
                raise _Refused() from None
        tries = self.retries + 1
        self._failures.append(
            ParameterFailure(
                step,
                ParameterFault.TIMEOUT,
                param,
                f"{last} ({tries} attempt(s))",
            )
        )
        raise _Restart()

    def _report_progress(self, step: ParameterStep, done: int, total: int) -> None:
        self.step = step
        if self.progress is not None:
            try:
                self.progress(step, done, total)
            except Exception:  # a display's failure must not leave a node half-written
                log.exception("parameter manager: progress callback %r failed", self.progress)


class _Refused(Exception):
    pass


#: Reads in a row left unanswered (after their retries) that stop a snapshot.
_SILENT_READS = 3


_U32 = DataType.UNSIGNED32


def is_parameter(var: Variable) -> bool:
    """Whether ``var`` is a parameter a set may hold: readable and writable, not a DOMAIN,
    not the save/restore commands (1010h/1011h), not a PDO's communication or mapping
    parameter (the master configures those), not a record's sub-index 0."""
    if not (var.readable and var.writable) or var.data_type is DataType.DOMAIN:
        return False
    if var.index in (0x1010, 0x1011) or 0x1400 <= var.index <= 0x1BFF:
        return False
    return not (var.subindex == 0 and var.parent is not None)


def _chosen(
    od: ObjectDictionary,
    objects: Iterable[int | tuple[int, int] | str] | None,
    communication: bool,
    left_out: list[tuple[Variable, str]],
) -> Iterable[Variable]:
    if objects is None:
        low = 0x1000 if communication else 0x2000
        commands = CommandObjects(od)
        for var in od.variables():
            if var.index < low or not is_parameter(var):
                continue
            why = process_data_of(var, commands)
            if why is None:
                yield var
            else:
                left_out.append((var, why))
        return
    for key in objects:
        if isinstance(key, tuple):
            named = od.get_variable(*key)
            if named is None:
                raise ValueError(f"the EDS has no object 0x{key[0]:04X}:{key[1]:02X}")
            found: Iterable[Variable] = [named]
        else:
            obj = od.get(key)
            if obj is None:
                shown = f"0x{key:04X}" if isinstance(key, int) else repr(key)
                raise ValueError(f"the EDS has no object {shown}")
            found = [obj] if isinstance(obj, Variable) else list(obj)
        yield from (v for v in found if is_parameter(v))


class ParameterManager(BlockingTwin, twin_of=AsyncParameterManager):
    """The parameter manager for blocking code, with the methods of
    :class:`AsyncParameterManager`, each returning once done: ``ParameterManager(node,
    "drive.yml")`` on a node of a blocking network (``net.add_remote(...)``) or a blocking EC
    motor drive, ``ParameterManager(master, "drive.yml", node="servo")`` on a node a
    :class:`~cobus.master.BlockingMaster` manages."""

    def __init__(
        self, target: Any, parameters: Any = None, *, node: int | str | None = None, **options: Any
    ) -> None:
        runner = getattr(target, "_runner", None)
        if runner is None:
            raise TypeError(
                "ParameterManager takes a node of a blocking Network, a blocking EC motor drive "
                "or a BlockingMaster with node=NAME; in async code use AsyncParameterManager"
            )
        aio_target = target.aio
        if node is not None:
            from cobus.master import Master

            if not isinstance(aio_target, Master):
                raise TypeError("ParameterManager(master, ..., node=NAME): node= is for a master")
            aio_target = runner.call(aio_target.node, node)
        if options.get("progress") is not None:  # in the callback thread, as every callback
            options["progress"] = runner.callback(options["progress"])
        aio = runner.call(lambda: AsyncParameterManager(aio_target, parameters, **options))
        super().__init__(aio, runner)


# ------------------------------------------------------------------------------ master hook


class Parameterise:
    """A master boot step: before the master starts a node, its parameters are brought to
    ``parameters`` (a set or a file; the node's EDS names the objects). The result is the
    detail of the master's :class:`~cobus.master.BootStepDone` event, a failure holds the
    node back (diagnostic "SDO error", the problem names the object).

    ``master.add_boot_step("zapi", Parameterise("zapi.yml"))``; ``status`` maps node-IDs
    to the last report's summary, ``reports`` to the reports."""

    name = "parameters"

    def __init__(self, parameters: ParameterSet | str | os.PathLike[str], **options: Any) -> None:
        self.parameters = parameters
        self.options = options
        self.reports: dict[int, ParameterReport] = {}
        self._sets: dict[int, ParameterSet] = {}  # a file read once per node (its own EDS)

    @property
    def status(self) -> Mapping[int, str]:
        """Node-ID → "up to date" / "re-parameterised ..." / "failed ..."."""
        return {n: r.summary for n, r in self.reports.items()}

    def set_for(self, node: Any) -> ParameterSet:
        """The set as ``node``'s EDS names its objects (a file is read once per node);
        :class:`~cobus.blocks.ParameterFileError` when the file does not fit the node."""
        known = self._sets.get(node.node_id)
        if known is None:
            source = self.parameters
            if not isinstance(source, ParameterSet):
                source = load_parameters(source, od=self.options.get("od") or _od_of(node))
            known = self._sets[node.node_id] = source
        return known

    async def __call__(self, node: Any) -> str:
        self.reports.pop(node.node_id, None)
        try:
            manager = AsyncParameterManager(node, self.set_for(node), **self.options)
        except (ParameterFileError, ValueError, TypeError) as exc:
            raise BootStepError(str(exc)) from None
        try:
            report = await manager.apply()
        except CommandsInSetError as exc:
            raise BootStepError(str(exc)) from None
        self.reports[node.node_id] = report
        if not report.ok:
            raise BootStepError(report.summary)
        return report.summary
