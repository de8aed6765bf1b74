"""The alarm handler: rotation timing, edge semantics, AND/OR rules, the SQLite history
(queries, CSV, retention, restart, a crash mid-write), and the handler fed by the simulated
thesis rig's faults through the master and the ZAPI adapter on the simulated clock."""

from __future__ import annotations

import csv
import multiprocessing
import os
import signal
import sqlite3
import textwrap
import time
from pathlib import Path
from typing import Any

import pytest

from cobus.blocks.alarm_history import AlarmHistory, AlarmHistoryError
from cobus.blocks.alarm_texts import AlarmSeverity, MasterAlarm, table_text
from cobus.blocks.alarms import (
    AlarmAcknowledged,
    AlarmCleared,
    AlarmEvent,
    AlarmHandler,
    AlarmRaised,
    AlarmRuleError,
)
from cobus.device import export_eds
from cobus.master import BlockingMaster, loads_network
from cobus.profiles import Drive402
from cobus.profiles.zapi import ZapiDrive
from cobus.runtime import Network
from cobus.sim import Rig, start_rig


class Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


EPOCH = 1_750_000_000.0


def handler(tmp_path: Path | None = None, **options: Any) -> tuple[AlarmHandler, Clock]:
    clock = Clock()
    history = None if tmp_path is None else tmp_path / "alarms.db"
    h = AlarmHandler(history, clock=clock, wall_clock=lambda: EPOCH + clock.now, **options)
    return h, clock


def shown(h: AlarmHandler) -> int | None:
    alarm = h.current()
    return None if alarm is None else alarm.code


def test_the_current_alarm_rotates_each_view_time_and_is_none_when_none_is_active() -> None:
    h, clock = handler()
    assert shown(h) is None
    h.raise_alarm("zapi", 17)
    clock.now = 1.0
    h.raise_alarm("zapi", 248, node=8)
    h.raise_alarm("plant", 3, text="door open")
    seen = []
    for t in range(0, 13):
        clock.now = float(t)
        seen.append(shown(h))
    # 17 from 0 s (raised alone), then each for 3 s in the order raised
    assert seen == [17, 17, 17, 248, 248, 248, 3, 3, 3, 17, 17, 17, 248]
    clock.now = 13.5
    h.clear_alarm("zapi", 248, node=8)  # the shown one goes: the next shows at once
    assert shown(h) == 3
    clock.now = 16.4
    assert shown(h) == 3
    clock.now = 16.5
    assert shown(h) == 17
    h.clear_alarm("zapi", 17)
    h.clear_alarm("plant", 3)
    assert shown(h) is None and h.active == ()
    with pytest.raises(ValueError, match="view_time=0"):
        AlarmHandler(view_time=0)


def test_each_activation_and_clearing_is_logged_exactly_once(tmp_path: Path) -> None:
    h, clock = handler(tmp_path)
    events: list[AlarmEvent] = []
    h.add_listener(events.append)
    for _ in range(3):  # the same code every cycle, as a PLC would feed it
        h.set_code("zapi", 17, node=8)
        clock.now += 0.02
    clock.now = 5.0
    h.set_code("zapi", 248, node=8)  # replaces 17
    h.set_code("zapi", 248, node=8)
    clock.now = 9.0
    assert h.acknowledge(by="anna") == 1 and h.acknowledge(by="bob") == 0
    h.set_code("zapi", 0, node=8)
    h.set_code("zapi", 0, node=8)
    assert not h.clear_alarm("zapi", 248, node=8)
    rows = h.history.query(newest_first=False) if h.history else []
    assert [(r.code, r.raised_at - EPOCH, r.cleared_at) for r in rows] == [
        (17, 0.0, EPOCH + 5.0),
        (248, 5.0, EPOCH + 9.0),
    ]
    assert rows[0].text == "LOGIC FAILURE #3" and rows[1].text == "CAN BUS KO"
    assert rows[1].acknowledged_by == "anna" and rows[0].acknowledged_by is None
    assert [type(e) for e in events] == [
        AlarmRaised,
        AlarmCleared,
        AlarmRaised,
        AlarmAcknowledged,
        AlarmCleared,
    ]
    h.close()


def test_rules_combine_conditions_with_and_or_not() -> None:
    h, _ = handler()
    h.add_rule(101, "overtemp and not fan_ok or door_open", text="cabinet too hot")
    h.add_rule(102, "estop", text="emergency stop", severity=AlarmSeverity.WARNING)
    assert h.active == ()
    h.set_conditions({"overtemp": True, "fan_ok": True})
    assert h.active == ()
    h.set_condition("fan_ok", False)
    assert [(a.source, a.code, a.text) for a in h.active] == [("rule", 101, "cabinet too hot")]
    h.set_conditions({"overtemp": False, "door_open": True})  # together: no flicker
    assert [a.code for a in h.active] == [101]
    h.set_condition("door_open", False)
    h.set_condition("estop", True)
    assert [(a.code, a.severity) for a in h.active] == [(102, AlarmSeverity.WARNING)]
    for bad, reason in (
        ("", "write conditions"),
        ("a and", "does not read"),
        ("__import__('os')", "only condition names"),
        ("a.b", "only condition names"),
        ("a == b", "only condition names"),
    ):
        with pytest.raises(AlarmRuleError, match=reason):
            h.add_rule(200, bad, text="x")
    with pytest.raises(AlarmRuleError, match="there is a rule 101 already"):
        h.add_rule(101, "x", text="again")
    with pytest.raises(ValueError, match="True or False"):
        h.set_condition("estop", 1)  # type: ignore[arg-type]


def test_codes_show_their_text_or_at_least_their_number_and_class() -> None:
    assert table_text("zapi", 17) == "LOGIC FAILURE #3"
    assert table_text("zapi", 99) == "ALARM 99"
    assert table_text("cia402", 0x7121) == "Motor blocked"
    assert table_text("cia402", 0x4399) == "Temperature (4399h)"
    assert table_text("cia301", 0x8130) == "Life guard error or heartbeat error"
    assert table_text("cia301", 0x4399) == "Temperature (4399h)"
    assert table_text("stober", 33) == "overcurrent"
    assert table_text("stober", 99) == "E82 event 99"
    assert table_text("ecmotor", 9) == "max current"
    assert table_text("ecmotor", 20) == "m_sss bit 20"
    assert table_text("master", MasterAlarm.BUS_OFF) == "CAN bus-off"
    with pytest.raises(KeyError, match="no alarm text table 'acme'"):
        table_text("acme", 1)
    h, _ = handler()
    assert h.raise_alarm("plant", 7).text == "alarm 7"


def test_history_queries_csv_and_retention(tmp_path: Path) -> None:
    with AlarmHistory(tmp_path / "h.db", max_rows=3) as history:
        rows = []
        for n in range(6):
            rows.append(
                history.opened(
                    source="emcy",
                    node=n % 2 + 1,
                    code=0x1000 + n,
                    text=f"e{n}",
                    severity="alarm",
                    at=EPOCH + n,
                )
            )
            if n != 0:
                history.cleared(rows[-1], EPOCH + n + 0.5)
        history.cleared(rows[1], EPOCH + 99)  # a second clearing changes nothing
        # the first is still active: never pruned; of the cleared, the newest 3 are kept
        assert [r.code for r in history.query(newest_first=False)] == [
            0x1000,
            0x1003,
            0x1004,
            0x1005,
        ]
        assert [r.code for r in history.query(node=2)] == [0x1005, 0x1003]
        assert [r.code for r in history.query(since=EPOCH + 3, until=EPOCH + 5)] == [
            0x1004,
            0x1003,
        ]
        assert [r.code for r in history.query(active=True)] == [0x1000]
        assert [r.code for r in history.query(code=0x1004, source="emcy")] == [0x1004]
        assert len(history) == 4 and history.check() == "ok"
        count = history.export_csv(tmp_path / "h.csv", node=2)
        lines = list(csv.reader((tmp_path / "h.csv").open()))
        assert count == 2 and lines[0][:3] == ["raised", "cleared", "node"]
        assert lines[1][2:6] == ["2", "emcy", str(0x1003), "e3"]
        assert lines[1][0].endswith("+00:00")
    with AlarmHistory(tmp_path / "age.db", max_rows=None, max_age=10) as history:
        old = history.opened(source="s", node=None, code=1, text="t", severity="info", at=0.0)
        history.cleared(old, 1.0)
        history.opened(source="s", node=None, code=2, text="t", severity="info", at=100.0)
        assert [r.code for r in history] == [2]


def test_a_restart_keeps_the_history_and_the_active_alarms(tmp_path: Path) -> None:
    h, clock = handler(tmp_path)
    h.raise_alarm("zapi", 17, node=8)
    h.raise_alarm("plant", 5, text="low air pressure", severity=AlarmSeverity.WARNING)
    h.acknowledge(by="anna")
    h.close()
    again, clock = handler(tmp_path)  # the program starts again
    assert [(a.code, a.acknowledged_by, a.severity) for a in again.active] == [
        (17, "anna", AlarmSeverity.ALARM),
        (5, "anna", AlarmSeverity.WARNING),
    ]
    again.set_code("zapi", 17, node=8)  # the source reports it again: no new row
    clock.now = 4.0
    again.set_code("zapi", 0, node=8)
    assert again.history is not None
    rows = again.history.query(newest_first=False)
    assert [(r.code, r.cleared_at) for r in rows] == [(17, EPOCH + 4.0), (5, None)]
    again.close()


def _write_alarms(path: str, done: Any) -> None:
    history = AlarmHistory(path)
    n = 0
    while True:
        row = history.opened(
            source="soak", node=1, code=n, text="x" * 200, severity="alarm", at=float(n)
        )
        history.cleared(row, n + 0.5)
        n += 1
        done.value = n


def test_a_crash_mid_write_loses_nothing_committed(tmp_path: Path) -> None:
    path = str(tmp_path / "crash.db")
    ctx = multiprocessing.get_context("fork")
    done = ctx.Value("i", 0)
    child = ctx.Process(target=_write_alarms, args=(path, done))
    child.start()
    deadline = time.monotonic() + 20
    while done.value < 200 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert child.pid is not None
    os.kill(child.pid, signal.SIGKILL)  # mid-write, most likely
    child.join()
    reported = done.value
    assert reported >= 200
    with AlarmHistory(path) as history:
        assert history.check() == "ok"
        rows = history.query(newest_first=False)
        assert len(rows) >= reported  # every committed activation is there
        assert [r.code for r in rows] == list(range(len(rows)))
        assert all(r.cleared_at == r.code + 0.5 for r in rows[:reported])


def test_a_file_that_is_no_alarm_history_is_refused(tmp_path: Path) -> None:
    (tmp_path / "text.db").write_text("hello " * 1000)
    with pytest.raises(AlarmHistoryError, match="is not an alarm history database"):
        AlarmHistory(tmp_path / "text.db")
    other = sqlite3.connect(tmp_path / "other.db")
    other.execute("CREATE TABLE customers (name TEXT)")
    other.commit()
    other.close()
    with pytest.raises(AlarmHistoryError, match="tables of another program"):
        AlarmHistory(tmp_path / "other.db")
    with pytest.raises(ValueError, match="max_rows=0"):
        AlarmHistory(tmp_path / "x.db", max_rows=0)


RIG = """
bus: embedded
devices:
  - {node: 8, kind: zapi_ace2, name: ace2 traction}
  - {node: 10, kind: cia402_drive, name: servo}
"""
NETWORK = """
master: {node_id: 1, sync_period: 20}
nodes:
  zapi: {node_id: 8, eds: zapi.eds, mandatory: true, do_not_initialise: true}
  servo: {node_id: 10, eds: servo.eds, mandatory: false, heartbeat_time: 100}
"""


def test_the_handler_fed_by_the_thesis_rig_through_master_and_zapi_adapter(
    tmp_path: Path,
) -> None:
    with Network(simulated=True) as net:
        rig = start_rig(net, Rig.loads(RIG))
        (tmp_path / "zapi.eds").write_text(export_eds(rig.aio.devices[8].od))
        (tmp_path / "servo.eds").write_text(export_eds(rig.aio.devices[10].od))
        master = BlockingMaster(net, loads_network(textwrap.dedent(NETWORK), base_dir=tmp_path))
        master.boot(timeout=10)
        zapi = ZapiDrive(master, "zapi")
        alarms = AlarmHandler(
            tmp_path / "alarms.db", clock=net.time, wall_clock=lambda: EPOCH + net.time()
        )
        alarms.attach_master(master, emcy_tables={"servo": "cia402"})
        alarms.attach_zapi(zapi)
        net.sleep(0.5)
        assert alarms.active == () and alarms.current() is None

        rig.inject(8, "alarm", code=17)  # the inverter's LOGIC FAILURE #3
        net.sleep(0.2)
        rig.inject(10, "drive_fault", code=0x7121)  # the servo: motor blocked
        net.sleep(0.2)
        texts = [str(a) for a in alarms.active]
        assert texts == [
            "node 8 zapi 17: LOGIC FAILURE #3",
            # the alarm drops the inverter to pre-operational: its TPDO1 stops
            "node 8 zapi_check 1: handshake lost (no TPDO1 for 60 ms)",
            "node 8 master 7: TPDO missing: TPDO 1 (0x188) missing",
            "node 10 emcy 7121h: Motor blocked",
        ]
        first = alarms.current()
        net.sleep(3.0)
        assert alarms.current() is not first  # rotated after view_time

        Drive402(master, "servo").fault_reset()  # EMCY 0000h clears the node's emergencies
        net.sleep(0.2)
        assert [a.source for a in alarms.active] == ["zapi", "zapi_check", "master"]
        zapi.acknowledge()
        net.sleep(0.5)
        assert alarms.active == ()  # the inverter runs again: its TPDO1 is back

        rig.inject(10, "drive_fault", code=0x2310)
        net.sleep(0.2)
        assert [a.code for a in alarms.active] == [0x2310]
        rig.inject(10, "power_loss")  # heartbeat lost: the master's alarm
        net.sleep(0.5)
        lost = [a for a in alarms.active if a.source == "master"]
        assert sorted((a.node, a.code) for a in lost) == [
            (10, MasterAlarm.ERROR_CONTROL_LOST),
            (10, MasterAlarm.TPDO_MISSING),
        ]
        lost_texts = {a.text for a in lost}
        assert "heartbeat or node guarding lost: heartbeat lost" in lost_texts
        rig.inject(10, "power_return")
        net.sleep(5)
        # operational again; the boot-up voided the emergency of before the power loss
        assert alarms.active == () and alarms.current() is None
        assert alarms.history is not None
        rows = alarms.history.query(newest_first=False)
        keys = [(r.source, r.node, r.code) for r in rows]
        assert keys.count(("zapi", 8, 17)) == 1 and keys.count(("emcy", 10, 0x7121)) == 1
        assert keys.count(("master", 10, MasterAlarm.ERROR_CONTROL_LOST)) == 1
        assert all(r.cleared_at is not None for r in rows)
        alarms.close()
        master.stop()


class FakeNetwork:
    connected = False

    def __init__(self) -> None:
        self.listeners: list[Any] = []

    def add_listener(self, listener: Any) -> None:
        self.listeners.append(listener)

    def remove_listener(self, listener: Any) -> None:
        self.listeners.remove(listener)


class FakeMaster:
    """What attach_master uses of a master: its listeners and nodes by name."""

    def __init__(self) -> None:
        self.network = FakeNetwork()
        self.listeners: list[Any] = []

    def node(self, key: int | str) -> Any:
        return type("Node", (), {"node_id": 10 if key == "servo" else key})()

    def add_listener(self, listener: Any) -> None:
        self.listeners.append(listener)

    def remove_listener(self, listener: Any) -> None:
        self.listeners.remove(listener)

    def emit(self, event: Any) -> None:
        for listener in self.listeners:
            listener(event)


def test_emcy_error_reset_clears_what_the_register_no_longer_shows() -> None:
    from cobus.master import NodeEmergency, StateRestored, UnexpectedState
    from cobus.proto.nmt import NmtState

    h, _ = handler()
    master = FakeMaster()
    h.attach_master(master, emcy_tables={"servo": "cia402", 11: "stober"})
    master.emit(NodeEmergency(10, 0x2310, 0x03, b"", "Current"))
    master.emit(NodeEmergency(10, 0x4310, 0x0B, b"", "Temperature"))
    master.emit(NodeEmergency(11, 0x2310, 0x03, b"", "Current"))
    assert [str(a) for a in h.active] == [
        "node 10 emcy 2310h: Continuous over-current",
        "node 10 emcy 4310h: Excess temperature drive (motor over-temperature)",
        "node 11 emcy 2310h: overcurrent (E82 33)",
    ]
    master.emit(NodeEmergency(10, 0x0000, 0x09, b"", "reset"))  # the temperature bit stays
    assert [a.code for a in h.select(node=10)] == [0x4310]
    master.emit(NodeEmergency(10, 0x0001, 0x00, b"", "reset"))  # 00xxh: all gone
    assert h.select(node=10) == ()
    master.emit(UnexpectedState(12, NmtState.OPERATIONAL, NmtState.PRE_OPERATIONAL))
    assert [a.code for a in h.select(node=12)] == [MasterAlarm.UNEXPECTED_STATE]
    master.emit(StateRestored(12, NmtState.OPERATIONAL))
    assert h.select(node=12) == ()
    with pytest.raises(KeyError, match="does not name EMCY codes"):
        h.attach_master(master, emcy_tables={"servo": "zapi"})
    h.close()
    assert master.listeners == [] and master.network.listeners == []


def test_listeners_run_outside_the_lock_and_see_events_in_order() -> None:
    h, _ = handler()
    seen: list[str] = []

    def first(event: AlarmEvent) -> None:
        seen.append(f"first {type(event).__name__}")
        if isinstance(event, AlarmRaised) and event.alarm.code == 1:
            h.clear_alarm("plant", 1)  # a listener calling back into the handler

    h.add_listener(first)
    h.add_listener(lambda e: seen.append(f"second {type(e).__name__}"))
    h.raise_alarm("plant", 1)
    assert seen == [
        "first AlarmRaised",
        "second AlarmRaised",
        "first AlarmCleared",
        "second AlarmCleared",
    ]


def test_a_broken_history_loses_no_alarm_and_says_so(tmp_path: Path) -> None:
    h, _ = handler(tmp_path)
    events: list[AlarmEvent] = []
    h.add_listener(events.append)
    assert h.history is not None
    h.history.close()  # the file goes away under the handler
    h.raise_alarm("zapi", 17, node=8)
    assert [(a.source, a.code) for a in h.active] == [("zapi", 17), ("history", 1)]
    assert h.history_problem is not None and "cannot be written" in h.history_problem
    assert h.active[1].severity is AlarmSeverity.WARNING
    assert h.clear_alarm("zapi", 17, node=8)
    assert [type(e) for e in events] == [AlarmRaised, AlarmRaised, AlarmCleared]


def test_adopted_alarms_stay_only_if_their_source_confirms_them(tmp_path: Path) -> None:
    h, _ = handler(tmp_path)
    h.raise_alarm("zapi", 17, node=8)
    h.raise_alarm("master", MasterAlarm.BUS_OFF)
    h.close()
    again, clock = handler(tmp_path, adopt_grace=5.0)
    assert len(again.active) == 2 and all(a.adopted for a in again.active)
    again.set_code("zapi", 17, node=8)  # confirmed
    clock.now = 6.0
    assert [(a.source, a.adopted) for a in again.active] == [("zapi", False)]
    assert again.history is not None
    rows = again.history.query(newest_first=False)
    assert [r.cleared_at for r in rows] == [None, EPOCH + 6.0]  # the bus-off: cleared, logged
    again.close()


def test_odd_inputs() -> None:
    h, clock = handler()
    h.set_code("stober", 33, node=5)
    assert h.active[0].text == "overcurrent"
    h.set_code("stober", 30, node=5)  # E82 30: no event
    assert h.active == ()
    h.add_rule(1, "a", text="a")
    with pytest.raises(ValueError, match="True or False"):
        h.set_conditions({"a": True, "b": 1})
    assert h.conditions == {} and h.active == ()  # nothing half-set
    h.raise_alarm("p", 1, severity="warning")
    h.raise_alarm("p", 2, severity=AlarmSeverity.ALARM)
    clock.now = 100.0
    assert shown(h) == 2  # (2 of 1, 2 after 100 s)
    clock.now = 10.0  # the clock set back: rotation goes on from there
    assert shown(h) == 2
    clock.now = 13.0
    assert shown(h) == 1
    assert h.highest_severity is AlarmSeverity.ALARM and h.unacknowledged == 2
    assert [a.code for a in h.select(min_severity="alarm")] == [2]
    with pytest.raises(ValueError, match="severity 'loud'"):
        h.raise_alarm("p", 3, severity="loud")


def test_the_command_line_shows_and_exports_a_history(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    import json

    from cobus.cli import main

    monkeypatch.setenv("COLUMNS", "200")  # a wide terminal: rich wraps nothing
    h, clock = handler(tmp_path)
    h.raise_alarm("zapi", 17, node=8)
    clock.now = 60.0
    h.raise_alarm("emcy", 0x7121, node=10, text="Motor blocked")
    h.set_code("zapi", 0, node=8)
    h.close()
    db = str(tmp_path / "alarms.db")
    assert main(["alarms", "show", db]) == 0
    out = capsys.readouterr().out
    assert "LOGIC FAILURE #3" in out and "7121h" in out and "Motor blocked" in out
    assert main(["alarms", "show", db, "--node", "10", "--active", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [(r["node"], r["code"], r["cleared_at"]) for r in rows] == [(10, 0x7121, None)]
    assert main(["alarms", "show", db, "--code", "7121h", "--json"]) == 0
    assert len(json.loads(capsys.readouterr().out)) == 1
    assert main(["alarms", "export", db, str(tmp_path / "out.csv"), "--source", "zapi"]) == 0
    assert (tmp_path / "out.csv").read_text().count("\n") == 2
    assert main(["alarms", "show", str(tmp_path / "none.db")]) == 1
    (tmp_path / "junk.db").write_text("junk" * 500)
    assert main(["alarms", "show", str(tmp_path / "junk.db")]) == 1
    assert "not an alarm history database" in capsys.readouterr().err


def test_a_command_not_reported_back_for_some_cycles_is_an_alarm() -> None:
    h, _ = handler()
    seen = []
    for commanded, reported in [(1, 0), (1, 0), (1, 0), (1, 0), (1, 1), (1, 0), (0, 0)]:
        seen.append(
            h.check_feedback("A16", bool(commanded), bool(reported), code=16, node=8, cycles=3)
        )
    assert seen == [False, False, True, True, False, False, False]
    assert h.history is None
    with pytest.raises(ValueError, match="cycles=0"):
        h.check_feedback("A16", True, False, code=16, cycles=0)


def _damaged_copies(tmp_path: Path, runs: int) -> list[Path]:
    """Copies of a history of 400 rows, each with one byte flipped past the file header."""
    import random

    source = tmp_path / "sound.db"
    with AlarmHistory(source) as history:
        for n in range(400):
            row = history.opened(
                source="zapi", node=8, code=n, text=f"alarm {n} " * 5, severity="alarm", at=n
            )
            history.cleared(row, n + 0.5)
    data = source.read_bytes()
    rng = random.Random(39)
    copies = []
    for n in range(runs):
        damaged = bytearray(data)
        damaged[rng.randrange(100, len(data))] ^= 1 << rng.randrange(8)
        path = tmp_path / f"damaged-{n}.db"
        path.write_bytes(bytes(damaged))
        copies.append(path)
    return copies


def test_a_damaged_history_never_raises_anything_but_its_own_error(tmp_path: Path) -> None:
    """A flipped byte made query() raise sqlite3's OperationalError / DatabaseError (24 of
    48 runs); now AlarmHistoryError, and a damaged file is refused when it opens."""
    refused = 0
    for path in _damaged_copies(tmp_path, 48):
        try:
            with AlarmHistory(path) as history:
                history.query()
                len(history)
                history.export_csv(tmp_path / "out.csv")
                history.opened(source="x", node=None, code=1, text="t", severity="alarm", at=1)
        except AlarmHistoryError:
            refused += 1
    assert refused > 0  # (the integrity check finds what queries would trip on)


def test_the_handler_starts_on_a_damaged_history_moving_it_aside(tmp_path: Path) -> None:
    from cobus.blocks.alarm_history import AlarmHistoryDamagedError

    moved = 0
    for path in _damaged_copies(tmp_path, 48):
        damaged = path.read_bytes()
        try:
            AlarmHistory(path).close()
            was_damaged = False
        except AlarmHistoryDamagedError:
            was_damaged = True
        h = AlarmHandler(path)  # never raises: the application starts
        h.raise_alarm("zapi", 17, node=8)
        assert h.history is not None and h.history_problem is None
        if was_damaged:
            moved += 1
            assert h.history_moved is not None and h.history_moved.read_bytes() == damaged
            assert h.history_moved.name.startswith(f"{path.name}.damaged-")
            (warning,) = [a for a in h.active if a.source == "history"]
            assert warning.code == 2 and warning.severity is AlarmSeverity.WARNING
            assert "was damaged (" in warning.text and h.history_moved.name in warning.text
            assert [r.code for r in h.history.query()] == [17]  # a new file
        else:
            assert h.history_moved is None
        h.close()
    assert moved > 0


def test_the_command_line_says_a_history_is_damaged_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from cobus.cli import main

    for path in _damaged_copies(tmp_path, 24):
        for words in (["show", str(path)], ["export", str(path), str(tmp_path / "x.csv")]):
            status = main(["alarms", *words])
            err = capsys.readouterr().err
            assert status in (0, 1)
            assert "Traceback" not in err
            if status == 1:
                assert len(err.strip().splitlines()) == 1 and "is damaged" in err


def test_another_programs_damaged_database_is_never_moved_aside(tmp_path: Path) -> None:
    other = tmp_path / "other.db"
    db = sqlite3.connect(other)
    db.execute("CREATE TABLE customers (name TEXT)")
    db.executemany("INSERT INTO customers VALUES (?)", [("x" * 200,)] * 200)
    db.commit()
    db.close()
    data = bytearray(other.read_bytes())
    data[len(data) // 2] ^= 0xFF  # damaged in a data page
    other.write_bytes(bytes(data))
    with pytest.raises(AlarmHistoryError, match="tables of another program"):
        AlarmHandler(other)
    assert other.read_bytes() == bytes(data) and list(tmp_path.iterdir()) == [other]


def test_a_damaged_history_that_cannot_be_moved_leaves_the_handler_without_one(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import cobus.blocks.alarms as alarms

    path = _damaged_copies(tmp_path, 48)
    damaged = next(p for p in path if _is_damaged(p))

    def refuse(target: Path) -> Path:
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(alarms, "_move_aside", refuse)
    h = AlarmHandler(damaged)  # the application still starts
    assert h.history is None and h.history_moved is None
    (warning,) = h.active
    assert "cannot be moved aside (Permission denied): no history kept" in warning.text
    h.raise_alarm("zapi", 17, node=8)  # alarms still work, in memory
    assert len(h.active) == 2


def _is_damaged(path: Path) -> bool:
    from cobus.blocks.alarm_history import AlarmHistoryDamagedError

    try:
        AlarmHistory(path).close()
    except AlarmHistoryDamagedError:
        return True
    return False


def test_a_damaged_text_in_a_history_reads_with_a_replacement_character(
    tmp_path: Path,
) -> None:
    """sqlite3 decodes texts (and SQLite's messages, which quote a damaged schema) as UTF-8:
    a flipped byte there raised UnicodeDecodeError from AlarmHistory (make fuzz found it)."""
    path = tmp_path / "alarms.db"
    with AlarmHistory(path) as history:
        history.opened(source="zapi", node=8, code=1, text="é" * 50, severity="alarm", at=1.0)
    data = bytearray(path.read_bytes())
    at = data.rindex("é".encode())
    data[at] = 0xFF  # no UTF-8 starts so
    path.write_bytes(bytes(data))
    with AlarmHistory(path) as history:  # (the structure is sound: quick_check passes)
        (record,) = history.query()
        assert "\ufffd" in record.text  # read, the damaged character replaced


def test_a_history_whose_header_magic_is_damaged_is_moved_aside_not_refused(
    tmp_path: Path,
) -> None:
    """make fuzz: a flipped byte in "SQLite format 3" made the handler refuse the file as
    another program's (the application died at start)."""
    path = tmp_path / "alarms.db"
    with AlarmHistory(path) as history:
        history.opened(source="zapi", node=8, code=1, text="t", severity="alarm", at=1.0)
    data = bytearray(path.read_bytes())
    data[3] ^= 0x01  # "SQLite" -> "SQLhte"
    path.write_bytes(bytes(data))
    h = AlarmHandler(path)
    assert h.history_moved is not None and h.history is not None
    h.close()
    (tmp_path / "text.db").write_text("hello " * 1000)  # a text file is still refused
    with pytest.raises(AlarmHistoryError, match="is not an alarm history database"):
        AlarmHandler(tmp_path / "text.db")
