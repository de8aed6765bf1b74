"""Unconfigured simulated devices (a rig's ``node: unconfigured``): found by fastscan, given
node-IDs by LSS, booted; what a power cycle keeps (only what the master had them store)."""

from __future__ import annotations

from pathlib import Path

import pytest

from cobus.cli import main
from cobus.device import UNCONFIGURED
from cobus.proto.lss import LssState
from cobus.proto.nmt import NmtState
from cobus.runtime import AsyncNetwork
from cobus.sim import Rig
from cobus.sim.generic import CanopenSimDevice
from cobus.sim.rig import RigError
from tests.util import simulate

RIG = """
devices:
  - {node: 5, kind: cia401_io}
  - {node: unconfigured, kind: cia402_drive, serial: 0x1234}
  - {node: unconfigured, kind: cia402_drive}
  - {node: unconfigured, kind: cia401_io}
  - {node: unconfigured, kind: cia401_io, name: valves}
"""


def canopen(rig: Rig, node: int | str) -> CanopenSimDevice:
    device = rig.device(node)
    assert isinstance(device, CanopenSimDevice)
    return device


def test_four_unconfigured_rig_devices_found_named_and_booted() -> None:
    rig = Rig.loads(RIG)

    async def main() -> None:
        async with AsyncNetwork() as net:
            await rig.start(net)
            assert sorted(rig.devices) == [5, 0x101, 0x102, 0x103, 0x104]
            unconfigured = [d for d in rig.devices.values() if d.node_id == UNCONFIGURED]
            assert len(unconfigured) == 4
            assert rig.devices[0x101].name == "cia402_drive-00001234"
            assert rig.device("valves") is rig.devices[0x104]
            t0 = net.time()
            serials = {}
            for node_id in (20, 21, 22, 23):
                found = await net.lss.fastscan()
                assert found is not None
                serials[found.serial] = node_id
                await net.lss.configure_node_id(node_id)
                if node_id == 20:
                    await net.lss.store()
                net.lss.switch_global(LssState.WAITING)
            assert await net.lss.fastscan() is None
            print(f"4 devices found and named in {net.time() - t0:.2f} s (simulated)")
            await net.sleep(0.1)
            assert serials[0x1234] in (20, 21, 22, 23)
            for node_id in (20, 21, 22, 23):
                device = canopen(rig, node_id)
                assert device.device.state is NmtState.PRE_OPERATIONAL
                assert await net.add_remote(node_id, device.od).sdo.read(0x1018, 4) in serials
            # a power cycle keeps the node-ID the master had stored, and only that one
            stored, volatile = canopen(rig, 20), canopen(rig, 21)
            for device in (stored, volatile):
                device.inject("power_loss")
                device.inject("power_return")
            await net.sleep(0.1)
            assert stored.node_id == 20 and stored.device.state is NmtState.PRE_OPERATIONAL
            assert volatile.node_id == UNCONFIGURED
            assert await net.lss.fastscan() is not None  # waits for a node-ID again
            await rig.stop()

    simulate(main())


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("{node: unconfigured, kind: stober_mds5000}", "has no LSS slave"),
        ("{node: unconfigured, kind: cia401_io, serial: -1}", "serial -1"),
        ("{node: unconfigured, kind: cia401_io, serial: 1.5}", "serial 1.5"),
        ("{node: nobody, kind: cia401_io}", "or unconfigured"),
    ],
)
def test_a_device_that_cannot_start_unconfigured_is_told_why(text: str, message: str) -> None:
    async def main() -> None:
        rig = Rig.loads(f"devices:\n  - {text}\n")
        async with AsyncNetwork() as net:
            await rig.start(net)

    with pytest.raises(RigError, match=message):
        simulate(main())


def test_cobus_sim_lists_an_unconfigured_device_as_such(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "rig.yaml"
    path.write_text(RIG)
    assert main(["sim", str(path), "--list-faults"]) == 0
    out = capsys.readouterr().out
    assert "unconfigured valves (cia401_io):" in out and "node 255" not in out
