"""One SDO transport per server COB-ID pair: every asker on a network shares it (issue 41).

A master's node and a remote node asking the same node at once queue their transfers on one
client instead of taking each other's answers; each transfer keeps its asker's timeout, and a
removed asker ends only its own transfers."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from cobus.device import add_device
from cobus.master import ManagedNode
from cobus.proto import Event
from cobus.proto.sdo import SdoTimeoutError, UploadDone
from cobus.runtime import AsyncNetwork, NetworkClosedError
from cobus.runtime.remote import AsyncRemoteNode, SdoChannel
from tests.test_master_support import Rig, io_od, network, rig_test, simulate

NET = """master: {node_id: 127, heartbeat_time: 100}
nodes:
  io:
    node_id: 10
    eds: io.eds
    heartbeat_time: 100
    device_type: 0x191
    vendor_id: 0x00C0B05
"""


def _aborts(rig: Rig) -> list[bytes]:
    """SDO abort frames either way between node 10 and its clients."""
    return [d for cob in (0x60A, 0x58A) for d in rig.data(cob) if d[:1] == b"\x80"]


async def _booted(rig: Rig) -> tuple[AsyncRemoteNode, ManagedNode]:
    """Node 10 booted by the master, and a remote node for it on the same network."""
    rig.add(10, io_od())
    await rig.master.boot(timeout=5)
    return rig.net.add_remote(10, io_od()), rig.master.nodes[10]


def test_a_remote_node_and_the_masters_node_asking_node_10_at_once_queue_on_one_channel(
    tmp_path: Path,
) -> None:
    cfg = network(tmp_path, NET)

    async def scenario(rig: Rig) -> None:
        remote, managed = await _booted(rig)
        heard: list[Event] = []
        rig.net.add_listener(heard.append)
        assert remote.sdo.transport is managed.sdo.transport
        before = managed.sdo.transport.transfers
        heard.clear()

        # segmented uploads (the device name is longer than 4 bytes) and writes, interleaved
        results = await asyncio.gather(
            *(
                job
                for n in range(5)
                for job in (
                    managed.sdo.upload(0x1008),
                    remote.sdo.read("Manufacturer device name"),
                    remote.sdo.write("Setpoint", n),
                    managed.sdo.read(0x2001),
                )
            )
        )
        assert results[0::4] == [b"test io"] * 5
        assert results[1::4] == ["test io"] * 5
        assert results[3::4] == [0, 1, 2, 3, 4]  # each read after the write asked before it
        assert not _aborts(rig)
        assert managed.sdo.transport.transfers - before == 20
        assert managed.sdo.transport.failures == 0
        # the remote node's transfers are heard on the network; the master's stay its own
        assert sum(isinstance(e, UploadDone) for e in heard) == 5

    rig_test(cfg, scenario)


def test_removing_the_remote_node_ends_its_own_transfers_only(tmp_path: Path) -> None:
    cfg = network(tmp_path, NET)

    async def scenario(rig: Rig) -> None:
        remote, managed = await _booted(rig)
        transport = managed.sdo.transport
        masters = asyncio.ensure_future(managed.sdo.upload(0x1008))
        remotes = asyncio.ensure_future(remote.sdo.upload(0x1008))  # waits its turn
        await asyncio.sleep(0)
        rig.net.remove_remote(10)
        assert await masters == b"test io"  # not aborted
        with pytest.raises(NetworkClosedError, match="removed"):
            await remotes
        assert not _aborts(rig)
        assert managed.sdo.transport is transport  # the master still holds it
        again = rig.net.add_remote(10, io_od())
        assert again.sdo.transport is transport
        assert await again.sdo.read("Manufacturer device name") == "test io"

    rig_test(cfg, scenario)


def test_the_remote_node_removed_during_its_own_transfer_aborts_it_and_frees_the_channel(
    tmp_path: Path,
) -> None:
    cfg = network(tmp_path, NET)

    async def scenario(rig: Rig) -> None:
        remote, managed = await _booted(rig)
        remotes = asyncio.ensure_future(remote.sdo.upload(0x1008))
        await asyncio.sleep(0)  # its request is sent
        assert managed.sdo.transport.owner is remote.sdo
        masters = asyncio.ensure_future(managed.sdo.upload(0x1008))  # waits its turn
        rig.net.remove_remote(10)
        with pytest.raises(NetworkClosedError, match="removed"):
            await remotes
        assert await masters == b"test io"
        assert len(_aborts(rig)) == 1  # the server was told

    rig_test(cfg, scenario)


def test_each_transfer_waits_with_its_own_askers_timeout() -> None:
    async def main() -> tuple[float, float]:
        async with AsyncNetwork() as net:
            quick = SdoChannel(net, 20, None, timeout=0.2)
            slow = SdoChannel(net, 20, None, timeout=1.0)
            assert quick.transport is slow.transport
            start = net.time()
            first = asyncio.ensure_future(slow.upload(0x1000))
            second = asyncio.ensure_future(quick.upload(0x1000))
            with pytest.raises(SdoTimeoutError):
                await first
            slow_took = net.time() - start
            with pytest.raises(SdoTimeoutError):
                await second
            return slow_took, net.time() - start - slow_took

    slow_took, quick_took = simulate(main())
    assert slow_took == pytest.approx(1.0, abs=0.01)
    assert quick_took == pytest.approx(0.2, abs=0.01)


def test_the_last_user_detaches_the_transport() -> None:
    async def main() -> None:
        async with AsyncNetwork() as net:
            add_device(net, 5, io_od())
            one = SdoChannel(net, 5, None)
            two = SdoChannel(net, 5, None)
            other = SdoChannel(net, 5, None, rx_cob_id=0x640, tx_cob_id=0x5C0)
            taken = net.sdo_transport(5)
            assert one.transport is two.transport is taken
            taken.release()
            assert other.transport is not one.transport
            one._close()
            assert await two.upload(0x1000) == (0x191).to_bytes(4, "little")
            two._close()
            assert net.sdo_transport(5) is not one.transport  # a new one, made afresh
            with pytest.raises(NetworkClosedError, match="removed"):
                await one.upload(0x1000)

    simulate(main())


def test_a_timeout_changed_while_a_transfer_waits_applies_when_its_turn_comes() -> None:
    async def main() -> list[float]:
        async with AsyncNetwork() as net:
            channel = SdoChannel(net, 20, None, timeout=1.0)  # node 20 is silent
            first = asyncio.ensure_future(channel.upload(0x1000))
            second = asyncio.ensure_future(channel.upload(0x1000))
            await asyncio.sleep(0)  # the first runs, the second waits
            channel.timeout = 0.2
            start, ended = net.time(), []
            for transfer in (first, second):
                with pytest.raises(SdoTimeoutError):
                    await transfer
                ended.append(net.time() - start)
            return ended

    assert simulate(main()) == pytest.approx([1.0, 1.2], abs=0.01)


def test_removal_fails_the_removed_askers_waiting_transfers_at_once() -> None:
    async def main() -> float:
        async with AsyncNetwork() as net:
            other = SdoChannel(net, 20, None, timeout=2.0, emit=False)  # node 20 is silent
            removed = SdoChannel(net, 20, None, timeout=0.1)
            running = asyncio.ensure_future(other.upload(0x1000))
            waiting = asyncio.ensure_future(removed.upload(0x1000))
            await asyncio.sleep(0)
            start = net.time()
            removed._close()
            removed._close()  # (twice: released once)
            with pytest.raises(NetworkClosedError, match="removed"):
                await waiting
            took = net.time() - start
            assert other.transport is net.sdo_transport(20)  # still the other's
            running.cancel()
            return took

    assert simulate(main()) == 0.0


def test_a_disconnect_frees_the_transport_of_turns_that_never_ran() -> None:
    """A transfer waiting when the network disconnects fails; the next loop finds the
    transport free (a turn given before the disconnect is void)."""
    net = AsyncNetwork()
    kept: list[SdoChannel] = []

    async def first() -> None:
        await net.connect()
        add_device(net, 5, io_od())
        holder, waiter = SdoChannel(net, 5, None, emit=False), SdoChannel(net, 5, None)
        kept.append(holder)
        running = asyncio.ensure_future(holder.upload(0x1008))
        waiting = asyncio.ensure_future(waiter.upload(0x1008))
        await asyncio.sleep(0)
        await net.disconnect()
        for task in (running, waiting):
            with pytest.raises(NetworkClosedError):
                await task

    async def second() -> bytes:
        await net.connect()
        try:
            assert SdoChannel(net, 5, None).transport is kept[0].transport
            return await asyncio.wait_for(SdoChannel(net, 5, None).upload(0x1000), 5)
        finally:
            await net.disconnect()

    simulate(first())
    assert simulate(second()) == (0x191).to_bytes(4, "little")
