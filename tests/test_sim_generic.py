"""The device of any EDS/DCF (kind ``eds``): corpus files served with their defaults and PDOs,
what a file lacks reported clearly, parameters from a rig file."""

from __future__ import annotations

import struct

import pytest

from cobus.device import minimal_od
from cobus.od import EdsError
from cobus.sim import SimulationError
from cobus.sim.generic import EdsDevice, EdsDeviceError
from tests.conftest import EDS_DIR
from tests.test_sim_support import SimBench, run_sim, simulate

SYSTEC = EDS_DIR / "systec_iox1_16di_8do.eds"


def test_a_corpus_eds_is_served_with_its_defaults_and_pdos():
    async def scenario(b: SimBench):
        assert await b.sdo.read(0x1000) == 197009
        assert await b.sdo.read(0x1018, 1) == 63
        assert await b.sdo.read(0x1018, 2) == 3001000
        assert await b.sdo.read(0x1800, 3) == 500  # inhibit time 50 ms, from the file
        b.net.nmt.start(5)
        await b.settle()
        dev = b.sim.device
        dev.set(0x6000, 1, 0x55)
        dev.set(0x6000, 2, 0x01)  # within the inhibit time: sent at its end
        await b.settle()
        assert b.data(0x185) == [bytes((0x55, 0x00))]
        await b.net.sleep(0.06)
        assert [round(t, 3) for t, _ in b.on(0x185)] == [0.0, 0.05]
        assert b.data(0x185)[-1] == bytes((0x55, 0x01))
        b.send(0x205, bytes((0xA5,)))  # RPDO1 -> 6200h sub 1
        await b.settle()
        assert dev.get(0x6200, 1) == 0xA5
        assert b.sim.findings == []
        assert b.sim.status()["eds"] == SYSTEC.name

    run_sim(lambda net: EdsDevice(net, 5, eds=SYSTEC), scenario)


def test_what_a_file_lacks_is_reported_and_the_node_still_runs():
    path = EDS_DIR / "lely_co-sdev.dcf"

    async def scenario(b: SimBench):
        assert await b.sdo.read(0x1018, 1) == 864
        findings = "\n".join(b.sim.findings)
        assert "1017h is not in the file: the node sends no heartbeat" in findings
        assert "no TPDO communication objects" in findings
        assert "1200h is not in the file: SDO is served on the default" in findings
        await b.net.sleep(1.0)
        assert b.on(0x700 + 2)[0][1].data == b"\x00"  # boot-up, then no heartbeat
        assert len(b.on(0x700 + 2)) == 1

    run_sim(lambda net: EdsDevice(net, 2, eds=path), scenario)


def test_dictionary_problems_of_the_file_are_collected_at_boot():
    path = EDS_DIR / "canopen-python_sample.eds"

    async def scenario(b: SimBench):
        problems = "\n".join(b.sim.problems)
        assert "TPDO 1" in problems and "0x6041:00, which does not exist" in problems

    run_sim(lambda net: EdsDevice(net, 3, eds=path), scenario)


def test_missing_mandatory_objects_are_refused_or_completed(tmp_path):
    od = minimal_od(vendor_id=7)
    od.remove(0x1018)
    path = tmp_path / "no_identity.eds"
    path.write_text(od.to_eds(), encoding="utf-8")

    async def refuse():
        from cobus.runtime import AsyncNetwork

        async with AsyncNetwork() as net:
            with pytest.raises(EdsDeviceError, match=r"lacks 1018h.*complete: true"):
                EdsDevice(net, 4, eds=path)
            with pytest.raises(EdsError):
                EdsDevice(net, 4, eds=tmp_path / "missing.eds")
            with pytest.raises(SimulationError, match="node-ID 0 is out of range"):
                EdsDevice(net, 0, eds=SYSTEC)

    simulate(refuse())

    async def scenario(b: SimBench):
        assert await b.sdo.read(0x1018, 1) == 0
        assert any("1018h is not in the file" in f for f in b.sim.findings)

    run_sim(lambda net: EdsDevice(net, 4, eds=path, complete=True), scenario)


def test_parameters_of_a_rig_file_become_the_configured_values():
    async def scenario(b: SimBench):
        assert await b.sdo.read(0x1017) == 100
        await b.net.sleep(0.35)
        assert len(b.data(0x705)) == 1 + 3  # boot-up and three heartbeats
        assert await b.sdo.read(0x1800, 5) == 250
        # a reset node returns to the configured values, not the file's defaults
        await b.sdo.write(0x1017, 0, 0)
        b.net.nmt.reset_node(5)
        await b.settle()
        assert await b.sdo.read(0x1017) == 100
        raw = await b.sdo.upload(0x6200, 1)
        assert struct.unpack("<B", raw)[0] == 0

    run_sim(
        lambda net: EdsDevice(net, 5, eds=SYSTEC, parameters={"0x1017": 100, "1800sub5": 250}),
        scenario,
    )


@pytest.mark.parametrize(
    ("key", "message"),
    [
        ("0x5555", "there is no object 0x5555"),
        ("0x1018", "write 0x1018:N"),
        ("0x1017:1", "leave the sub-index out"),
        ("bogus", "is not an object address"),
        ("0x1018:9", "has no sub-index 9"),
    ],
)
def test_bad_parameter_keys_say_how_to_write_them(key, message):
    async def main():
        from cobus.runtime import AsyncNetwork

        async with AsyncNetwork() as net:
            with pytest.raises(SimulationError, match=message):
                EdsDevice(net, 5, eds=SYSTEC, parameters={key: 1})
            with pytest.raises(SimulationError, match="0x1017"):
                EdsDevice(net, 5, eds=SYSTEC, parameters={"0x1017": 70000})

    simulate(main())
