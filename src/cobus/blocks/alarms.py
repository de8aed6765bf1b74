"""The alarm handler: the set of active alarms, the rotating current alarm, acknowledgement,
and a persistent history — the thesis's generic PLC block, fed by every source cobus has.

Sources:

- an integer code per source, like the ZAPI alarm byte: :meth:`AlarmHandler.set_code` (0
  clears; another code replaces the previous one of that source and node);
- boolean conditions combined by rules into alarm numbers: :meth:`AlarmHandler.add_rule`
  (``"overtemp and not fan_ok or door_open"``) and :meth:`AlarmHandler.set_condition`;
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
import threading
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any, TypeVar

from cobus.blocks.alarm_history import AlarmHistory
from cobus.blocks.alarm_texts import TABLES, MasterAlarm, Severity, table_text
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
    @functools.wraps(method)
    def run(self: AlarmHandler, *args: Any, **kwargs: Any) -> T:
        with self._lock:
            return method(self, *args, **kwargs)

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
    severity: Severity
    raised_at: float
    acknowledged_by: str | None = None
    row: int | None = field(default=None, repr=False)

    @property
    def key(self) -> Key:
        """(source, node, code): what identifies the alarm."""
        return (self.source, self.node, self.code)

    @property
    def acknowledged(self) -> bool:
        """Whether someone acknowledged it."""
        return self.acknowledged_by is not None

    def __str__(self) -> str:
        node = f"node {self.node} " if self.node is not None else ""
        return f"{node}{self.source} {self.code}: {self.text}"


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
    severity: Severity


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


class AlarmHandler:
    """The alarm handler. ``history``: an :class:`AlarmHistory` or a file for one (None:
    no history); ``view_time``: seconds each active alarm is the current one; ``clock``: the
    time the rotation runs on (default: monotonic; a network's ``time`` on the simulated
    clock); ``wall_clock``: the time logged (default: ``time.time``)."""

    def __init__(
        self,
        history: AlarmHistory | str | os.PathLike[str] | None = None,
        *,
        view_time: float = 3.0,
        clock: Callable[[], float] | None = None,
        wall_clock: Callable[[], float] | None = None,
    ) -> None:
        if isinstance(view_time, bool) or not isinstance(view_time, int | float):
            raise ValueError(f"view_time={view_time!r}: seconds above 0")
        if not 0 < view_time < float("inf"):
            raise ValueError(f"view_time={view_time!r}: seconds above 0")
        self.view_time = float(view_time)
        self.clock = clock or time.monotonic
        self.wall_clock = wall_clock or time.time
        if history is not None and not isinstance(history, AlarmHistory):
            history = AlarmHistory(history)
        self.history = history
        self._active: dict[Key, Alarm] = {}
        self._listeners: list[Callable[[AlarmEvent], object]] = []
        self._rules: dict[int, _Rule] = {}
        self._conditions: dict[str, bool] = {}
        self._shown: Key | None = None
        self._since = 0.0
        self._detach: list[Callable[[], None]] = []
        # sources call in from the network's loop or callback thread, a panel reads from
        # its own: every public method holds this lock
        self._lock = threading.RLock()
        if history is not None:
            self._adopt(history)

    def _adopt(self, history: AlarmHistory) -> None:
        """Alarms still active when the program stopped are active again (their sources
        clear them once they report; their history rows go on)."""
        for record in history.query(active=True, newest_first=False):
            try:
                severity = Severity[record.severity.upper()]
            except KeyError:
                severity = Severity.ALARM
            alarm = Alarm(
                record.source,
                record.node,
                record.code,
                record.text,
                severity,
                record.raised_at,
                record.acknowledged_by,
                record.id,
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
        for listener in list(self._listeners):
            try:
                listener(event)
            except Exception:  # a listener's failure must not lose the alarm
                log.exception("alarm listener %r failed", listener)

    # ------------------------------------------------------------------ raise / clear

    @_locked
    def raise_alarm(
        self,
        source: str,
        code: int,
        *,
        node: int | None = None,
        text: str | None = None,
        severity: Severity | None = None,
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
            return alarm
        tab = TABLES.get(table or source)
        if text is None:
            text = tab.text(code) if tab is not None else f"alarm {code}"
        if severity is None:
            severity = tab.severity if tab is not None else Severity.ALARM
        alarm = Alarm(source, node, code, text, Severity(severity), self.wall_clock())
        if self.history is not None:
            alarm.row = self.history.opened(
                source=source,
                node=node,
                code=code,
                text=text,
                severity=alarm.severity.name.lower(),
                at=alarm.raised_at,
            )
        self._active[key] = alarm
        if len(self._active) == 1:
            self._shown, self._since = key, self.clock()
        self._emit(AlarmRaised(alarm))
        return alarm

    @_locked
    def clear_alarm(self, source: str, code: int, *, node: int | None = None) -> bool:
        """The cause of alarm (``source``, ``node``, ``code``) is gone; False if it was not
        active."""
        key = (source, node, code)
        alarm = self._active.get(key)
        if alarm is None:
            return False
        if key == self._shown:
            order = list(self._active)
            following = order[(order.index(key) + 1) % len(order)]
            self._shown = None if following == key else following
            self._since = self.clock()
        del self._active[key]
        if self.history is not None and alarm.row is not None:
            self.history.cleared(alarm.row, self.wall_clock())
        self._emit(AlarmCleared(alarm))
        return True

    @_locked
    def clear_source(self, source: str, *, node: int | None = None) -> int:
        """Clear every active alarm of ``source`` (of ``node`` only, when given)."""
        keys = [k for k in self._active if k[0] == source and (node is None or k[1] == node)]
        for k in keys:
            self.clear_alarm(k[0], k[2], node=k[1])
        return len(keys)

    @_locked
    def set_code(
        self, source: str, code: int, *, node: int | None = None, table: str | None = None
    ) -> None:
        """An integer alarm input (like the ZAPI alarm byte): ``code`` is the one active
        alarm of ``source`` and ``node``; 0 clears it."""
        for key in [k for k in self._active if k[0] == source and k[1] == node]:
            if key[2] != code:
                self.clear_alarm(source, key[2], node=node)
        if code:
            self.raise_alarm(source, code, node=node, table=table)

    # ------------------------------------------------------------------ rules

    @_locked
    def add_rule(
        self,
        number: int,
        when: str,
        *,
        text: str,
        severity: Severity = Severity.ALARM,
    ) -> None:
        """Alarm ``number`` (source ``"rule"``) is active while the conditions ``when``
        holds: names of boolean conditions joined by ``and``, ``or``, ``not`` and brackets,
        e.g. ``"overtemp and not fan_ok or door_open"``. A condition never set is False."""
        if isinstance(number, bool) or not isinstance(number, int):
            raise AlarmRuleError(f"rule number {number!r}: an integer")
        if number in self._rules:
            raise AlarmRuleError(f"there is a rule {number} already ({self._rules[number].text})")
        code, names = _compile_rule(when)
        self._rules[number] = _Rule(number, when, code, names, text, Severity(severity))
        self._evaluate([self._rules[number]])

    def set_condition(self, name: str, value: bool) -> None:
        """Set a boolean condition and re-evaluate the rules that use it."""
        self.set_conditions({name: value})

    @_locked
    def set_conditions(self, values: Mapping[str, bool]) -> None:
        """Set several conditions at once (rules see them together: no alarm flickers on
        between two of them)."""
        changed = set()
        for name, value in values.items():
            if not isinstance(value, bool):
                raise ValueError(f"condition {name!r} = {value!r}: True or False")
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
                self.clear_alarm("rule", rule.number)

    # ------------------------------------------------------------------ state

    @property
    def active(self) -> tuple[Alarm, ...]:
        """The active alarms, oldest first."""
        with self._lock:
            return tuple(self._active.values())

    @_locked
    def current(self) -> Alarm | None:
        """The alarm to show now: each active one in turn for ``view_time`` seconds (in the
        order they were raised), None when none is active."""
        if not self._active:
            self._shown = None
            return None
        now = self.clock()
        order = list(self._active)
        if self._shown not in self._active:
            self._shown, self._since = order[0], now
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
        for target in targets:
            target.acknowledged_by = by
            if self.history is not None and target.row is not None:
                self.history.acknowledged(target.row, self.wall_clock(), by)
            self._emit(AlarmAcknowledged(target))
        return len(targets)

    # ------------------------------------------------------------------ sources

    def attach_master(
        self, master: Any, *, emcy_tables: Mapping[int | str, str] | None = None
    ) -> None:
        """Raise and clear alarms from ``master``'s events (an async
        :class:`~cobus.master.Master` or a blocking one): emergencies (source ``emcy``, cleared
        by the node's EMCY 0000h or its boot-up; text
        from ``emcy_tables[node]`` — a table name per node-ID or node name, e.g. ``{"servo":
        "cia402"}`` —, else CiA 301), and the master's own alarms (source ``master``, codes
        of :class:`~cobus.blocks.alarm_texts.MasterAlarm`)."""
        from cobus.master import events as ev
        from cobus.master.states import NodeState
        from cobus.runtime import BusState, BusStateChanged

        master = getattr(master, "aio", master)  # (a blocking master: its loop's events)

        tables: dict[int, str] = {}
        for key, name in (emcy_tables or {}).items():
            if name not in TABLES:
                raise KeyError(f"no alarm text table {name!r}; the tables: {', '.join(TABLES)}")
            tables[master.node(key).node_id] = name

        def master_alarm(node: int | None, code: MasterAlarm, detail: str) -> None:
            base = table_text("master", code)
            self.raise_alarm("master", int(code), node=node, text=f"{base}: {detail}")

        def on_event(event: Any) -> None:
            if isinstance(event, ev.NodeEmergency):
                if event.code == 0:
                    self.clear_source("emcy", node=event.node_id)
                    return
                table = tables.get(event.node_id)
                text = table_text(table, event.code) if table else event.text
                self.raise_alarm(
                    "emcy", event.code, node=event.node_id, text=f"{text} ({event.code:04X}h)"
                )
            elif isinstance(event, ev.NodeBooted):
                self.clear_source("emcy", node=event.node_id)  # a reset forgets its errors
            elif isinstance(event, ev.NodeMissing):
                master_alarm(event.node_id, MasterAlarm.NODE_MISSING, event.reason)
            elif isinstance(event, ev.ErrorControlLost):
                master_alarm(event.node_id, MasterAlarm.ERROR_CONTROL_LOST, f"{event.kind} lost")
            elif isinstance(event, ev.ErrorControlRestored):
                self.clear_alarm("master", MasterAlarm.ERROR_CONTROL_LOST, node=event.node_id)
            elif isinstance(event, ev.DeviceTypeMismatch | ev.IdentityMismatch):
                master_alarm(event.node_id, MasterAlarm.WRONG_DEVICE, str(event))
            elif isinstance(event, ev.ConfigurationFailed | ev.BootStepFailed):
                master_alarm(event.node_id, MasterAlarm.CONFIGURATION_FAILED, str(event))
            elif isinstance(event, ev.UnexpectedState):
                master_alarm(event.node_id, MasterAlarm.UNEXPECTED_STATE, str(event))
            elif isinstance(event, ev.NodeStateChanged):
                if event.new is NodeState.OPERATIONAL:
                    for code in MasterAlarm:
                        if code < MasterAlarm.BUS_OFF:
                            self.clear_alarm("master", code, node=event.node_id)
                elif event.new is NodeState.CONFIGURED:
                    self.clear_alarm("master", MasterAlarm.NODE_MISSING, node=event.node_id)
                    self.clear_alarm("master", MasterAlarm.WRONG_DEVICE, node=event.node_id)

        def on_network(event: Any) -> None:
            if not isinstance(event, BusStateChanged):
                return
            if event.new is BusState.BUS_OFF:
                master_alarm(None, MasterAlarm.BUS_OFF, "the controller stopped sending")
            elif event.new is BusState.PASSIVE:
                self.clear_alarm("master", MasterAlarm.BUS_OFF)
                self.raise_alarm(
                    "master",
                    MasterAlarm.ERROR_PASSIVE,
                    text=table_text("master", MasterAlarm.ERROR_PASSIVE),
                    severity=Severity.WARNING,
                )
            else:
                self.clear_alarm("master", MasterAlarm.BUS_OFF)
                self.clear_alarm("master", MasterAlarm.ERROR_PASSIVE)

        master.add_listener(on_event)
        master.network.add_listener(on_network)
        self._detach.append(lambda: master.remove_listener(on_event))
        self._detach.append(lambda: master.network.remove_listener(on_network))

    def attach_zapi(self, drive: Any) -> None:
        """Raise and clear alarms from a ZAPI adapter (:class:`~cobus.profiles.zapi.
        AsyncZapiDrive`): its alarm byte (source ``zapi``), a lost handshake and
        command/feedback mismatches (source ``zapi_check``: 1 handshake, 2 feedback)."""
        from cobus.profiles import zapi

        drive = getattr(drive, "aio", drive)

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
                    2,
                    node=node,
                    text=f"{event.output} commanded but not reported back",
                )

        drive.add_listener(on_event)
        self._detach.append(lambda: drive.remove_listener(on_event))

    def close(self) -> None:
        """Stop listening to the sources and close the history."""
        for detach in self._detach:
            detach()
        self._detach.clear()
        if self.history is not None:
            self.history.close()
