"""The alarm handler: the set of active alarms, the rotating current alarm, acknowledgement,
and a persistent history — the thesis's generic PLC block, fed by every source cobus has.

Sources:

- an integer code per source, like the ZAPI alarm byte: :meth:`AlarmHandler.set_code` (0
  clears; another code replaces the previous one of that source and node);
- boolean conditions combined by rules into alarm numbers: :meth:`AlarmHandler.add_rule`
  (``"overtemp and not fan_ok or door_open"``) and :meth:`AlarmHandler.set_condition`;
- command/feedback checks per program cycle: :meth:`AlarmHandler.check_feedback`;
- a master's events (:meth:`AlarmHandler.attach_master`): emergencies of any node (code
  0000h clears the node's), node missing, heartbeat/guarding lost, wrong device, failed
  configuration, unexpected NMT state, bus-off and error passive;
- a ZAPI adapter (:meth:`AlarmHandler.attach_zapi`): its alarm byte, a lost handshake, and
  command/feedback mismatches;
- anything else: :meth:`AlarmHandler.raise_alarm` / :meth:`AlarmHandler.clear_alarm`.

Each alarm is identified by (source, node, code): raising one that is active, or clearing one
that is not, changes nothing — so the history (:class:`~cobus.blocks.alarm_history.AlarmHistory`)
gets every activation and every clearing exactly once. :meth:`AlarmHandler.current` cycles
through the active alarms, each shown ``view_time`` seconds (3 s as in the thesis), None when
none is active. Texts come from the code tables of :mod:`cobus.blocks.alarm_texts`.
"""

from __future__ import annotations

import ast
import functools
import logging
import os
import re
import sqlite3
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

from cobus.blocks.alarm_history import AlarmHistory, AlarmHistoryDamagedError, AlarmHistoryError
from cobus.blocks.alarm_texts import (
    ALIASES,
    TABLES,
    AlarmSeverity,
    MasterAlarm,
    emcy_text,
    table_text,
)
from cobus.errors import CobusError

__all__ = [
    "Alarm",
    "AlarmAcknowledged",
    "AlarmCleared",
    "AlarmEvent",
    "AlarmHandler",
    "AlarmRaised",
    "AlarmRuleError",
]

log = logging.getLogger(__name__)

Key = tuple[str, int | None, int]
T = TypeVar("T")


def _locked(method: Callable[..., T]) -> Callable[..., T]:
    """Run ``method`` under the handler's lock; the events it produced are delivered after
    the lock is released, in order (a listener may call the handler again)."""

    @functools.wraps(method)
    def run(self: AlarmHandler, *args: Any, **kwargs: Any) -> T:
        with self._lock:
            self._expire_adopted()
            result = method(self, *args, **kwargs)
        self._deliver()
        return result

    return run


class AlarmRuleError(CobusError, ValueError):
    """A rule that cannot be evaluated; the text says what to write instead."""


@dataclass
class Alarm:
    """An active alarm: what (source, node, code, text, severity), since when (``raised_at``,
    the wall clock), whether acknowledged and by whom; ``row`` is its history row."""

    source: str
    node: int | None
    code: int
    text: str
    severity: AlarmSeverity
    raised_at: float
    acknowledged_by: str | None = None
    row: int | None = field(default=None, repr=False)
    #: Active when the program started (from the history), not yet confirmed by its source.
    adopted: bool = False

    @property
    def key(self) -> Key:
        """(source, node, code): what identifies the alarm."""
        return (self.source, self.node, self.code)

    @property
    def acknowledged(self) -> bool:
        """Whether someone acknowledged it."""
        return self.acknowledged_by is not None

    @property
    def code_text(self) -> str:
        """The code as the device's documents write it: EMCY codes in hex (``7121h``)."""
        return f"{self.code:04X}h" if self.source == "emcy" else str(self.code)

    def __str__(self) -> str:
        node = f"node {self.node} " if self.node is not None else ""
        return f"{node}{self.source} {self.code_text}: {self.text}"


@dataclass(frozen=True)
class AlarmEvent:
    """Base of the handler's events."""

    alarm: Alarm


@dataclass(frozen=True)
class AlarmRaised(AlarmEvent):
    """An alarm became active."""


@dataclass(frozen=True)
class AlarmCleared(AlarmEvent):
    """An active alarm's cause is gone."""


@dataclass(frozen=True)
class AlarmAcknowledged(AlarmEvent):
    """Someone acknowledged an active alarm."""


@dataclass
class _Rule:
    number: int
    expression: str
    code: Any  # the compiled check
    names: frozenset[str]
    text: str
    severity: AlarmSeverity


_ALLOWED = (ast.Expression, ast.BoolOp, ast.And, ast.Or, ast.UnaryOp, ast.Not, ast.Name, ast.Load)


def _compile_rule(expression: str) -> tuple[Any, frozenset[str]]:
    if not isinstance(expression, str) or not expression.strip():
        raise AlarmRuleError(f"rule {expression!r}: write conditions joined by and/or/not")
    try:
        tree = ast.parse(expression.strip(), mode="eval")
    except SyntaxError as exc:
        raise AlarmRuleError(f"rule {expression!r} does not read: {exc.msg}") from None
    names = set()
    for node in ast.walk(tree):
        if not isinstance(node, _ALLOWED):
            raise AlarmRuleError(
                f"rule {expression!r}: only condition names, and, or, not and brackets "
                f"(found {type(node).__name__.lower()})"
            )
        if isinstance(node, ast.Name):
            names.add(node.id)
    return compile(tree, "<alarm rule>", "eval"), frozenset(names)


def _move_aside(path: Path) -> Path:
    """Rename a damaged history file (and its WAL and shared-memory files) to
    ``NAME.damaged-YYYYMMDD-HHMMSS``: kept for a post-mortem, out of the way of a new one."""
    stamp = time.strftime("%Y%m%d-%H%M%S")
    target = path.with_name(f"{path.name}.damaged-{stamp}")
    n = 1
    while target.exists():
        n += 1
        target = path.with_name(f"{path.name}.damaged-{stamp}-{n}")
    for suffix in ("-wal", "-shm"):
        extra = path.with_name(path.name + suffix)
        if extra.exists():
            extra.replace(target.with_name(target.name + suffix))
    path.replace(target)
    return target


class AlarmHandler:
    """The alarm handler. ``history``: an :class:`AlarmHistory` or a file for one (None:
    no history); ``view_time``: seconds each active alarm is the current one; ``clock``: the
    time the rotation runs on (default: monotonic; a network's ``time`` on the simulated
    clock); ``wall_clock``: the time logged (default: ``time.time``); ``adopt_grace``:
    seconds an alarm still active in the history when the handler starts stays active
    without its source raising it again (then it is cleared and logged so).

    Listeners run in the thread that raised or cleared the alarm (a blocking master's
    callback thread for its events); the handler may be called from any thread."""

    def __init__(
        self,
        history: AlarmHistory | str | os.PathLike[str] | None = None,
        *,
        view_time: float = 3.0,
        clock: Callable[[], float] | None = None,
        wall_clock: Callable[[], float] | None = None,
        adopt_grace: float = 30.0,
    ) -> None:
        if isinstance(view_time, bool) or not isinstance(view_time, int | float):
            raise ValueError(f"view_time={view_time!r}: seconds above 0")
        if not 0 < view_time < float("inf"):
            raise ValueError(f"view_time={view_time!r}: seconds above 0")
        self.view_time = float(view_time)
        self.clock = clock or time.monotonic
        self.wall_clock = wall_clock or time.time
        #: Where a damaged history file was moved before a new one was started (None: it
        #: was not); an active warning (source "history", code 2) says so too.
        self.history_moved: Path | None = None
        damage = ""
        if history is not None and not isinstance(history, AlarmHistory):
            path = Path(history)
            try:
                history = AlarmHistory(path)
            except AlarmHistoryDamagedError as exc:
                damage = f"the alarm history {path} was damaged ({exc.reason})"
                try:
                    self.history_moved = _move_aside(path)
                except OSError as move:  # (a folder it cannot rename in): no history, said
                    damage += f" and cannot be moved aside ({move.strerror}): no history kept"
                    history = None
                else:
                    history = AlarmHistory(path)
        self.history = history
        self._active: dict[Key, Alarm] = {}
        self._listeners: list[Callable[[AlarmEvent], object]] = []
        self._rules: dict[int, _Rule] = {}
        self._misses: dict[tuple[str, int | None], int] = {}
        self._conditions: dict[str, bool] = {}
        self._shown: Key | None = None
        self._since = 0.0
        self._detach: list[Callable[[], None]] = []
        # sources call in from the network's loop or callback thread, a panel reads from
        # its own: every public method holds this lock
        self._lock = threading.RLock()
        self._outbox: deque[AlarmEvent] = deque()
        self._delivering = False
        self.adopt_grace = float(adopt_grace)
        self._adopted_until: float | None = self.clock() + self.adopt_grace
        #: Why the history could not be written last (None: it works).
        self.history_problem: str | None = None
        if damage:
            text = damage
            if self.history_moved is not None:
                text += f": it was kept as {self.history_moved.name}, a new one started"
            log.warning("%s", text)
            self._raise_unlogged("history", 2, text, AlarmSeverity.WARNING)
        if history is not None:
            self._adopt(history)

    def _adopt(self, history: AlarmHistory) -> None:
        """Alarms still active when the program stopped are active again, their history rows
        going on; a source confirms one by raising it again within ``adopt_grace``."""
        records = self._log("reading the active alarms", lambda: history.query(active=True))
        for record in reversed(records or []):
            try:
                severity = AlarmSeverity.of(record.severity)
            except ValueError:
                severity = AlarmSeverity.ALARM
            alarm = Alarm(
                record.source,
                record.node,
                record.code,
                record.text,
                severity,
                record.raised_at,
                record.acknowledged_by,
                record.id,
                adopted=True,
            )
            self._active[alarm.key] = alarm

    # ------------------------------------------------------------------ listeners

    def add_listener(self, listener: Callable[[AlarmEvent], object]) -> None:
        """Call ``listener(event)`` for every :class:`AlarmRaised`, :class:`AlarmCleared` and
        :class:`AlarmAcknowledged`."""
        self._listeners.append(listener)

    def remove_listener(self, listener: Callable[[AlarmEvent], object]) -> None:
        """Stop calling ``listener``."""
        if listener in self._listeners:
            self._listeners.remove(listener)

    def _emit(self, event: AlarmEvent) -> None:
        self._outbox.append(event)

    def _deliver(self) -> None:
        """Give the queued events to the listeners, outside the lock, in order; a call
        made by a listener queues its events behind those still to come."""
        with self._lock:
            if self._delivering:
                return
            self._delivering = True
        try:
            while True:
                with self._lock:
                    if not self._outbox:
                        self._delivering = False
                        return
                    event = self._outbox.popleft()
                for listener in list(self._listeners):
                    try:
                        listener(event)
                    except Exception:  # a listener's failure must not lose the alarm
                        log.exception("alarm listener %r failed", listener)
        except BaseException:
            with self._lock:
                self._delivering = False
            raise

    def _log(self, what: str, call: Callable[[], T]) -> T | None:
        """Run a history write; a failure is logged and shown as an alarm of its own, and
        never loses the alarm it was about (that is active in memory already)."""
        if self.history is None:
            return None
        try:
            result = call()
        except (sqlite3.Error, AlarmHistoryError) as exc:
            problem = f"the alarm history cannot be written ({what}): {exc}"
            log.error("%s", problem)
            first = self.history_problem is None
            self.history_problem = problem
            if first:
                self._raise_unlogged("history", 1, problem, AlarmSeverity.WARNING)
            return None
        if self.history_problem is not None:
            self.history_problem = None
            self._clear_unlogged("history", 1)
        return result

    def _raise_unlogged(self, source: str, code: int, text: str, severity: AlarmSeverity) -> None:
        key = (source, None, code)
        if key not in self._active:
            alarm = Alarm(source, None, code, text, severity, self.wall_clock())
            self._insert(alarm)

    def _clear_unlogged(self, source: str, code: int) -> None:
        alarm = self._remove((source, None, code))
        if alarm is not None:
            self._emit(AlarmCleared(alarm))

    def _insert(self, alarm: Alarm) -> None:
        self._active[alarm.key] = alarm
        if len(self._active) == 1:
            self._shown, self._since = alarm.key, self.clock()
        self._emit(AlarmRaised(alarm))

    def _remove(self, key: Key) -> Alarm | None:
        alarm = self._active.get(key)
        if alarm is None:
            return None
        if key == self._shown:
            order = list(self._active)
            following = order[(order.index(key) + 1) % len(order)]
            self._shown = None if following == key else following
            self._since = self.clock()
        del self._active[key]
        return alarm

    def _expire_adopted(self) -> None:
        if self._adopted_until is None or self.clock() < self._adopted_until:
            return
        self._adopted_until = None
        for key in [k for k, a in self._active.items() if a.adopted]:
            self._clear(key)

    # ------------------------------------------------------------------ raise / clear

    @_locked
    def raise_alarm(
        self,
        source: str,
        code: int,
        *,
        node: int | None = None,
        text: str | None = None,
        severity: AlarmSeverity | None = None,
        table: str | None = None,
    ) -> Alarm:
        """Make alarm (``source``, ``node``, ``code``) active (nothing changes if it is);
        ``text`` default: the code's text in ``table`` (default: the table named like the
        source, else the code's number)."""
        if isinstance(code, bool) or not isinstance(code, int):
            raise ValueError(f"alarm code {code!r}: an integer")
        if not isinstance(source, str) or not source:
            raise ValueError(f"alarm source {source!r}: a name")
        key = (source, node, code)
        alarm = self._active.get(key)
        if alarm is not None:
            alarm.adopted = False  # (its source confirms an alarm of before a restart)
            return alarm
        tab = TABLES.get(ALIASES.get(table or source, table or source))
        if text is None:
            text = tab.text(code) if tab is not None else f"alarm {code}"
        level = AlarmSeverity.of(severity) if severity is not None else None
        if level is None:
            level = tab.severity if tab is not None else AlarmSeverity.ALARM
        alarm = Alarm(source, node, code, text, level, self.wall_clock())
        self._insert(alarm)  # active and announced first: a history failure loses nothing
        alarm.row = self._log(
            "activation",
            lambda: self.history.opened(  # type: ignore[union-attr]
                source=source,
                node=node,
                code=code,
                text=alarm.text,
                severity=alarm.severity.name.lower(),
                at=alarm.raised_at,
            ),
        )
        return alarm

    @_locked
    def clear_alarm(self, source: str, code: int, *, node: int | None = None) -> bool:
        """The cause of alarm (``source``, ``node``, ``code``) is gone; False if it was not
        active."""
        return self._clear((source, node, code))

    def _clear(self, key: Key) -> bool:
        alarm = self._remove(key)
        if alarm is None:
            return False
        self._emit(AlarmCleared(alarm))
        row = alarm.row
        if row is not None:
            at = self.wall_clock()
            self._log("clearing", lambda: self.history.cleared(row, at))  # type: ignore[union-attr]
        return True

    @_locked
    def clear_source(self, source: str, *, node: int | None = None) -> int:
        """Clear every active alarm of ``source`` (of ``node`` only, when given)."""
        keys = [k for k in self._active if k[0] == source and (node is None or k[1] == node)]
        for k in keys:
            self._clear(k)
        return len(keys)

    @_locked
    def set_code(
        self, source: str, code: int, *, node: int | None = None, table: str | None = None
    ) -> None:
        """An integer alarm input (like the ZAPI alarm byte): ``code`` is the one active
        alarm of ``source`` and ``node``; 0 (or the table's "no alarm" code, e.g. STÖBER's
        event 30) clears it."""
        tab = TABLES.get(ALIASES.get(table or source, table or source))
        quiet = code == 0 or (tab is not None and code == tab.no_alarm)
        for key in [k for k in self._active if k[0] == source and k[1] == node]:
            if quiet or key[2] != code:
                self._clear(key)
        if not quiet:
            self.raise_alarm(source, code, node=node, table=table)

    # ------------------------------------------------------------------ rules

    @_locked
    def check_feedback(
        self,
        name: str,
        commanded: bool,
        reported: bool,
        *,
        code: int,
        node: int | None = None,
        cycles: int = 3,
        text: str | None = None,
    ) -> bool:
        """A command/feedback check, called once per program cycle: alarm ``code`` (source
        ``feedback``) when ``commanded`` is on and ``reported`` stayed off for ``cycles``
        calls in a row (a contactor that does not close); cleared once it is reported or
        no longer commanded. Returns whether the alarm is active."""
        if isinstance(cycles, bool) or not isinstance(cycles, int) or cycles < 1:
            raise ValueError(f"cycles={cycles!r}: 1 or more")
        key = (name, node)
        if commanded and not reported:
            misses = self._misses.get(key, 0) + 1
            self._misses[key] = misses
            if misses >= cycles:
                shown = text or f"{name} commanded but not reported back"
                self.raise_alarm("feedback", code, node=node, text=shown)
                return True
            return ("feedback", node, code) in self._active
        self._misses[key] = 0
        self._clear(("feedback", node, code))
        return False

    @_locked
    def add_rule(
        self,
        number: int,
        when: str,
        *,
        text: str,
        severity: AlarmSeverity = AlarmSeverity.ALARM,
    ) -> None:
        """Alarm ``number`` (source ``"rule"``) is active while the conditions ``when``
        holds: names of boolean conditions joined by ``and``, ``or``, ``not`` and brackets,
        e.g. ``"overtemp and not fan_ok or door_open"``. A condition never set is False."""
        if isinstance(number, bool) or not isinstance(number, int):
            raise AlarmRuleError(f"rule number {number!r}: an integer")
        if number in self._rules:
            raise AlarmRuleError(f"there is a rule {number} already ({self._rules[number].text})")
        code, names = _compile_rule(when)
        self._rules[number] = _Rule(number, when, code, names, text, AlarmSeverity.of(severity))
        self._evaluate([self._rules[number]])

    def set_condition(self, name: str, value: bool) -> None:
        """Set a boolean condition and re-evaluate the rules that use it."""
        self.set_conditions({name: value})

    @_locked
    def set_conditions(self, values: Mapping[str, bool]) -> None:
        """Set several conditions at once (rules see them together: no alarm flickers on
        between two of them)."""
        for name, value in values.items():
            if not isinstance(value, bool):
                raise ValueError(f"condition {name!r} = {value!r}: True or False")
        changed = set()
        for name, value in values.items():
            if self._conditions.get(name, False) != value:
                changed.add(name)
            self._conditions[name] = value
        if changed:
            self._evaluate(r for r in self._rules.values() if r.names & changed)

    @property
    def conditions(self) -> Mapping[str, bool]:
        """The conditions as last set."""
        return dict(self._conditions)

    def _evaluate(self, rules: Iterable[_Rule]) -> None:
        for rule in list(rules):
            scope = {name: self._conditions.get(name, False) for name in rule.names}
            if eval(rule.code, {"__builtins__": {}}, scope):
                self.raise_alarm("rule", rule.number, text=rule.text, severity=rule.severity)
            else:
                self._clear(("rule", None, rule.number))

    # ------------------------------------------------------------------ state

    @property
    def active(self) -> tuple[Alarm, ...]:
        """The active alarms, oldest first."""
        with self._lock:
            self._expire_adopted()
            found = tuple(self._active.values())
        self._deliver()
        return found

    @_locked
    def current(self) -> Alarm | None:
        """The alarm to show now: each active one in turn for ``view_time`` seconds (in the
        order they were raised), None when none is active."""
        if not self._active:
            self._shown = None
            return None
        now = self.clock()
        order = list(self._active)
        if self._shown not in self._active or now < self._since:  # (a clock set back)
            self._shown = self._shown if self._shown in self._active else order[0]
            self._since = now
        steps = int((now - self._since) // self.view_time)
        if steps > 0:
            assert self._shown is not None
            position = (order.index(self._shown) + steps) % len(order)
            self._shown = order[position]
            self._since += steps * self.view_time
        assert self._shown is not None
        return self._active[self._shown]

    @_locked
    def acknowledge(self, alarm: Alarm | Key | None = None, *, by: str = "operator") -> int:
        """Acknowledge ``alarm`` (None: every active one not yet acknowledged); how many
        were acknowledged now."""
        if alarm is None:
            targets = [a for a in self._active.values() if not a.acknowledged]
        else:
            key = alarm.key if isinstance(alarm, Alarm) else alarm
            found = self._active.get(key)
            targets = [found] if found is not None and not found.acknowledged else []
        at = self.wall_clock()
        for target in targets:
            target.acknowledged_by = by
            self._emit(AlarmAcknowledged(target))
            row = target.row
            if row is not None:
                self._log(
                    "acknowledgement",
                    lambda row=row: self.history.acknowledged(row, at, by),  # type: ignore[union-attr,misc]
                )
        return len(targets)

    @_locked
    def select(
        self,
        *,
        node: int | None = None,
        source: str | None = None,
        min_severity: AlarmSeverity | int | str | None = None,
        unacknowledged: bool = False,
    ) -> tuple[Alarm, ...]:
        """The active alarms of ``node``/``source`` (None: any), at least ``min_severity``,
        only those not acknowledged yet (``unacknowledged``), oldest first."""
        low = AlarmSeverity.of(min_severity) if min_severity is not None else None
        return tuple(
            a
            for a in self._active.values()
            if (node is None or a.node == node)
            and (source is None or a.source == source)
            and (low is None or a.severity >= low)
            and not (unacknowledged and a.acknowledged)
        )

    @property
    def highest_severity(self) -> AlarmSeverity | None:
        """The worst severity among the active alarms (None: none active) — for a horn or
        a lamp."""
        return max((a.severity for a in self.active), default=None)

    @property
    def unacknowledged(self) -> int:
        """How many active alarms nobody acknowledged yet."""
        return sum(1 for a in self.active if not a.acknowledged)

    # ------------------------------------------------------------------ sources

    def attach_master(
        self, master: Any, *, emcy_tables: Mapping[int | str, str] | None = None
    ) -> None:
        """Raise and clear alarms from ``master``'s events (a :class:`~cobus.master.Master`,
        or a :class:`~cobus.master.BlockingMaster`: then the handler works in its callback
        thread, off the bus loop):

        - emergencies (source ``emcy``), cleared by the node's error reset (00xxh: those its
          error register no longer shows) or its boot-up; texts from ``emcy_tables[node]``
          (node-ID or name → ``cia402``, ``stober`` or ``cia301``, the default);
        - the master's alarms (source ``master``, codes of
          :class:`~cobus.blocks.alarm_texts.MasterAlarm`): node missing, heartbeat or
          guarding lost, guarding toggle, wrong device, configuration failed (until the next
          configuration), unexpected NMT state, TPDO missing, bus-off, error passive,
          network stopped.
        """
        from cobus.master import events as ev
        from cobus.master.states import MasterState, NodeState
        from cobus.runtime import BusState, BusStateChanged
        from cobus.runtime.emcy import error_still_shown

        runner = getattr(master, "_runner", None)
        aio = getattr(master, "aio", master)
        tables: dict[int, str] = {}
        for key, name in (emcy_tables or {}).items():
            emcy_text(name, 0x1000)  # KeyError for a table that names no EMCY codes
            tables[aio.node(key).node_id] = name
        per_node = (
            MasterAlarm.NODE_MISSING,
            MasterAlarm.ERROR_CONTROL_LOST,
            MasterAlarm.GUARDING_TOGGLE,
            MasterAlarm.WRONG_DEVICE,
            MasterAlarm.UNEXPECTED_STATE,
            MasterAlarm.TPDO_MISSING,
        )

        def master_alarm(node: int | None, code: MasterAlarm, detail: str) -> None:
            base = table_text("master", code)
            detail = re.sub(r"^node \d+:? ", "", detail)  # (the alarm names its node)
            self.raise_alarm("master", int(code), node=node, text=f"{base}: {detail}")

        def clear(node: int | None, *codes: MasterAlarm) -> None:
            for code in codes:
                self.clear_alarm("master", int(code), node=node)

        def on_emergency(event: Any) -> None:
            node = event.node_id
            if event.code >> 8 == 0:  # error reset: what the register no longer shows goes
                for alarm in self.select(node=node, source="emcy"):
                    if not event.register or not error_still_shown(alarm.code, event.register):
                        self.clear_alarm("emcy", alarm.code, node=node)
                return
            table = tables.get(node)
            text = emcy_text(table, event.code) if table else event.text
            self.raise_alarm("emcy", event.code, node=node, text=text)

        def on_event(event: Any) -> None:
            if isinstance(event, ev.NodeEmergency):
                on_emergency(event)
            elif isinstance(event, ev.NodeBooted):
                self.clear_source("emcy", node=event.node_id)  # a reset forgets its errors
                clear(event.node_id, MasterAlarm.NODE_MISSING, MasterAlarm.ERROR_CONTROL_LOST)
            elif isinstance(event, ev.NodeMissing):
                master_alarm(event.node_id, MasterAlarm.NODE_MISSING, event.reason)
            elif isinstance(event, ev.ErrorControlLost):
                master_alarm(event.node_id, MasterAlarm.ERROR_CONTROL_LOST, f"{event.kind} lost")
            elif isinstance(event, ev.ErrorControlRestored):
                clear(event.node_id, MasterAlarm.ERROR_CONTROL_LOST, MasterAlarm.GUARDING_TOGGLE)
            elif isinstance(event, ev.GuardingToggleFault):
                master_alarm(event.node_id, MasterAlarm.GUARDING_TOGGLE, str(event))
            elif isinstance(event, ev.DeviceTypeMismatch | ev.IdentityMismatch):
                master_alarm(event.node_id, MasterAlarm.WRONG_DEVICE, str(event))
            elif isinstance(event, ev.ConfigurationFailed | ev.BootStepFailed):
                master_alarm(event.node_id, MasterAlarm.CONFIGURATION_FAILED, str(event))
            elif isinstance(event, ev.UnexpectedState):
                master_alarm(event.node_id, MasterAlarm.UNEXPECTED_STATE, str(event))
            elif isinstance(event, ev.StateRestored):
                clear(event.node_id, MasterAlarm.UNEXPECTED_STATE)
            elif isinstance(event, ev.TpdoMissing):
                master_alarm(event.node_id, MasterAlarm.TPDO_MISSING, str(event))
            elif isinstance(event, ev.TpdoRestored):
                clear(event.node_id, MasterAlarm.TPDO_MISSING)
            elif isinstance(event, ev.NetworkStopped):
                master_alarm(None, MasterAlarm.NETWORK_STOPPED, str(event))
            elif isinstance(event, ev.MasterStateChanged) and event.new is MasterState.RUNNING:
                clear(None, MasterAlarm.NETWORK_STOPPED)
            elif isinstance(event, ev.NodeStateChanged):
                if event.new is NodeState.CONFIGURING:  # configured again: judged again
                    clear(event.node_id, MasterAlarm.CONFIGURATION_FAILED)
                if event.new in (NodeState.CONFIGURED, NodeState.OPERATIONAL):
                    clear(event.node_id, *per_node)

        def on_network(event: Any) -> None:
            if not isinstance(event, BusStateChanged):
                return
            if event.new is BusState.BUS_OFF:
                master_alarm(None, MasterAlarm.BUS_OFF, "the controller stopped sending")
            elif event.new is BusState.PASSIVE:
                clear(None, MasterAlarm.BUS_OFF)
                self.raise_alarm(
                    "master",
                    MasterAlarm.ERROR_PASSIVE,
                    text=table_text("master", MasterAlarm.ERROR_PASSIVE),
                    severity=AlarmSeverity.WARNING,
                )
            else:
                clear(None, MasterAlarm.BUS_OFF, MasterAlarm.ERROR_PASSIVE)

        if runner is not None:  # a blocking master: off the loop, in its callback thread
            on_event = runner.callback(on_event)
            on_network = runner.callback(on_network)
        aio.add_listener(on_event)
        aio.network.add_listener(on_network)
        self._detach.append(lambda: aio.remove_listener(on_event))
        self._detach.append(lambda: aio.network.remove_listener(on_network))
        if aio.network.connected and aio.network.bus_state is not BusState.ACTIVE:
            on_network(BusStateChanged(BusState.ACTIVE, aio.network.bus_state))

    def attach_zapi(self, drive: Any) -> None:
        """Raise and clear alarms from a ZAPI adapter (:class:`~cobus.profiles.zapi.
        AsyncZapiDrive` or the blocking one): its alarm byte (source ``zapi``), a lost
        handshake (source ``zapi_check`` code 1) and command/feedback mismatches (codes 11,
        12, 13: A16 main contactor, A18 output, enable), each cleared when it ends."""
        from cobus.profiles import zapi

        runner = getattr(drive, "_runner", None)
        aio = getattr(drive, "aio", drive)
        outputs = {name: 11 + n for n, name in enumerate(zapi.FEEDBACK_OUTPUTS)}

        def on_event(event: Any) -> None:
            node = event.node_id
            if isinstance(event, zapi.AlarmChanged):
                self.set_code("zapi", event.code, node=node)
            elif isinstance(event, zapi.HandshakeLost):
                self.raise_alarm("zapi_check", 1, node=node, text=str(event).split(": ", 1)[1])
            elif isinstance(event, zapi.HandshakeRestored):
                self.clear_alarm("zapi_check", 1, node=node)
            elif isinstance(event, zapi.FeedbackMismatch):
                self.raise_alarm(
                    "zapi_check",
                    outputs.get(event.output, 10),
                    node=node,
                    text=f"{event.output} commanded but not reported back",
                )
            elif isinstance(event, zapi.FeedbackRestored):
                self.clear_alarm("zapi_check", outputs.get(event.output, 10), node=node)

        if runner is not None:
            on_event = runner.callback(on_event)
        aio.add_listener(on_event)
        self._detach.append(lambda: aio.remove_listener(on_event))

    def close(self) -> None:
        """Stop listening to the sources and close the history."""
        for detach in self._detach:
            detach()
        self._detach.clear()
        if self.history is not None:
            self.history.close()
