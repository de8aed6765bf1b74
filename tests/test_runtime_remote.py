"""Remote nodes, NMT and SYNC services on the simulated clock, against an in-process SDO server
on the same network (the server sees the client's frames through the local echo)."""

import asyncio

import pytest

from cobus.od import ValueRangeError
from cobus.proto import Frame
from cobus.proto.sdo import DictBackend, SdoAbortedError, SdoServer, SdoTimeoutError
from cobus.runtime import AsyncNetwork, Network, ObjectNotFoundError
from tests.conftest import EDS_DIR
from tests.util import simulate

PROFILE = EDS_DIR / "canfestival_ds401_slave_gui.eds"
DATA = bytes(range(200)) * 5


def backend() -> DictBackend:
    return DictBackend(
        {
            (0x1000, 0): (0x191).to_bytes(4, "little"),
            (0x1017, 0): (0).to_bytes(2, "little"),
            (0x1018, 1): (0x12345678).to_bytes(4, "little"),
            (0x1008, 0): b"cobus test device",
            (0x2000, 0): DATA,
        },
        read_only=[(0x1000, 0), (0x1018, 1)],
    )


def serve(net: AsyncNetwork, node_id: int, store: DictBackend) -> SdoServer:
    server = SdoServer(0x600 + node_id, 0x580 + node_id, store)
    net.attach(server, [0x600 + node_id])
    return server


def test_raw_transfers_of_every_kind_on_one_network():
    async def main():
        async with AsyncNetwork() as net:
            store = backend()
            serve(net, 4, store)
            sdo = net.add_remote(4).sdo
            assert await sdo.upload(0x1000) == b"\x91\x01\x00\x00"
            assert await sdo.upload(0x1008) == b"cobus test device"
            assert await sdo.upload(0x2000, block=True) == DATA
            await sdo.download(0x2000, 0, DATA[::-1], block=True)
            assert store.entries[(0x2000, 0)] == DATA[::-1]
            await sdo.download(0x1017, 0, b"\xe8\x03")
            assert store.entries[(0x1017, 0)] == b"\xe8\x03"
            return net.time()

    # every frame is exchanged without the clock moving: no timer had to expire
    assert simulate(main()) == 0.0


def test_transfers_on_one_channel_run_one_after_the_other():
    async def main():
        async with AsyncNetwork() as net:
            serve(net, 4, backend())
            sdo = net.add_remote(4).sdo
            return await asyncio.gather(
                sdo.upload(0x1008), sdo.upload(0x2000), sdo.upload(0x1000, block=True)
            )

    assert simulate(main()) == [b"cobus test device", DATA, b"\x91\x01\x00\x00"]


def test_timeout_when_no_server_answers_is_typed_and_on_time():
    async def main():
        async with AsyncNetwork() as net:
            node = net.add_remote(9, sdo_timeout=0.5)
            with pytest.raises(SdoTimeoutError) as err:
                await node.sdo.upload(0x1000)
            return err.value, net.time()

    error, now = simulate(main())
    assert now == pytest.approx(0.5)
    assert "0x1000" in str(error) or "1000" in str(error)


def test_abort_is_raised_with_code_and_the_channel_stays_usable():
    async def main():
        async with AsyncNetwork() as net:
            serve(net, 4, backend())
            sdo = net.add_remote(4).sdo
            with pytest.raises(SdoAbortedError) as err:
                await sdo.download(0x1000, 0, b"\x00\x00\x00\x00")
            assert err.value.code == 0x06010002
            return await sdo.upload(0x1000)

    assert simulate(main()) == b"\x91\x01\x00\x00"


def test_typed_read_and_write_through_the_eds():
    async def main():
        async with AsyncNetwork() as net:
            store = backend()
            serve(net, 4, store)
            node = net.add_remote(4, PROFILE)
            assert await node.sdo.read(0x1000) == 0x191
            assert await node.sdo.read("Identity", "Vendor ID") == 0x12345678
            await node.sdo.write(0x1017, 0, 1000)
            assert store.entries[(0x1017, 0)] == (1000).to_bytes(2, "little")
            assert await node.sdo.read("Manufacturer Device Name") == "cobus test device"
            # a value the type cannot hold is refused before any frame is sent
            sent = net.frames_sent
            with pytest.raises(ValueRangeError):
                await node.sdo.write(0x1017, 0, 70000)
            assert net.frames_sent == sent
            with pytest.raises(ObjectNotFoundError, match="no object 0x5555"):
                await node.sdo.read(0x5555)
            with pytest.raises(ObjectNotFoundError, match="has no sub-index 9"):
                await node.sdo.read(0x1018, 9)

    simulate(main())


def test_typed_access_without_a_dictionary_says_what_to_do():
    async def main():
        async with AsyncNetwork() as net:
            node = net.add_remote(3)
            with pytest.raises(ObjectNotFoundError, match="no object dictionary"):
                await node.sdo.read(0x1000)

    simulate(main())


def test_nmt_commands_and_sync_producer_frames():
    async def main():
        async with AsyncNetwork() as net:
            seen = []
            net.subscribe_all(lambda f, now: seen.append((round(now, 6), f)))
            net.nmt.send("start", 0)
            net.nmt.reset_node(17)
            net.nmt.stop()
            with pytest.raises(ValueError, match="unknown NMT command"):
                net.nmt.send("explode", 1)
            net.sync.start(0.01, overflow=3)
            await net.sleep(0.045)
            net.sync.stop()
            await net.sleep(0.1)
            return seen

    seen = simulate(main())
    assert [f for _, f in seen[:3]] == [
        Frame.parse("000 [2] 01 00"),
        Frame.parse("000 [2] 81 11"),
        Frame.parse("000 [2] 02 00"),
    ]
    syncs = seen[3:]
    assert [t for t, _ in syncs] == pytest.approx([0.01, 0.02, 0.03, 0.04])
    assert [f.data for _, f in syncs] == [b"\x01", b"\x02", b"\x03", b"\x01"]


def test_blocking_facade_on_the_simulated_clock():
    with Network(simulated=True) as net:
        store = backend()
        net.run(_serve_async(net.aio, store))
        node = net.add_remote(4, PROFILE, sdo_timeout=0.2)
        assert node.sdo.read(0x1000) == 0x191
        node.sdo.write("Producer Heartbeat Time", 0, 250)
        assert store.entries[(0x1017, 0)] == (250).to_bytes(2, "little")
        assert node.sdo.upload(0x2000, block=True) == DATA
        net.nmt.start(4)
        net.sync.start(0.001)
        net.sleep(1.0)
        assert net.sync.running
        with pytest.raises(SdoTimeoutError):
            net.add_remote(5, sdo_timeout=0.2).sdo.upload(0x1000)


async def _serve_async(net, store):
    serve(net, 4, store)


def test_a_node_cannot_be_added_twice():
    async def main():
        async with AsyncNetwork() as net:
            net.add_remote(4)
            with pytest.raises(ValueError, match="already"):
                net.add_remote(4)

    simulate(main())
