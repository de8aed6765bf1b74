"""The document devices driven by the cobus master the way their documents' masters do it
(issue 6: "a scenario test driven by the master"), on the simulated clock:

- the ZAPI ACE2 of the thesis (seed 000): no boot-up, no error control, SYNC before start,
  the toggle handshake answered every cycle through the process image, a broken handshake
  (alarm 248 in TPDO2), acknowledge by controlword 2.4;
- the STÖBER MDS 5000 (seed 004): booted the CiA 302 way (reset, 1000h/1018h, start-up list
  with parameters by group and a direct PDO mapping, node guarding), run through the process
  image, motor over-temperature seen as EMCY with its E82 event, acknowledged, and the drive's
  life guarding when the master stops guarding;
- the EC motor (seed 002): no CiA SDO server, so not initialised; polled by an empty RPDO1
  every SYNC, its status in the process image, an overload trip recorded as EMCY with the
  motor's own layout; what the master cannot do with it is pinned down at the end.

Then what these scenarios needed, each on its own: from the master SYNC before the first NMT
start, TPDO listeners and ``send_rpdo``, direct PDO mapping, nodes without an SDO server and
RPDOs with an empty mapping; from the STÖBER simulator a fault that outlasts an NMT reset node,
reported again.
"""

from __future__ import annotations

import itertools
import struct
import textwrap
from pathlib import Path

import pytest

from cobus.device import export_eds
from cobus.master import (
    Diagnostic,
    MasterState,
    MasterValueError,
    NetworkConfig,
    NetworkConfigError,
    NodeEmergency,
    NodeState,
    TpdoMissing,
    loads_network,
)
from cobus.profiles.zapi import AsyncZapiDrive
from cobus.proto import Frame
from cobus.proto.nmt import NmtState
from cobus.proto.sdo import SdoTimeoutError
from cobus.runtime import AsyncNetwork, HandlerFailed
from cobus.sim.ecmotor import EcMotor
from cobus.sim.stober import EVENTS, StoberMds5000
from cobus.sim.zapi import ZapiAce2
from tests.test_master_support import (
    Rig,
    diagnostic,
    master_state,
    network,
    nmt,
    rig_test,
    state,
)
from tests.util import simulate


def frames_of(rig: Rig, cob_id: int, since: float = -1.0) -> list[Frame]:
    return [f for _, f in rig.on(cob_id, since=since)]


def first(rig: Rig, cob_id: int, data: bytes | None = None) -> float:
    """When the first frame on ``cob_id`` (with ``data``) went over the bus."""
    return next(t for t, f in rig.on(cob_id) if data is None or f.data == data)


def sim_state(sim: ZapiAce2 | StoberMds5000) -> NmtState | None:
    """The device's NMT state (a function: mypy would narrow a property after one check)."""
    return sim.state if isinstance(sim, ZapiAce2) else sim.nmt_state


def place(rig: Rig, cob_id: int, data: bytes | None = None) -> int:
    """Where the first frame on ``cob_id`` (with ``data``) is in the bus order."""
    return next(
        n
        for n, (_, f) in enumerate(rig.frames)
        if f.cob_id == cob_id and (data is None or f.data == data)
    )


# ================================================================================ ZAPI ACE2
ZAPI = 8
ACK = 1 << 4  # controlword byte 2 bit 4: fault acknowledge
SW_A16, SW_ENABLED, SW_IDLE = 1 << 1, 1 << 3, 1 << 14

ZAPI_NETWORK = """
    master: {sync_period: 20}          # the PLC's CANopen module: SYNC every 20 ms
    nodes:
      zapi:
        node_id: 8
        eds: zapi.eds                  # the hand-made EDS of the thesis (here: exported)
        mandatory: true
        do_not_initialise: true        # no boot-up: no reset, no configuration
        # no heartbeat_time / guard_time: the controller answers neither
        signals:
          speed_setpoint: {object: speed_setpoint, scale: 0.01, unit: Hz}
          speed: {object: actual_speed, scale: 0.01, unit: Hz}
          alarm: alarm_code
"""


def handshake_kept(rig: Rig, since: float, until: float) -> bool:
    """Whether every TPDO1 in [since, until) was answered by RPDO1 with the opposite toggle
    before the next SYNC (the last RPDO1 of each cycle counts)."""
    syncs = [t for t, _ in rig.on(0x80) if since <= t < until]
    for begin, end in itertools.pairwise(syncs):
        tpdo = [f for t, f in rig.on(0x188) if begin <= t < end]
        rpdo = [f for t, f in rig.on(0x208) if begin <= t < end]
        if not tpdo or not rpdo or rpdo[-1].data[3] >> 7 == tpdo[0].data[3] >> 7:
            return False
    return len(syncs) > 2


def test_zapi_ace2_run_by_the_master(tmp_path: Path) -> None:
    """SYNC 20 ms, start, the handshake answered every cycle, 50 Hz clockwise reached; the
    handshake breaks: alarm 248 in TPDO2 and TPDO1 missing; acknowledge (controlword 2.4) and
    restart: running again."""

    async def main() -> None:
        async with AsyncNetwork() as net:
            zapi = ZapiAce2(net, ZAPI)
            (tmp_path / "zapi.eds").write_text(export_eds(zapi.od))
            config = loads_network(textwrap.dedent(ZAPI_NETWORK), base_dir=tmp_path)
            rig = Rig(net, config)
            master = rig.master
            node = master.nodes[ZAPI]
            plc = AsyncZapiDrive(master, "zapi")  # the thesis's RPDO/TPDO processing block
            zapi.start()
            try:
                # -- boot: 1000h read, SYNC running, then the start
                await master.boot(timeout=5)
                assert sim_state(zapi) is NmtState.OPERATIONAL and zapi.alarm == 0
                assert state(node) is NodeState.OPERATIONAL and node.error_control is None
                assert rig.data(0x000) == [b"\x01\x08"]  # no reset: do_not_initialise
                assert frames_of(rig, 0x608)[0].data[:4] == bytes.fromhex("40001000")
                assert place(rig, 0x80) < place(rig, 0x000, b"\x01\x08")  # SYNC runs first
                await net.sleep(0.5)
                assert zapi.status()["handshake"] == "running" and zapi.alarm == 0
                byte3 = [f.data[3] for f in frames_of(rig, 0x188)]
                assert byte3[:4] == [0x44, 0xC4, 0x44, 0xC4]  # the thesis's 44h / C4h
                assert handshake_kept(rig, first(rig, 0x188), net.time())
                assert plc.cycles >= 20

                # -- run at 50 Hz clockwise (default ramp 10 Hz/s)
                plc.run(50.0)  # A16, enable, clockwise
                began = net.time()
                await net.sleep(5.5)
                assert master.inputs["zapi.speed"] == 50.0
                status = master.inputs["zapi.statusword"]
                assert status & (SW_A16 | SW_ENABLED) == SW_A16 | SW_ENABLED
                assert not status & SW_IDLE
                sent = {f.data for f in frames_of(rig, 0x208, since=began)}
                assert bytes.fromhex("8813 4A00 000000") in sent  # the thesis's golden RPDO1
                assert bytes.fromhex("8813 4A80 000000") in sent  # ... with the toggle set
                assert handshake_kept(rig, began, net.time())
                assert master.inputs["zapi.alarm"] == 0

                # -- the handshake breaks (a PLC scan longer than 20 ms)
                plc.answering = False
                broke = net.time()
                await net.sleep(0.2)
                assert sim_state(zapi) is NmtState.PRE_OPERATIONAL  # a fault drops it to pre-op
                assert master.inputs["zapi.alarm"] == 248  # "CAN BUS KO", by TPDO2
                assert frames_of(rig, 0x288, since=broke)[0].data[0] == 248
                assert rig.of(TpdoMissing) == [TpdoMissing(ZAPI, 1, 0x188)]
                assert diagnostic(node) is Diagnostic.TPDO_MISSING
                assert master.inputs["zapi.speed"] == 0.0  # inputs of the missing TPDO: 0
                # without error control the master cannot see the NMT state: it still
                # counts the node started; the missing TPDO1 is what tells
                assert state(node) is NodeState.OPERATIONAL
                # in pre-operational the thesis's PLC reads the alarm by SDO
                assert (await node.sdo.read(0x2110)) == 248

                # -- acknowledge: the run bits released, start again, controlword 2.4
                plc.answering = True
                acked = net.time()
                await plc.acknowledge()  # controlword 2.4, run bits released, NMT start
                await net.sleep(0.2)
                assert rig.data(0x000, since=acked) == [b"\x01\x08"]
                # 2.4 acts on its rising edge: off in the first cycle after the start, then on
                acks = [f.data[2] & ACK for f in frames_of(rig, 0x208, since=acked)]
                assert acks[0] == 0 and ACK in acks
                assert sim_state(zapi) is NmtState.OPERATIONAL and zapi.alarm == 0
                assert master.inputs["zapi.alarm"] == 0  # TPDO2 at once on the change
                # the restart cleared the fault: TPDO1 is supervised and taken again
                assert diagnostic(node) is Diagnostic.OK and len(rig.of(TpdoMissing)) == 1
                assert master.inputs["zapi.statusword"] & 0x0400  # CNA6 input, i.e. taken
                assert master.inputs["zapi.speed"] == pytest.approx(zapi.speed, abs=0.2)
                plc.run(50.0)
                again = net.time()
                await net.sleep(1.0)
                assert zapi.alarm == 0 and zapi.status()["handshake"] == "running"
                assert handshake_kept(rig, again, net.time())
                assert master.inputs["zapi.speed"] == pytest.approx(zapi.speed, abs=0.2)
                assert zapi.speed > 40.0
            finally:
                await master.stop()
                zapi.close()

    simulate(main())


# ================================================================================ STÖBER
MDS = 1
ENABLE_BIT, ACK_BIT = 1 << 0, 1 << 2  # A180 device control (the simulator's choice)
OPERATION_ENABLED, FAULT, SWITCH_ON_DISABLED = 4, 7, 1

STOBER_NETWORK = """
    master: {node_id: 127}
    nodes:
      mds:
        node_id: 1
        eds: mds5000.eds
        mandatory: true
        device_type: 0x00020192        # 1000h: profile 402
        vendor_id: 0xB9                # STOeBER
        product_code: 15               # rated power 1.5 kW in 0.1 kW
        guard_time: 100                # node guarding (the manual: guarding or heartbeat)
        life_time_factor: 3
        sdo:
          - {object: "0x2401:00", value: 2500}   # C01 n-Max = 2500 rpm (group C -> 2400h)
        # the drive's COB-ID parameters hold the bare function code ("plus the node-ID"):
        # the network file gives the identifiers in full
        rpdo1: {cob_id: 0x201, mapping: ["0x20B4:00", "0x26E6:00"], transmission_type: 254}
        tpdo1:
          cob_id: 0x181
          mapping: ["0x2808:00", "0x2830:00", "0x2852:00", "0x2827:00"]
          transmission_type: 254       # answers each RPDO1
          event_timer: 50
        signals:
          control: "0x20B4:00"                       # A180
          setpoint: {object: "0x26E6:00", unit: rpm} # D230
          n_motor: {object: "0x2808:00", unit: rpm}  # E08
          device_state: "0x2830:00"                  # E48
          event: "0x2852:00"                         # E82
          cause: "0x2827:00"                         # E39
"""


def sdo_write(index: int, sub: int, command: int, value: int) -> bytes:
    size = {0x2F: 1, 0x2B: 2, 0x23: 4}[command]
    return struct.pack("<BHB", command, index, sub) + value.to_bytes(size, "little").ljust(4, b"\0")


def test_stober_mds5000_booted_and_run_by_the_master(tmp_path: Path) -> None:
    """Reset, boot-up, 1000h and 1018h checked, start-up list (C01 by its group index, the
    PDO mapping written entry by entry, guarding), start; 1500 rpm through the process
    image; motor over-temperature: EMCY 4310h with E82 event 41 in the node's history;
    acknowledged (EMCY 0000h, event 30); the master stops guarding: the drive's life
    guarding trips (event 52), which the master finds (EMCY and process image) when it boots
    the drive again; acknowledged."""

    async def main() -> None:
        async with AsyncNetwork() as net:
            mds = StoberMds5000(net, MDS)
            (tmp_path / "mds5000.eds").write_text(export_eds(mds.od))
            config = loads_network(textwrap.dedent(STOBER_NETWORK), base_dir=tmp_path)
            rig = Rig(net, config)
            master = rig.master
            node = master.nodes[MDS]
            mds.start()
            try:
                # -- CiA 302 boot-up
                await master.boot(timeout=5)
                assert master_state(master) is MasterState.RUNNING
                assert state(node) is NodeState.OPERATIONAL and node.error_control == "guarding"
                assert node.device_type == 0x00020192 and not node.config_errors
                assert node.identity == {"vendor_id": 0xB9, "product_code": 15}
                assert rig.data(0x701)[:2] == [b"\x00", b"\x00"]  # power-on, after the reset
                assert rig.data(0x000) == [b"\x81\x01", b"\x01\x01"]
                writes = [f.data for f in frames_of(rig, 0x601) if f.data[0] >> 5 == 1]
                # C01 = 2500 rpm; the manual prints `23 01 24 00 C4 09 00 00`, the master sends
                # the U16 with its size (2Bh), which the drive takes as well
                assert sdo_write(0x2401, 0, 0x2B, 2500) in writes
                mapping = [d for d in writes if d[1:3] == b"\x00\x1a"]  # 1A00h, entry by entry
                assert [d[3] for d in mapping] == [1, 2, 3, 4, 5, 6]
                assert mapping[0] == sdo_write(0x1A00, 1, 0x23, 0x28080010)  # E08, 16 bit
                assert not any(d[1:4] == b"\x00\x1a\x00" for d in writes)  # sub 0 untouched
                assert writes[-2:] == [
                    sdo_write(0x100C, 0, 0x2B, 100),
                    sdo_write(0x100D, 0, 0x2F, 3),
                ]
                device = mds.device
                assert device is not None
                assert device.get(0x2401) == 2500 and device.get(0x100C) == 100
                assert mds.mapped_length(0x1A00) == 5 and mds.mapped_length(0x1600) == 4
                await net.sleep(0.35)
                assert rig.data(0x701)[2] == b"\x7f"  # first guarding reply: pre-op, toggle 0
                started = place(rig, 0x000, b"\x01\x01")
                replies = [
                    f.data for _, f in rig.frames[started:] if f.cob_id == 0x701 and not f.rtr
                ]
                assert len(replies) >= 3 and {d[0] & 0x7F for d in replies} == {0x05}
                toggles = [d[0] >> 7 for d in replies]
                assert all(a != b for a, b in itertools.pairwise(toggles))
                assert mds.status()["led_green"] == "on"

                # -- run at 1500 rpm
                master.outputs["mds.setpoint"] = 1500
                master.outputs["mds.control"] = ENABLE_BIT
                await net.sleep(0.8)
                assert master.inputs["mds.n_motor"] == 1500
                assert master.inputs["mds.device_state"] == OPERATION_ENABLED
                assert frames_of(rig, 0x201)[-1].data == bytes.fromhex("0100 DC05")

                # -- motor over-temperature
                hot = net.time()
                mds.inject("motor_overtemperature")
                await net.sleep(0.5)
                assert rig.data(0x081, since=hot) == [bytes.fromhex("1043082900000000")]
                record = node.emcy_history[0]
                assert (record.code, record.register) == (0x4310, 0x08)
                assert record.manufacturer_data == bytes(
                    (41, 0, 0, 0, 0)
                )  # byte 3 E82 = 41, byte 4 E39
                assert record.text == "Temperature (4310h)"  # the CiA class: the master's text
                assert (
                    EVENTS[record.manufacturer_data[0]][0] == "motor temperature"
                )  # the manual's text
                assert node.emcy_count == 1 and node.error_register == 0x08
                emergencies = rig.of(NodeEmergency)
                assert [(e.node_id, e.code) for e in emergencies] == [(MDS, 0x4310)]
                assert master.inputs["mds.device_state"] == FAULT
                assert master.inputs["mds.event"] == 41 and master.inputs["mds.n_motor"] == 0

                # -- the motor cools down; acknowledge (A180 bit 2, rising edge)
                mds.inject("motor_overtemperature", active=False)
                master.outputs["mds.control"] = ACK_BIT
                acked = net.time()
                await net.sleep(0.1)
                assert rig.data(0x081, since=acked) == [bytes.fromhex("0000001E00000000")]
                assert (
                    node.emcy_history[0].code == 0
                    and node.emcy_history[0].manufacturer_data[0] == 30
                )
                assert master.inputs["mds.device_state"] == SWITCH_ON_DISABLED
                assert master.inputs["mds.event"] == 30
                master.outputs["mds.control"] = 0

                # -- the master stops (and with it its node guarding): life guarding trips
                await master.stop()
                stopped = net.time()
                await net.sleep(0.5)
                last_rtr = max(t for t, f in rig.on(0x701) if f.rtr)
                assert last_rtr <= stopped
                (lost_at, lost), *_ = rig.on(0x081, since=stopped)
                assert lost.data == bytes.fromhex("0081103401000000")  # 8100h, event 52, cause 1
                assert lost_at == pytest.approx(last_rtr + 0.3)  # 100 ms x 3
                assert sim_state(mds) is NmtState.PRE_OPERATIONAL
                status = mds.status()
                assert (status["event"], status["cause"], status["led_red"]) == (
                    52,
                    1,
                    "double flash",
                )
                # -- booted again, the master finds the drive in fault with event 52: the
                # reset does not end the fault, the drive reports it once more
                count = node.emcy_count
                await master.boot(timeout=5)
                await net.sleep(0.1)
                assert state(node) is NodeState.OPERATIONAL
                assert node.emcy_count == count + 1
                record = node.emcy_history[0]
                assert (record.code, record.register, record.manufacturer_data[:2]) == (
                    0x8100,
                    0x10,
                    b"\x34\x01",
                )
                assert EVENTS[record.manufacturer_data[0]][0] == "communication"
                assert master.inputs["mds.device_state"] == FAULT
                assert (master.inputs["mds.event"], master.inputs["mds.cause"]) == (52, 1)
                count = node.emcy_count
                master.outputs["mds.control"] = ACK_BIT
                await net.sleep(0.1)
                assert (
                    node.emcy_count == count + 1 and node.emcy_history[0].manufacturer_data[0] == 30
                )
                assert node.emcy_history[0].code == 0 and master.inputs["mds.event"] == 30
            finally:
                await master.stop()
                mds.close()

    simulate(main())


def test_stober_fault_outlasting_a_reset_node_is_reported_again_and_acknowledged() -> None:
    """NMT reset node clears the CANopen errors, not the inverter's fault: the drive reports
    the event once more after its boot-up (1001h shows it), and the acknowledge sends
    0000h as the manual says; reset communication keeps the error and sends nothing."""

    async def main() -> list[tuple[int, bytes]]:
        async with AsyncNetwork() as net:
            frames: list[tuple[int, bytes]] = []
            net.subscribe_all(lambda f, now: frames.append((f.cob_id, f.data)))
            mds = StoberMds5000(net, MDS)
            mds.start()
            mds.inject("event", number=44, cause=7)  # external fault
            await net.sleep(0.1)
            net.nmt.reset_communication(MDS)
            await net.sleep(0.1)
            net.nmt.reset_node(MDS)
            await net.sleep(0.1)
            device = mds.device
            assert device is not None and device.get(0x1001) == 0x01
            mds.inject("event", number=44, active=False)
            assert mds.acknowledge()
            await net.sleep(0.01)
            assert device.get(0x1001) == 0
            mds.close()
            return [(c, d) for c, d in frames if c in (0x081, 0x701)]

    fault = (0x081, bytes.fromhex("0090012C07000000"))  # 9000h, register 01, event 44, cause 7
    assert simulate(main()) == [
        (0x701, b"\x00"),  # power-on
        fault,
        (0x701, b"\x00"),  # reset communication: the error is kept, nothing sent
        (0x701, b"\x00"),  # reset node: the error is gone from 1001h ...
        fault,  # ... and reported again
        (0x081, bytes.fromhex("0000001E00000000")),  # acknowledged: 0000h, event 30
    ]


# ================================================================================ EC motor
MOTOR = 3
# m_ssm (200Fh) and m_sss (200Eh) bits, mode in m_ssm bits 4-0
BER, BRU, BPZ = 1 << 15, 1 << 10, 1 << 11
BRS, BSW, BIH = 1 << 14, 1 << 12, 1 << 9
OFF, VEL, ERR = 1, 5, 29

#: The EC motor as the master sees it (the motor ships no EDS and has no dictionary a
#: master could read): TPDO1 is its status reply, RPDO1 the status poll with no data.
EC_MOTOR_EDS = """\
[FileInfo]
FileName=ec_motor.eds
FileVersion=1
FileRevision=0
EDSVersion=4.0
Description=EC motor (seed 002): the status poll and its reply, for the master

[DeviceInfo]
VendorName=EC motor
ProductName=EC motor, manufacturer CAN profile
BaudRate_250=1
SimpleBootUpSlave=1
Granularity=0
NrOfRXPDO=1
NrOfTXPDO=1

[MandatoryObjects]
SupportedObjects=0

[OptionalObjects]
SupportedObjects=4
1=0x1400
2=0x1600
3=0x1800
4=0x1A00

[ManufacturerObjects]
SupportedObjects=3
1=0x200A
2=0x200F
3=0x2012

[1400]
ParameterName=Status poll (RPDO1)
ObjectType=0x9
SubNumber=3

[1400sub0]
ParameterName=Highest sub-index supported
ObjectType=0x7
DataType=0x0005
AccessType=ro
DefaultValue=2
PDOMapping=0

[1400sub1]
ParameterName=COB-ID used by RPDO
ObjectType=0x7
DataType=0x0007
AccessType=ro
DefaultValue=$NODEID+0x200
PDOMapping=0

[1400sub2]
ParameterName=Transmission type
ObjectType=0x7
DataType=0x0005
AccessType=ro
DefaultValue=1
PDOMapping=0

[1600]
ParameterName=Status poll mapping (no data)
ObjectType=0x9
SubNumber=1

[1600sub0]
ParameterName=Number of mapped objects
ObjectType=0x7
DataType=0x0005
AccessType=ro
DefaultValue=0
PDOMapping=0

[1800]
ParameterName=Status (TPDO1)
ObjectType=0x9
SubNumber=3

[1800sub0]
ParameterName=Highest sub-index supported
ObjectType=0x7
DataType=0x0005
AccessType=ro
DefaultValue=2
PDOMapping=0

[1800sub1]
ParameterName=COB-ID used by TPDO
ObjectType=0x7
DataType=0x0007
AccessType=ro
DefaultValue=$NODEID+0x180
PDOMapping=0

[1800sub2]
ParameterName=Transmission type
ObjectType=0x7
DataType=0x0005
AccessType=ro
DefaultValue=1
PDOMapping=0

[1A00]
ParameterName=Status mapping
ObjectType=0x9
SubNumber=4

[1A00sub0]
ParameterName=Number of mapped objects
ObjectType=0x7
DataType=0x0005
AccessType=ro
DefaultValue=3
PDOMapping=0

[1A00sub1]
ParameterName=Mapped object 1
ObjectType=0x7
DataType=0x0007
AccessType=ro
DefaultValue=0x20120120
PDOMapping=0

[1A00sub2]
ParameterName=Mapped object 2
ObjectType=0x7
DataType=0x0007
AccessType=ro
DefaultValue=0x200A0010
PDOMapping=0

[1A00sub3]
ParameterName=Mapped object 3
ObjectType=0x7
DataType=0x0007
AccessType=ro
DefaultValue=0x200F0010
PDOMapping=0

[200A]
ParameterName=m_eci
ObjectType=0x7
DataType=0x0006
AccessType=rw
DefaultValue=0
PDOMapping=1

[200F]
ParameterName=m_ssm
ObjectType=0x7
DataType=0x0006
AccessType=ro
DefaultValue=0
PDOMapping=1

[2012]
ParameterName=h_poz
ObjectType=0x9
SubNumber=2

[2012sub0]
ParameterName=Highest sub-index supported
ObjectType=0x7
DataType=0x0005
AccessType=ro
DefaultValue=1
PDOMapping=0

[2012sub1]
ParameterName=h_poz 32-bit
ObjectType=0x7
DataType=0x0004
AccessType=ro
DefaultValue=0
PDOMapping=1
"""

EC_NETWORK = """
    master: {sync_period: 20}
    nodes:
      motor:
        node_id: 3
        eds: ec_motor.eds
        do_not_initialise: true     # no boot-up, NMT reset 82h only
        sdo_server: false           # its SDO dialect is not CiA 301: no 1000h read
        rpdo1: {mapping: []}        # the status poll: 203 [0] with every SYNC
        signals:
          position: {object: "0x2012:01", scale: 0.1171875, unit: deg}   # h_poz (P)
          status: m_ssm
"""


def ec_emcy(record_register: int, data: bytes) -> tuple[int, int, int]:
    """m_sss, c_sss, m_ssm of an EC motor emergency as the master recorded it: the master reads
    the frame as CiA's (code U16, error register U8, 5 bytes), so m_sss is split over the
    "register" and the first data byte."""
    m_sss = record_register | data[0] << 8
    c_sss, m_ssm = struct.unpack_from("<HH", data, 1)
    return m_sss, c_sss, m_ssm


def test_ec_motor_run_by_the_master(tmp_path: Path) -> None:
    """Not initialised and never asked by SDO; polled by the master's empty RPDO1 with every
    SYNC, its status in the process image; set to velocity mode by the application's SDO
    writes (the dialect takes CiA's expedited download); an overload trips it (mode 29): the
    master records the emergency, laid out as the motor sends it; cleared and reset."""

    async def main() -> None:
        async with AsyncNetwork() as net:
            motor = EcMotor(net, MOTOR)
            (tmp_path / "ec_motor.eds").write_text(EC_MOTOR_EDS)
            config = loads_network(textwrap.dedent(EC_NETWORK), base_dir=tmp_path)
            rig = Rig(net, config)
            master = rig.master
            node = master.nodes[MOTOR]
            motor.start()
            try:
                # -- boot: no SDO, no reset; the start (01 03) means nothing to the motor
                await master.boot(timeout=5)
                assert state(node) is NodeState.OPERATIONAL
                assert frames_of(rig, 0x603) == [] and rig.data(0x000) == [b"\x01\x03"]
                await net.sleep(0.1)
                polls = frames_of(rig, 0x203)
                replies = frames_of(rig, 0x183)
                assert polls and all(f.dlc == 0 and not f.rtr for f in polls)
                assert len(replies) == len(polls) == len(frames_of(rig, 0x80))
                status = master.inputs["motor.status"]
                assert status & 0x1F == OFF and status & BER  # brs latched at power-on
                assert diagnostic(node) is Diagnostic.OK

                # -- the application initialises it as the document's controller does
                sdo = node.sdo
                await sdo.download(0x2045, 0, b"\0\0")  # clear errors (brs)
                await sdo.download(0x2024, 0, (640).to_bytes(2, "little"))  # p_ven 120 rpm
                await sdo.download(0x2042, 0, VEL.to_bytes(2, "little"))  # T_MOD 5
                assert rig.data(0x583)[-1] == bytes.fromhex("60422000")  # DLC 4: the dialect
                await net.sleep(0.5)
                status = master.inputs["motor.status"]
                assert status & 0x1F == VEL and status & (BRU | BPZ) == BRU | BPZ
                assert not status & BER
                position = master.inputs["motor.position"]
                assert position == pytest.approx(motor.position * 0.1171875, abs=15)
                assert position > 100.0  # deg: 120 rpm for about 0.4 s
                assert node.emcy_count == 0

                # -- overload: the current saturates, the SW protection trips (mode 29)
                tripped = net.time()
                motor.inject("overload")
                await net.sleep(0.1)
                (emcy,) = frames_of(rig, 0x083, since=tripped)
                assert emcy.data[:2] == b"\x10\x00"  # as printed, not CiA's 00 10
                assert node.emcy_count == 1
                record = node.emcy_history[0]
                assert record.code == 0x0010
                m_sss, c_sss, m_ssm = ec_emcy(record.register, record.manufacturer_data)
                assert (m_sss, c_sss, m_ssm) == struct.unpack_from("<HHH", emcy.data, 2)
                assert m_sss & (BSW | BIH) == BSW | BIH and c_sss == 0
                assert m_ssm & 0x1F == ERR and m_ssm & BER
                # the master names it by CiA's table, where 00xxh is "no error"
                assert record.text == "Error reset or no error"
                status = master.inputs["motor.status"]
                assert status & 0x1F == ERR and status & BER

                # -- load removed, errors cleared, mode 1 leaves mode 29
                motor.inject("overload", torque=0)
                await net.sleep(0.2)
                await sdo.download(0x2045, 0, b"\0\0")
                await sdo.download(0x2042, 0, OFF.to_bytes(2, "little"))
                await net.sleep(0.05)
                status = master.inputs["motor.status"]
                assert status & 0x1F == OFF and not status & BER

                # -- NMT reset (82h, the only NMT command it knows) by the master's network
                master.network.nmt.reset_communication(MOTOR)
                await net.sleep(0.05)
                assert rig.data(0x000)[-1] == b"\x82\x03" and rig.data(0x703) == []
                assert master.inputs["motor.status"] & BER  # brs: a reset occurred

                # -- what the master cannot do: read it by SDO. The reply's command byte 40h
                # reads as a segmented upload; the segment request (60h) and the client's
                # abort (80h) are refused by the motor with an emergency each.
                before = node.emcy_count
                with pytest.raises(SdoTimeoutError):
                    await sdo.upload(0x2014, 0)
                assert node.emcy_count == before + 2
                asked = [f.data[0] for f in frames_of(rig, 0x603)][-2:]
                assert asked == [0x60, 0x80]

                # -- the status poll is all the supervision there is: power loss
                motor.inject("power_loss")
                await net.sleep(0.1)
                assert rig.of(TpdoMissing) == [TpdoMissing(MOTOR, 1, 0x183)]
                assert diagnostic(node) is Diagnostic.TPDO_MISSING
                assert master.inputs["motor.status"] == 0
            finally:
                await master.stop()
                motor.close()

    simulate(main())


# ================================================================================ the master
# What the scenarios needed from the master, each on its own with the master tests' I/O node.
IO_NODE = """
  a:
    node_id: 5
    eds: io.eds
    tpdo1: {{mapping: [counter], transmission_type: 255}}
    rpdo1: {{mapping: [flags], transmission_type: {rpdo1}}}
"""


def io_network(tmp_path: Path, master: str, extra: str = "", rpdo1: int = 255) -> NetworkConfig:
    text = f"master: {master}\nnodes:" + IO_NODE.format(rpdo1=rpdo1) + extra
    return network(tmp_path, text)


@pytest.mark.parametrize("sync", [True, False], ids=["sync", "no-sync"])
def test_the_master_starts_nodes_once_its_first_sync_is_out(tmp_path: Path, sync: bool) -> None:
    """A node that needs no boot-up is ready at once; with SYNC configured the master waits
    for its first SYNC (one period) before the NMT start, as the ZAPI ACE2 requires."""
    master = "{sync_period: 50}" if sync else "{}"
    cfg = io_network(tmp_path, master, "    do_not_initialise: true\n")

    async def scenario(rig: Rig) -> None:
        rig.add(5)
        await rig.master.boot(timeout=5)
        start = place(rig, 0x000, b"\x01\x05")
        if sync:
            assert first(rig, 0x000, b"\x01\x05") == pytest.approx(0.05)
            assert place(rig, 0x80) < start
        else:
            assert first(rig, 0x000, b"\x01\x05") == 0.0 and rig.on(0x80) == []
        assert nmt(rig.devices[5]) is NmtState.OPERATIONAL

    rig_test(cfg, scenario)


def test_tpdo_listeners_see_each_tpdo_once_it_is_in_the_process_image(tmp_path: Path) -> None:
    cfg = io_network(tmp_path, "{}")

    async def scenario(rig: Rig) -> None:
        master = rig.master
        seen: list[tuple[int, int, float, object]] = []

        def listener(node_id: int, number: int, now: float) -> None:
            seen.append((node_id, number, now, master.inputs["a.counter"]))

        def broken(node_id: int, number: int, now: float) -> None:
            raise RuntimeError("application bug")

        failures: list[HandlerFailed] = []
        rig.net.add_listener(lambda e: failures.append(e) if isinstance(e, HandlerFailed) else None)
        master.add_tpdo_listener(broken)
        master.add_tpdo_listener(listener)
        device = rig.add(5)
        rig.send(0x185, b"\x07\x00")  # before the start: not taken, not reported
        await rig.settle()
        await master.boot(timeout=5)
        device.set(0x2000, 0, 42)
        await rig.run(0.01)
        # called when the TPDO arrives, with its value already in the image
        assert seen == [(5, 1, first(rig, 0x185, b"\x2a\x00"), 42)]
        assert len(failures) == 1 and "application bug" in failures[0].error
        master.remove_tpdo_listener(listener)
        master.remove_tpdo_listener(broken)
        device.set(0x2000, 0, 43)
        await rig.run(0.01)
        assert len(seen) == 1 and master.inputs["a.counter"] == 43

    rig_test(cfg, scenario)


def test_send_rpdo_sends_the_outputs_changed_or_not(tmp_path: Path) -> None:
    cfg = io_network(tmp_path, "{sync_period: 10}")

    async def scenario(rig: Rig) -> None:
        master = rig.master
        rig.add(5)
        master.start()
        assert master.send_rpdo("a", 1) is False  # not started yet: nothing
        await master.boot(timeout=5)
        master.outputs["a.flags"] = 3
        master.outputs["a.flags"] = 3  # unchanged: no frame
        await rig.settle()
        assert rig.data(0x205) == [b"\x00", b"\x03"]  # the start, the change
        assert master.send_rpdo(5, 1) is True
        await rig.settle()
        assert rig.data(0x205) == [b"\x00", b"\x03", b"\x03"]
        assert master.nodes[5].rpdo_sent[1] == 3
        with pytest.raises(MasterValueError, match=r"no RPDO 2 .*its RPDOs: 1"):
            master.send_rpdo("a", 2)

    rig_test(cfg, scenario)


def stober_eds(folder: Path) -> None:
    async def export() -> str:
        async with AsyncNetwork() as net:
            return export_eds(StoberMds5000(net, MDS).od)

    (folder / "mds5000.eds").write_text(simulate(export()))


def test_a_direct_mapping_is_written_entry_by_entry_and_read_without_its_zeros(
    tmp_path: Path,
) -> None:
    stober_eds(tmp_path)
    config = loads_network(textwrap.dedent(STOBER_NETWORK), base_dir=tmp_path)
    node = config.nodes[MDS]
    steps = [(e.index, e.subindex, e.value, e.name) for e in node.startup if e.index == 0x1800]
    steps += [(e.index, e.subindex, e.value, e.name) for e in node.startup if e.index == 0x1A00]
    assert [s[:3] for s in steps] == [
        (0x1800, 1, 0x80000181),
        (0x1800, 5, 50),
        (0x1800, 1, 0x181),
        (0x1A00, 1, 0x28080010),
        (0x1A00, 2, 0x28300008),
        (0x1A00, 3, 0x28520008),
        (0x1A00, 4, 0x28270008),
        (0x1A00, 5, 0),
        (0x1A00, 6, 0),
    ]
    order = [(e.index, e.subindex) for e in node.startup]
    assert order.index((0x1A00, 6)) < order.index((0x1800, 1), order.index((0x1800, 1)) + 1)
    (tpdo,) = node.tpdos
    assert tpdo.length == 5 and [s.index for s in tpdo.signals] == [0x2808, 0x2830, 0x2852, 0x2827]
    assert node.rpdos[0].length == 4
    # 7 entries do not fit the 6 the drive has; sub 0 is never configured
    seven = STOBER_NETWORK.replace(
        '"0x2827:00"]', '"0x2827:00", "0x2827:00", "0x2827:00", "0x2827:00"]'
    )
    with pytest.raises(NetworkConfigError, match=r"7 entries but 0x1A00 has 6"):
        loads_network(textwrap.dedent(seven), base_dir=tmp_path)


def test_a_node_without_an_sdo_server_is_never_asked_by_sdo(tmp_path: Path) -> None:
    cfg = io_network(tmp_path, "{}", "    do_not_initialise: true\n    sdo_server: false\n")

    async def scenario(rig: Rig) -> None:
        rig.add(5)
        await rig.master.boot(timeout=5)
        assert rig.on(0x605) == [] and rig.data(0x000) == [b"\x01\x05"]
        assert state(rig.master.nodes[5]) is NodeState.OPERATIONAL

    rig_test(cfg, scenario)
    for extra, reason in (
        ("    sdo_server: false\n", "needs do_not_initialise: true"),
        (
            "    do_not_initialise: true\n    sdo_server: false\n    device_type: 0x191\n"
            "    vendor_id: 1\n",
            r"device_type, vendor_id would be checked by SDO reads",
        ),
    ):
        with pytest.raises(NetworkConfigError, match=reason):
            io_network(tmp_path, "{}", extra)


def test_an_rpdo_mapped_with_nothing_goes_out_with_dlc_0(tmp_path: Path) -> None:
    """Only when the network file says ``mapping: []``: the EDS's own empty RPDOs (the I/O
    node's RPDO 2-4 are valid but map nothing) stay left out."""
    plain = io_network(tmp_path, "{sync_period: 10}", rpdo1=1)
    assert [r.number for r in plain.nodes[5].rpdos] == [1]
    cfg = io_network(
        tmp_path,
        "{sync_period: 10}",
        "    rpdo2: {mapping: [], transmission_type: 1}\n    rpdo3: {mapping: []}\n",
    )
    rpdos = {r.number: r for r in cfg.nodes[5].rpdos}
    assert sorted(rpdos) == [1, 2, 3] and rpdos[2].length == 0 and not rpdos[2].signals

    async def scenario(rig: Rig) -> None:
        rig.add(5)
        await rig.master.boot(timeout=5)
        await rig.run(0.05)
        started = place(rig, 0x000, b"\x01\x05")
        syncs = sum(1 for _, f in rig.frames[started:] if f.cob_id == 0x80)
        polls = rig.on(0x305)
        assert len(polls) == syncs + 1 and all(f.dlc == 0 for _, f in polls)  # start + SYNCs
        assert [f.dlc for _, f in rig.on(0x405)] == [0]  # event-driven: at the start only
        assert rig.master.send_rpdo("a", 3) is True

    rig_test(cfg, scenario)
