"""Node-ID change at run time, several devices on one network, the EDS export, dictionaries
built in code or read from files, and the blocking face of a device."""

from __future__ import annotations

import pytest

from cobus.device import (
    DEFAULT_DEVICE_TYPE,
    Booted,
    DeviceConfigError,
    DictionaryBuilder,
    EntryWritten,
    HeartbeatLost,
    NodeIdChanged,
    NodeIdInUseError,
    add_device,
    export_eds,
    minimal_od,
)
from cobus.od import DataType, ObjectDictionary, loads
from cobus.proto.nmt import NmtState
from cobus.proto.sdo import SdoTimeoutError
from cobus.runtime import AsyncNetwork, Network
from cobus.runtime.remote import SdoChannel
from tests.conftest import EDS_DIR
from tests.test_device_support import NODE, Bench, bench, run_bench, simulate, test_od


def test_node_id_change_moves_what_follows_the_node_id():
    async def scenario(b: Bench):
        device = b.device
        await b.sdo.write(0x1017, 0, 100)
        # TPDO1 (pre-defined COB-ID) maps the counter; TPDO2 gets an identifier of its own
        await b.sdo.write(0x1800, 1, 0x80000185)
        await b.sdo.write(0x1A00, 0, 0)
        await b.sdo.write(0x1A00, 1, 0x20000010)
        await b.sdo.write(0x1A00, 0, 1)
        await b.sdo.write(0x1800, 1, 0x185)
        await b.sdo.write(0x1801, 1, 0x80000285)
        await b.sdo.write(0x1801, 1, 0x3A0)
        await b.net.sleep(0.05)
        t0 = b.net.time()
        device.node_id = 7
        await b.settle()
        assert device.node_id == 7
        assert b.net.devices == {7: device}
        assert b.data(0x707, since=t0) == [b"\x00"]  # boot-up under the new node-ID
        assert b.state() is NmtState.PRE_OPERATIONAL
        assert b.of(NodeIdChanged) == [NodeIdChanged(7, NODE)]
        assert b.of(Booted)[-1] == Booted(7)
        new = SdoChannel(b.net, 7, b.master.od)
        assert await new.read(0x1014) == 0x87
        assert await new.read(0x1200, 1) == 0x607
        assert await new.read(0x1800, 1) == 0x187
        assert await new.read(0x1801, 1) == 0x3A0  # not the pre-defined one: kept
        assert await new.read(0x1017) == 100  # the configuration is kept
        old = SdoChannel(b.net, NODE, b.master.od, timeout=0.1)
        with pytest.raises(SdoTimeoutError):
            await old.read(0x1000)
        b.net.nmt.start(7)
        await b.settle()
        device.set(0x2000, 0, 0x4242)
        device.send_emergency(0x5000)
        await b.net.sleep(0.15)
        assert b.data(0x187) == [b"\x42\x42"]
        assert b.data(0x87) == [bytes.fromhex("0050 01 0000000000")]
        assert b.data(0x707, since=t0)[-1] == b"\x05"  # heartbeat under the new node-ID
        assert b.data(0x705, since=t0) == []

    run_bench(scenario)


def test_node_id_in_use_is_refused():
    async def main():
        async with AsyncNetwork() as net:
            a = add_device(net, 5, test_od())
            add_device(net, 6, test_od())
            with pytest.raises(NodeIdInUseError):
                a.node_id = 6
            with pytest.raises(ValueError):
                a.node_id = 128
            assert a.node_id == 5

    simulate(main())


def test_a_dictionary_serves_one_device_at_a_time():
    async def main():
        async with AsyncNetwork() as net:
            od = test_od()
            first = add_device(net, 5, od)
            with pytest.raises(DeviceConfigError, match="already served by device 5"):
                add_device(net, 6, od)
            first.close()
            assert add_device(net, 6, od).node_id == 6

    simulate(main())


def test_two_devices_on_one_network_do_not_interfere():
    async def main():
        async with AsyncNetwork() as net:
            b5 = bench(net, node_id=5)
            od6 = test_od()
            b6 = bench(net, od6, node_id=6)
            await b5.settle()
            d5, d6 = b5.device, b6.device
            await b5.sdo.write(0x2002, 0, 55)
            await b6.sdo.write(0x2002, 0, 66)
            assert (d5.get(0x2002), d6.get(0x2002)) == (55, 66)
            # PDO linking: device 6's RPDO1 listens to device 5's TPDO1
            await b5.sdo.write(0x1800, 1, 0x80000185)
            await b5.sdo.write(0x1A00, 0, 0)
            await b5.sdo.write(0x1A00, 1, 0x20020008)
            await b5.sdo.write(0x1A00, 0, 1)
            await b5.sdo.write(0x1800, 1, 0x185)
            await b6.sdo.write(0x1400, 1, 0x80000206)
            await b6.sdo.write(0x1600, 0, 0)
            await b6.sdo.write(0x1600, 1, 0x62000208)
            await b6.sdo.write(0x1600, 0, 1)
            await b6.sdo.write(0x1400, 1, 0x185)
            # device 6 watches device 5's heartbeat
            await b5.sdo.write(0x1017, 0, 50)
            await b6.sdo.write(0x1016, 1, 5 << 16 | 80)
            net.nmt.start(5)
            await b5.settle()
            assert (d5.state, d6.state) == (NmtState.OPERATIONAL, NmtState.PRE_OPERATIONAL)
            net.nmt.start(0)
            await b5.settle()
            d5.set(0x2002, 0, 0x99)
            await net.sleep(0.2)
            assert d6.get(0x6200, 2) == 0x99
            assert d6.get(0x2002) == 66
            assert not b6.of(HeartbeatLost)
            await b5.sdo.write(0x1017, 0, 0)
            await net.sleep(0.2)
            assert [e.node_id for e in b6.events if isinstance(e, HeartbeatLost)] == [6]
            assert [e.producer for e in b6.events if isinstance(e, HeartbeatLost)] == [5]
            writes = [(e.node_id, e.index) for e in b5.events if isinstance(e, EntryWritten)]
            assert (5, 0x2002) in writes and (6, 0x2002) in writes
            assert d5.state is NmtState.OPERATIONAL
            d5.close()
            assert net.devices == {6: d6}

    simulate(main())


def _sections(text: str) -> dict[str, dict[str, str]]:
    out: dict[str, dict[str, str]] = {}
    current: dict[str, str] = {}
    for line in text.splitlines():
        if line.startswith("["):
            current = out.setdefault(line.strip("[]"), {})
        elif "=" in line:
            key, _, value = line.partition("=")
            current[key] = value
    return out


def test_eds_export_of_a_device_built_in_code():
    builder = DictionaryBuilder(device_name="valve block", vendor_id=0x1234, product_code=0x42)
    builder.variable(0x2000, "Setpoint", DataType.INTEGER16, access="rww", mappable=True)
    builder.variable(0x6000, "Inputs", DataType.UNSIGNED8, access="ro", mappable=True)
    builder.rpdo(1, [(0x2000, 0)])
    builder.tpdo(1, [(0x6000, 0)], event_timer_ms=100)
    od = builder.build()
    text = export_eds(od)
    sections = _sections(text)
    info = sections["DeviceInfo"]
    assert info["ProductName"] == "valve block"
    assert info["VendorNumber"] == "0x00001234" and info["ProductNumber"] == "0x00000042"
    assert all(info[f"BaudRate_{r}"] == "1" for r in (10, 20, 50, 125, 250, 500, 800, 1000))
    assert info["SimpleBootUpSlave"] == "1" and info["SimpleBootUpMaster"] == "0"
    assert info["NrOfRXPDO"] == "4" and info["NrOfTXPDO"] == "4"
    assert sections["DummyUsage"]["Dummy0005"] == "1"
    assert sections["MandatoryObjects"] == {
        "SupportedObjects": "3",
        "1": "0x1000",
        "2": "0x1001",
        "3": "0x1018",
    }
    optional = set(sections["OptionalObjects"].values())
    for index in (0x1003, 0x1005, 0x100C, 0x100D, 0x1014, 0x1016, 0x1017, 0x1400, 0x1A00):
        assert f"0x{index:04X}" in optional
    assert "0x6000" in optional
    assert set(sections["ManufacturerObjects"].values()) == {"1", "0x2000"}
    assert sections["1000"]["DefaultValue"] == f"0x{DEFAULT_DEVICE_TYPE:X}"
    assert sections["1014"]["DefaultValue"] == "$NODEID+0x80"
    assert sections["1800sub1"]["DefaultValue"] == "$NODEID+0x180"
    assert sections["1A00sub1"]["DefaultValue"] == "0x60000008"
    assert sections["1800sub5"]["DefaultValue"] == "0x64"
    # read back, it is the same dictionary
    again = loads(text)
    assert [line for line in again.diff(od) if line.startswith("0x")] == []
    # the export did not change the dictionary itself
    assert od.device_info.nr_of_rx_pdo == 4 and export_eds(od) == text


def test_eds_export_leaves_the_dictionary_alone_while_it_writes():
    od = test_od()
    written: list[str] = []

    class Watched(ObjectDictionary):
        def __setattr__(self, name, value):
            written.append(name)
            super().__setattr__(name, value)

    class WatchedDict(dict[int, bool]):
        def __setitem__(self, key, value):
            written.append(f"dummy_usage[{key}]")
            super().__setitem__(key, value)

    od.dummy_usage = WatchedDict(od.dummy_usage)
    od.__class__ = Watched
    text = export_eds(od, description="exported")
    assert written == []
    assert "Description=exported" in text and od.file_info.description == "test device"


def test_device_from_an_eds_file_and_its_export(tmp_path):
    path = EDS_DIR / "canopennode_ds301_profile.eds"

    async def main():
        async with AsyncNetwork() as net:
            device = add_device(net, NODE, path)
            device.save_eds(tmp_path / "exported.eds")
            assert (tmp_path / "exported.eds").read_bytes().startswith(b"[FileInfo]\r\n")
            assert isinstance(device.od, ObjectDictionary)
            remote = net.add_remote(NODE, path)
            assert await remote.sdo.read(0x1018, 0) == device.get(0x1018, 0)
            assert await remote.sdo.read(0x1014) == 0x80 + NODE
            text = device.to_eds()
            sections = _sections(text)
            assert sections["DeviceInfo"]["SimpleBootUpSlave"] == "1"
            assert sections["DeviceInfo"]["LSS_Supported"] == "0"
            assert not [f for f in loads(text).findings if f.severity.value == "error"]

    simulate(main())


def test_minimal_od_is_the_communication_profile_as_objects():
    od = minimal_od(node_id=7, sdo_servers=2)
    assert od.path is None and od.findings == [] and od.node_id == 7
    following = [(0x1014, 0, 0x80), (0x1200, 1, 0x600), (0x1200, 2, 0x580), (0x1403, 1, 0x500)]
    for index, sub, base in following:
        var = od.get_variable(index, sub)
        assert var is not None and var.relative and var.value == base + 7
        assert var.default_raw == f"$NODEID+0x{base:X}"
    od.node_id = 9
    assert od.get_variable(0x1014).value == 0x89  # type: ignore[union-attr]
    second = od.get_variable(0x1201, 1)
    assert second is not None and second.value == 0x80000000 and not second.relative
    assert od.dummy_usage == dict.fromkeys(range(1, 8), True) and 5 in od  # dummies to map
    assert loads(od.to_eds(), node_id=9).diff(od) == []
    builder = DictionaryBuilder()
    builder.variable(0x2000, "x", DataType.UNSIGNED8, mappable=True)
    builder.tpdo(1, [(0x0005, 0), (0x2000, 0)])  # a dummy byte, then x
    assert builder.build().get_variable(0x1A00, 1).value == 0x00050008  # type: ignore[union-attr]
    with pytest.raises(DeviceConfigError, match=r"node-ID 0 is out of range: use 1\.\.127"):
        minimal_od(node_id=0)


def test_dictionaries_the_device_cannot_run_are_refused():
    od = minimal_od()
    od.remove(0x1018)

    async def main():
        async with AsyncNetwork() as net:
            with pytest.raises(DeviceConfigError, match="1018h"):
                add_device(net, NODE, od)

    simulate(main())
    builder = DictionaryBuilder()
    with pytest.raises(DeviceConfigError, match="not in the dictionary"):
        builder.tpdo(1, [(0x2000, 0)])
    with pytest.raises(DeviceConfigError, match=r"2000h\.\.FFFFh"):
        builder.variable(0x1234, "x", DataType.UNSIGNED8)
    with pytest.raises(DeviceConfigError, match="no TPDO 9"):
        builder.variable(0x2000, "x", DataType.UNSIGNED8, mappable=True)
        builder.tpdo(9, [(0x2000, 0)])
    builder.variable(0x2001, "y", DataType.UNSIGNED8)
    builder.tpdo(1, [(0x2001, 0)])  # not mappable
    with pytest.raises(DeviceConfigError, match="not PDO-mappable"):
        builder.build()
    with pytest.raises(DeviceConfigError):
        minimal_od(rpdos=513)
    record = DictionaryBuilder()
    record.record(0x3000, "Channel")
    record.variable(0x3000, "Gain", DataType.REAL32, subindex=1, default=1.0)
    record.variable(0x3000, "Offset", DataType.REAL32, subindex=2, default=0.0)
    assert record.build().get_variable(0x3000, 0).default == 2  # type: ignore[union-attr]


def test_blocking_device_on_the_simulated_clock():
    with Network(simulated=True) as net:
        device = add_device(net, NODE, test_od())
        remote = net.add_remote(NODE, loads(export_eds(test_od()), NODE))
        seen: list[object] = []
        device.add_listener(seen.append)
        assert device.state.name == "PRE_OPERATIONAL"
        remote.sdo.write(0x2002, 0, 3)
        assert device.get(0x2002) == 3
        device.set(0x2002, 0, 4)
        assert remote.sdo.read(0x2002) == 4
        device.on_read(0x2006, 0, lambda: 1.25)
        assert remote.sdo.read(0x2006) == 1.25
        device.send_emergency(0x4200)
        assert device.error_register == 0x09
        device.clear_emergency()
        assert device.error_register == 0
        net.nmt.start(NODE)
        net.sleep(0.01)
        assert device.state.name == "OPERATIONAL"
        device.node_id = 9
        assert device.node_id == 9 and device.state.name == "PRE_OPERATIONAL"
        assert "[DeviceInfo]" in device.to_eds()
        assert any(isinstance(e, EntryWritten) for e in seen)
        device.close()
