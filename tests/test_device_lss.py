"""The device as an LSS slave (CiA 305): a device started without a node-ID is silent but for
LSS, is found by fastscan, takes the node-ID a master gives it and boots; a configured one
takes a new node-ID at its next reset; ``store`` keeps both in the device's storage; a bit
timing is switched to when activated. On python-can's virtual bus and the simulated clock,
and against python-canopen's LSS master over python-can-remote."""

from __future__ import annotations

import hashlib
import json
import random
import struct
from pathlib import Path
from typing import Any

import pytest

from cobus.device import (
    UNCONFIGURED,
    BitRateSwitched,
    Booted,
    ConfigurationProblem,
    Device,
    DeviceConfigError,
    FileStorage,
    LssBitTimingConfigured,
    LssConfigurationStored,
    LssNodeIdConfigured,
    LssStoreFailed,
    NodeIdChanged,
    NodeIdInUseError,
    StorageError,
    StorageProblem,
    add_device,
    minimal_od,
)
from cobus.device._objects import U8, U32, composite
from cobus.od import DataType, NodeRelative, Record, Variable
from cobus.proto import Event, Frame
from cobus.proto.lss import LssIdentity, LssState
from cobus.proto.nmt import NmtCommand, NmtState
from cobus.runtime import AsyncNetwork, LssRefusedError
from tests.util import simulate

VENDOR, PRODUCT, REVISION = 0x360, 0x1234, 0x0001_0002


def od(serial: int) -> Any:
    return minimal_od(vendor_id=VENDOR, product_code=PRODUCT, revision=REVISION, serial=serial)


def identity(serial: int) -> LssIdentity:
    return LssIdentity(VENDOR, PRODUCT, REVISION, serial)


def frames_of(net: AsyncNetwork) -> list[Frame]:
    seen: list[Frame] = []
    net.subscribe_all(lambda frame, now: seen.append(frame))
    return seen


def events_of(net: AsyncNetwork) -> list[Event]:
    seen: list[Event] = []
    net.add_listener(seen.append)
    return seen


def state_of(device: Device) -> NmtState:
    return device.state


def rate_of(device: Device) -> int | None:
    return device.bit_rate


def test_an_unconfigured_device_is_silent_but_for_lss_until_it_is_given_a_node_id() -> None:
    async def main() -> None:
        async with AsyncNetwork() as net:
            frames = frames_of(net)
            events = events_of(net)
            dev = add_device(net, UNCONFIGURED, od(0xC0FFEE))
            assert dev.node_id == UNCONFIGURED and dev.lss is not None
            assert repr(dev) == "Device(unconfigured, serial 0x00C0FFEE)"
            assert state_of(dev) is NmtState.INITIALISING
            assert UNCONFIGURED not in net.devices
            net.nmt.reset_communication(0)  # NMT is not for a device without a node-ID
            dev.send_emergency(0x5000)  # recorded, not sent: it has no COB-ID
            await net.sleep(0.5)
            assert [f for f in frames if f.cob_id != 0] == []
            assert not any(isinstance(e, Booted) for e in events)

            assert await net.lss.identify_unconfigured()
            found = await net.lss.fastscan({"vendor": VENDOR, "product": PRODUCT})
            assert found == identity(0xC0FFEE)
            assert dev.lss.state is LssState.CONFIGURATION
            await net.lss.configure_node_id(12)
            assert dev.node_id == UNCONFIGURED  # pending until switched back to waiting
            net.lss.switch_global(LssState.WAITING)
            await net.sleep(0.01)
            assert dev.node_id == 12 and net.devices.get(12) is dev
            assert state_of(dev) is NmtState.PRE_OPERATIONAL
            assert any(f.cob_id == 0x70C and f.data == b"\x00" for f in frames)
            assert LssNodeIdConfigured(UNCONFIGURED, 12) in events
            assert NodeIdChanged(12, UNCONFIGURED) in events
            assert Booted(12) in events
            node = net.add_remote(12, minimal_od())
            assert await node.sdo.read(0x1018, 4) == 0xC0FFEE
            assert await node.sdo.read(0x1014) == 0x80 + 12  # the $NODEID COB-IDs follow
            assert await node.sdo.read(0x1200, 1) == 0x600 + 12
            assert not await net.lss.identify_unconfigured()  # it has a node-ID now

    simulate(main())


def test_four_unconfigured_devices_found_named_and_booted() -> None:
    rng = random.Random(7)
    serials = [rng.getrandbits(32) for _ in range(4)]

    async def main() -> None:
        async with AsyncNetwork() as net:
            devices = [add_device(net, UNCONFIGURED, od(s)) for s in serials]
            add_device(net, 5, od(99), lss=True)  # configured: takes no part in fastscan
            t0 = net.time()
            for node_id in (20, 21, 22, 23):
                found = await net.lss.fastscan()
                assert found is not None
                await net.lss.configure_node_id(node_id)
                net.lss.switch_global(LssState.WAITING)
            assert await net.lss.fastscan() is None
            await net.sleep(0.01)
            by_serial = {d.lss.identity.serial: d.node_id for d in devices if d.lss}
            assert sorted(by_serial.values()) == [20, 21, 22, 23]
            assert all(state_of(d) is NmtState.PRE_OPERATIONAL for d in devices)
            assert net.time() - t0 < 60  # simulated time: the scans' windows

    simulate(main())


def test_a_configured_device_takes_a_new_node_id_at_its_next_reset() -> None:
    async def main() -> None:
        async with AsyncNetwork() as net:
            events = events_of(net)
            dev = add_device(net, 5, od(7), lss=True)
            await net.lss.select(identity(7))
            assert await net.lss.inquire("node_id") == 5
            await net.lss.configure_node_id(40)
            net.lss.switch_global(LssState.WAITING)
            await net.sleep(0.01)
            assert dev.node_id == 5 and dev.lss is not None and dev.lss.pending_node_id == 40
            net.nmt.reset_communication(5)
            await net.sleep(0.01)
            assert dev.node_id == 40 and net.devices.get(40) is dev and 5 not in net.devices
            assert NodeIdChanged(40, 5) in events and Booted(40) in events
            assert await net.add_remote(40, minimal_od()).sdo.read(0x1014) == 0x80 + 40

            # FFh takes the node-ID away: at the next reset it answers LSS only
            await net.lss.select(identity(7))
            await net.lss.configure_node_id(UNCONFIGURED)
            net.lss.switch_global(LssState.WAITING)
            net.nmt.reset_node(40)
            await net.sleep(0.01)
            assert dev.node_id == UNCONFIGURED and 40 not in net.devices
            assert NodeIdChanged(UNCONFIGURED, 40) in events
            assert await net.lss.identify_unconfigured()
            assert await net.lss.fastscan({"vendor": VENDOR}) == identity(7)

    simulate(main())


def test_a_node_id_another_local_device_holds_is_not_taken_and_said_so() -> None:
    async def main() -> None:
        async with AsyncNetwork() as net:
            events = events_of(net)
            add_device(net, 12, od(1))
            dev = add_device(net, UNCONFIGURED, od(2))
            await net.lss.fastscan()
            await net.lss.configure_node_id(12)
            net.lss.switch_global(LssState.WAITING)
            await net.sleep(0.01)
            assert dev.node_id == UNCONFIGURED
            problems = [e for e in events if isinstance(e, ConfigurationProblem)]
            assert problems and "node-ID 12" in problems[0].reason
            assert await net.lss.identify_unconfigured()  # still waiting for one

    simulate(main())


def test_store_keeps_node_id_and_bit_rate_in_the_device_storage(tmp_path: Path) -> None:
    path = tmp_path / "params.json"

    async def main() -> None:
        async with AsyncNetwork() as net:
            events = events_of(net)
            dev = add_device(net, UNCONFIGURED, od(3), storage=path)
            await net.lss.fastscan()
            await net.lss.configure_node_id(33)
            await net.lss.configure_bit_rate(250)
            await net.lss.store()
            assert LssConfigurationStored(UNCONFIGURED, 33, 3) in events
            assert LssBitTimingConfigured(UNCONFIGURED, 3, 250) in events
            net.lss.switch_global(LssState.WAITING)
            await net.sleep(0.01)
            dev.store_parameters()  # 1010h keeps the LSS part
            dev.restore_defaults()  # and so does 1011h
            dev.close()
            assert json.loads(path.read_text())["lss"] == {
                "bit_timing": {"value": 3},
                "node_id": {"value": 33},
            }
            again = add_device(net, UNCONFIGURED, od(3), storage=path)
            assert again.node_id == 33 and again.bit_rate == 250
            assert state_of(again) is NmtState.PRE_OPERATIONAL
            again.close()
            # a stored node-ID wins over the one the device is made with
            third = add_device(net, 5, od(3), storage=path)
            assert third.node_id == 33 and third.lss is not None
            third.close()
            plain = add_device(net, 5, od(3), storage=path, lss=False)
            assert plain.node_id == 5 and plain.lss is None

    simulate(main())


def test_a_store_that_cannot_be_written_answers_media_error(tmp_path: Path) -> None:
    class Broken(FileStorage):
        def save(self, parameters: Any) -> None:
            raise StorageError("the flash is worn out")

    async def main() -> None:
        async with AsyncNetwork() as net:
            events = events_of(net)
            add_device(net, UNCONFIGURED, od(4), storage=Broken(tmp_path / "p.json"))
            await net.lss.fastscan()
            await net.lss.configure_node_id(9)
            with pytest.raises(LssRefusedError, match="media"):
                await net.lss.store()
            failed = [e for e in events if isinstance(e, LssStoreFailed)]
            assert failed and failed[0].error == 2 and "worn out" in failed[0].reason

    simulate(main())


def test_an_old_parameter_file_keeps_its_digest(tmp_path: Path) -> None:
    """Files written before the LSS group existed still load (their SHA-256 is unchanged)."""
    path = tmp_path / "old.json"
    store = FileStorage(path)
    store.save({"communication": {"1017:00": {"data": "e803"}}, "application": {}})
    assert "lss" not in json.loads(path.read_text())
    assert store.load()["communication"] == {"1017:00": {"data": "e803"}}


def test_an_activated_bit_timing_is_switched_to_after_the_delay() -> None:
    async def main() -> None:
        async with AsyncNetwork() as net:
            events = events_of(net)
            dev = add_device(net, 8, od(8), lss=True)
            assert dev.bit_rate is None
            net.lss.switch_global(LssState.CONFIGURATION)
            await net.lss.configure_bit_rate(125)
            t0 = net.time()
            net.lss.activate_bit_rate(0.2)
            await net.sleep(0.1)
            assert rate_of(dev) is None
            await net.sleep(0.15)
            assert rate_of(dev) == 125
            switched = [e for e in events if isinstance(e, BitRateSwitched)]
            assert switched == [BitRateSwitched(8, 4, 125)]
            assert net.time() - t0 >= 0.2

    simulate(main())


def test_lss_needs_the_whole_identity_and_a_node_id_is_checked() -> None:
    async def main() -> None:
        async with AsyncNetwork() as net:
            bare = minimal_od()
            bare.remove(0x1018)
            composite(
                bare,
                Record(0x1018, "Identity object"),
                [(0, "Highest sub-index supported", U8, 3)]
                + [(s, name, U32, 0) for s, name in enumerate(("Vendor", "Product", "Rev"), 1)],
            )
            with pytest.raises(DeviceConfigError, match="sub 4"):
                Device(net, UNCONFIGURED, bare)
            for bad in (0, 128, 254, True):
                with pytest.raises(DeviceConfigError, match="UNCONFIGURED"):
                    Device(net, bad, minimal_od())
            with pytest.raises(DeviceConfigError, match="lss="):
                Device(net, 5, minimal_od(), lss="yes")  # type: ignore[arg-type]

    simulate(main())


@pytest.mark.interop
def test_python_canopen_lss_master_finds_names_and_reads_a_cobus_device(
    remote_bus_url: str,
) -> None:
    """python-canopen's LSS master (another bus client, over python-can-remote) finds the
    cobus device by fastscan, gives it a node-ID, has it store it, and reads it by SDO."""
    canopen = pytest.importorskip("canopen")
    from canopen.lss import CS_INQUIRE_SERIAL_NUMBER

    from cobus.runtime import Network

    with Network(interface="remote", channel=remote_bus_url) as net:
        dev = add_device(net, UNCONFIGURED, od(0x5EED))
        cnet = canopen.Network()
        cnet.connect(interface="remote", channel=remote_bus_url)
        try:
            cnet.lss.RESPONSE_TIMEOUT = 0.2
            found, fields = cnet.lss.fast_scan()
            assert found and fields == list(identity(0x5EED).fields)
            cnet.lss.configure_node_id(17)
            cnet.lss.store_configuration()
            assert cnet.lss.inquire_lss_address(CS_INQUIRE_SERIAL_NUMBER) == 0x5EED
            cnet.lss.send_switch_state_global(cnet.lss.WAITING_STATE)
            node = cnet.add_node(17)
            for _ in range(100):
                if dev.node_id == 17:
                    break
                net.sleep(0.02)
            assert dev.node_id == 17
            raw = node.sdo.upload(0x1018, 4)
            assert struct.unpack("<I", raw)[0] == 0x5EED
        finally:
            cnet.disconnect()


def od_relative(serial: int) -> Any:
    """A dictionary with application entries whose defaults follow ``$NODEID``."""
    o = od(serial)
    o.add(Variable(0x2000, 0, "Station", DataType.UNSIGNED8, default=NodeRelative(1)))
    o.add(Variable(0x2001, 0, "Reply COB-ID", DataType.UNSIGNED32, default=NodeRelative(0x300)))
    return o


def test_values_that_follow_the_node_id_follow_one_given_by_lss() -> None:
    async def main() -> None:
        async with AsyncNetwork() as net:
            ref = add_device(net, 12, od_relative(9))
            ref.store_parameters()  # 2000h/2001h stored relative to the node-ID
            storage = ref._storage._storage
            ref.close()
            events = events_of(net)
            for made in (add_device(net, UNCONFIGURED, od_relative(1)), None):
                dev = made or add_device(net, UNCONFIGURED, od_relative(1), storage=storage)
                await net.lss.fastscan()
                await net.lss.configure_node_id(12)
                net.lss.switch_global(LssState.WAITING)
                await net.sleep(0.01)
                assert (dev.get(0x2000), dev.get(0x2001)) == (13, 0x30C)
                await net.lss.select(identity(1))
                await net.lss.configure_node_id(20)  # at the next reset: as set_node_id does
                net.lss.switch_global(LssState.WAITING)
                net.nmt.reset_communication(12)
                await net.sleep(0.01)
                assert (dev.node_id, dev.get(0x2000), dev.get(0x2001)) == (20, 21, 0x314)
                dev.close()
            assert not [e for e in events if isinstance(e, StorageProblem)]

    simulate(main())


@pytest.mark.parametrize("b_new", [5, UNCONFIGURED])
def test_two_devices_swap_node_ids_at_one_reset_of_all(b_new: int) -> None:
    async def configure(net: AsyncNetwork, serial: int, node_id: int) -> None:
        await net.lss.select(identity(serial))
        await net.lss.configure_node_id(node_id)
        net.lss.switch_global(LssState.WAITING)

    async def main() -> None:
        async with AsyncNetwork() as net:
            events = events_of(net)
            a = add_device(net, 5, od(1), lss=True)
            b = add_device(net, 6, od(2), lss=True)
            await configure(net, 1, 6)
            await configure(net, 2, b_new)
            net.nmt.reset_communication(0)
            await net.sleep(0.01)
            assert (a.node_id, b.node_id) == (6, b_new)
            assert net.devices.get(6) is a
            assert not [e for e in events if isinstance(e, ConfigurationProblem)]

    simulate(main())


def test_a_node_id_taken_at_the_reset_stays_pending_and_is_taken_later() -> None:
    async def main() -> None:
        async with AsyncNetwork() as net:
            events = events_of(net)
            dev = add_device(net, 5, od(1), lss=True)
            other = add_device(net, 6, od(2))
            await net.lss.select(identity(1))
            await net.lss.configure_node_id(6)
            net.lss.switch_global(LssState.WAITING)
            net.nmt.reset_communication(5)
            await net.sleep(0.01)
            assert dev.node_id == 5 and state_of(dev) is NmtState.PRE_OPERATIONAL
            problems = [e.reason for e in events if isinstance(e, ConfigurationProblem)]
            assert problems and "6 stays pending" in problems[0]
            other.close()
            net.nmt.reset_communication(5)
            await net.sleep(0.01)
            assert dev.node_id == 6

    simulate(main())


def test_a_pending_node_id_set_out_of_range_is_ignored_and_said() -> None:
    async def main() -> None:
        async with AsyncNetwork() as net:
            events = events_of(net)
            dev = add_device(net, 5, od(1), lss=True)
            assert dev.lss is not None
            dev.lss.pending_node_id = 200
            net.nmt.reset_communication(5)
            await net.sleep(0.01)
            assert dev.node_id == 5 and list(net.devices) == [5]
            assert any("200" in e.reason for e in events if isinstance(e, ConfigurationProblem))

    simulate(main())


def test_a_stored_node_id_another_device_holds_is_refused_saying_where_it_came_from(
    tmp_path: Path,
) -> None:
    async def main() -> None:
        async with AsyncNetwork() as net:
            path = tmp_path / "p.json"
            dev = add_device(net, UNCONFIGURED, od(1), storage=path)
            await net.lss.fastscan()
            await net.lss.configure_node_id(12)
            await net.lss.store()
            dev.close()
            add_device(net, 12, od(2))
            dictionary = od(1)
            with pytest.raises(NodeIdInUseError, match="LSS master had this device store"):
                Device(net, 5, dictionary, storage=path)
            assert dictionary.node_id is None  # untouched

    simulate(main())


def test_an_unreadable_store_is_never_overwritten_by_lss(tmp_path: Path) -> None:
    async def main() -> None:
        async with AsyncNetwork() as net:
            path = tmp_path / "p.json"
            path.write_text("not json")
            add_device(net, UNCONFIGURED, od(1), storage=path)
            await net.lss.fastscan()
            await net.lss.configure_node_id(12)
            with pytest.raises(LssRefusedError, match="media"):
                await net.lss.store()
            assert path.read_text() == "not json"

    simulate(main())


def test_a_file_with_lss_keeps_the_digest_a_cobus_before_lss_checks(tmp_path: Path) -> None:
    """The parameters' SHA-256 covers the communication and application groups as before;
    the LSS group has its own, so an older cobus reads the file and ignores the LSS part."""
    path = tmp_path / "p.json"
    store = FileStorage(path)
    params = {"communication": {"1017:00": {"data": "e803"}}, "application": {}}
    store.save({**params, "lss": {"node_id": {"value": 12}}})
    doc = json.loads(path.read_text())
    canonical = json.dumps(params, sort_keys=True).encode()
    assert doc["sha256"] == hashlib.sha256(canonical).hexdigest()
    assert store.load()["lss"] == {"node_id": {"value": 12}}
    doc["lss"]["node_id"]["value"] = 13
    path.write_text(json.dumps(doc))
    with pytest.raises(StorageError, match="LSS configuration"):
        store.load()


def test_what_an_unconfigured_device_cannot_do_is_said() -> None:
    async def main() -> None:
        async with AsyncNetwork() as net:
            with pytest.raises(DeviceConfigError, match="unreachable"):
                Device(net, UNCONFIGURED, od(1), lss=False)
            dev = add_device(net, UNCONFIGURED, od(1))
            for call in (lambda: dev.apply_nmt(NmtCommand.START), lambda: dev.send_tpdo(1)):
                with pytest.raises(DeviceConfigError, match="has no node-ID"):
                    call()
            dev.close()
            assert await net.lss.identify_unconfigured() is False  # closed: silent

    simulate(main())
