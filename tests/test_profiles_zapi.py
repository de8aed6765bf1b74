"""The ZAPI ACE2 adapter against the simulated inverter of the thesis rig, run by the master
on the simulated clock: the handshake held for ten minutes, broken on purpose, acknowledged."""

from __future__ import annotations

import textwrap
from pathlib import Path

import pytest

from cobus.device import export_eds
from cobus.master import BlockingMaster, loads_network
from cobus.profiles.zapi import (
    AlarmChanged,
    FeedbackMismatch,
    HandshakeLost,
    HandshakeRestored,
    ZapiControl,
    ZapiDrive,
    ZapiError,
    ZapiEvent,
    ZapiObjects,
    ZapiStatus,
    alarm_text,
)
from cobus.proto import Frame
from cobus.runtime import Network
from cobus.sim import Rig, start_rig

RIG = """
bus: embedded
devices:
  - {node: 8, kind: zapi_ace2, name: ace2 traction}
"""
NETWORK = """
master: {sync_period: 20}
nodes:
  zapi:
    node_id: 8
    eds: zapi.eds
    mandatory: true
    do_not_initialise: true
    signals:
      alarm: alarm_code
"""


class Bench:
    """The inverter, the master, the adapter, and every RPDO1/TPDO1/SYNC frame with its time."""

    def __init__(self, net: Network, tmp_path: Path) -> None:
        self.net = net
        self.rig = start_rig(net, Rig.loads(RIG))
        (tmp_path / "zapi.eds").write_text(export_eds(self.rig.aio.devices[8].od))
        config = loads_network(textwrap.dedent(NETWORK), base_dir=tmp_path)
        self.master = BlockingMaster(net, config)
        self.frames: list[tuple[float, Frame]] = []
        net.aio.subscribe_all(lambda frame, now: self.frames.append((now, frame)))
        self.master.boot(timeout=5)
        self.zapi = ZapiDrive(self.master, "zapi")
        self.events: list[ZapiEvent] = []
        self.zapi.add_listener(self.events.append)

    def kept(self, since: float) -> int:
        """The whole cycles since ``since`` (SYNC to SYNC), each checked: its last RPDO1
        answered its TPDO1's toggle (AssertionError at the first that did not)."""
        cycles = 0
        tpdo: list[Frame] | None = None  # None: before the first SYNC
        rpdo: list[Frame] = []
        for t, f in self.frames:
            if t < since:
                continue
            if f.cob_id == 0x80:
                if tpdo is not None:
                    assert tpdo and rpdo, f"cycle before {t:.3f} s: TPDO1 {tpdo}, RPDO1 {rpdo}"
                    assert rpdo[-1].data[3] >> 7 != tpdo[0].data[3] >> 7, f"cycle before {t} s"
                    cycles += 1
                tpdo, rpdo = [], []
            elif tpdo is not None and f.cob_id == 0x188:
                tpdo.append(f)
            elif tpdo is not None and f.cob_id == 0x208:
                rpdo.append(f)
        return cycles


def test_run_cw_then_ccw_ten_minutes_then_break_the_handshake(tmp_path: Path) -> None:
    with Network(simulated=True) as net:
        bench = Bench(net, tmp_path)
        zapi = bench.zapi
        inverter = bench.rig.device(8)
        net.sleep(0.2)
        assert zapi.handshake_running and zapi.alarm == 0

        began = net.time()
        zapi.run(50.0)  # clockwise; the inverter's default ramp, 10 Hz/s
        zapi.wait_for_speed(50.0)
        assert net.time() - began == pytest.approx(5.0, abs=0.1)  # 50 Hz at 10 Hz/s
        assert zapi.status & ZapiStatus.A16_MAIN_CONTACTOR and not zapi.status & ZapiStatus.IDLE
        sent = {f.data for t, f in bench.frames if f.cob_id == 0x208 and t >= began}
        assert bytes.fromhex("8813 4A00 000000") in sent  # the thesis's golden RPDO1
        assert bytes.fromhex("8813 4A80 000000") in sent  # ... with the toggle set

        zapi.run(-25.0, ramp=25.0)  # counter-clockwise, 25 Hz/s: 75 Hz to go in 3 s
        reversed_at = net.time()
        zapi.wait_for_speed(-25.0)
        assert net.time() - reversed_at == pytest.approx(3.0, abs=0.1)
        assert zapi.command & ZapiControl.COUNTER_CLOCKWISE
        assert inverter.status()["speed_hz"] == pytest.approx(-25.0)

        held = net.time()
        bench.frames.clear()
        net.sleep(600)  # ten minutes
        assert bench.kept(held) >= 29_990  # every 20 ms cycle answered
        assert zapi.alarm == 0 and inverter.status()["handshake"] == "running"
        assert zapi.speed == pytest.approx(-25.0) and bench.events == []

        zapi.answering = False  # a PLC scan that misses the cycle
        broke = net.time()
        net.sleep(0.3)
        lost = [e for e in bench.events if isinstance(e, HandshakeLost)]
        alarms = [e for e in bench.events if isinstance(e, AlarmChanged)]
        assert alarms and alarms[0].code == 248 and alarms[0].text == "CAN BUS KO"
        assert str(alarms[0]) == "node 8: alarm 248 CAN BUS KO"
        assert lost and lost[0].time - broke <= 0.1
        assert zapi.alarm_text == "CAN BUS KO" and not zapi.handshake_running
        with pytest.raises(ZapiError, match="alarm 248 CAN BUS KO while waiting for 10 Hz"):
            zapi.wait_for_speed(10.0, timeout=0.1)

        zapi.answering = True
        zapi.acknowledge()
        assert zapi.alarm == 0 and zapi.handshake_running
        assert any(isinstance(e, HandshakeRestored) for e in bench.events)
        cleared = [e for e in bench.events if isinstance(e, AlarmChanged) and e.code == 0]
        assert str(cleared[0]) == "node 8: alarm 248 CAN BUS KO cleared"
        zapi.run(10.0)
        zapi.wait_for_speed(10.0)
        assert bench.kept(net.time() - 0.5) > 20

        zapi.stop()  # set-point 0: the inverter ramps down, contactor and enable held
        assert zapi.setpoint == 0.0
        zapi.wait_for_speed(0.0)
        assert zapi.status & ZapiStatus.A16_MAIN_CONTACTOR
        assert not zapi.command & (ZapiControl.CLOCKWISE | ZapiControl.COUNTER_CLOCKWISE)
        assert zapi.command & ZapiControl.A16_MAIN_CONTACTOR
        zapi.release()  # everything off: no direction, no enable, the contactor opens
        assert zapi.command & ~ZapiControl.HANDSHAKE == 0
        net.sleep(0.2)
        assert not zapi.status & ZapiStatus.A16_MAIN_CONTACTOR
        assert inverter.status()["speed_hz"] == 0.0 and zapi.alarm == 0


def test_a_contactor_that_does_not_close_is_reported(tmp_path: Path) -> None:
    with Network(simulated=True) as net:
        bench = Bench(net, tmp_path)
        bench.rig.inject(8, "contactor_failure", active=True)
        bench.zapi.run(20.0)
        net.sleep(0.3)
        mismatches = [e for e in bench.events if isinstance(e, FeedbackMismatch)]
        assert [e.output for e in mismatches] == ["A16 main contactor"]
        assert "A16 main contactor commanded but not reported back for 5 cycles" in str(
            mismatches[0]
        )
        assert bench.zapi.speed == 0


def test_named_outputs_texts_and_what_the_adapter_refuses(tmp_path: Path) -> None:
    assert alarm_text(17) == "LOGIC FAILURE #3" and alarm_text(99) == "ALARM 99"
    assert alarm_text(0) == ""
    with Network(simulated=True) as net:
        bench = Bench(net, tmp_path)
        zapi = bench.zapi
        zapi.set_output("a18_output")
        net.sleep(0.1)
        assert zapi.status & ZapiStatus.A18_OUTPUT
        zapi.set_output(ZapiControl.A18_OUTPUT, False)
        with pytest.raises(ValueError, match="handshake bit is kept by the adapter"):
            zapi.set_output("handshake")
        with pytest.raises(ValueError, match=r"at most 327\.67 Hz"):
            zapi.run(400)
        with pytest.raises(ValueError, match=r"ramp 30 Hz/s: RPDO1 carries 0\.\.25\.5 Hz/s"):
            zapi.run(10, ramp=30)
        with pytest.raises(KeyError):
            zapi.set_output("warp drive")


def test_the_adapter_needs_a_master_and_a_mapped_node(tmp_path: Path) -> None:
    with Network(simulated=True) as net:
        bench = Bench(net, tmp_path)
        with pytest.raises(TypeError, match="runs on a node the master manages"):
            ZapiDrive(net, "zapi")
        listeners = len(bench.master.aio._tpdo_listeners)
        with pytest.raises(ZapiError, match="no TPDO of the network file maps 0x2199"):
            ZapiDrive(bench.master, "zapi", objects=ZapiObjects(statusword=0x2199))
        assert len(bench.master.aio._tpdo_listeners) == listeners
