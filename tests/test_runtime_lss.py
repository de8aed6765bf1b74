"""``net.lss``: LSS on a bus (python-can's virtual bus, simulated clock), with the slaves as
machines on the network; and python-canopen's LSS master finding and naming a cobus slave."""

from __future__ import annotations

import asyncio
import os
import random

import pytest

from cobus.proto import Event, Frame, Out
from cobus.proto.connection_set import LSS_MASTER_COB_ID
from cobus.proto.lss import (
    FastscanFieldFound,
    FastscanStarted,
    LssError,
    LssIdentity,
    LssSlave,
    LssState,
    LssStrayAnswer,
    NodeIdAssigned,
)
from cobus.runtime import (
    AsyncNetwork,
    LssRefusedError,
    LssScanError,
    LssTimeoutError,
    Network,
    NetworkClosedError,
)
from tests.util import simulate

ME = LssIdentity(0x360, 0x1234, 0x0001_0000, 0x2A)


def slaves_on(net: AsyncNetwork, *slaves: LssSlave) -> list[Event]:
    events: list[Event] = []
    for slave in slaves:
        net.attach(slave, (LSS_MASTER_COB_ID,), events.append)
    return events


async def attach(net: AsyncNetwork, slave: LssSlave, events: list[Event] | None = None) -> None:
    """On the network's loop (a blocking network's loop runs in its own thread)."""
    net.attach(slave, (LSS_MASTER_COB_ID,), None if events is None else events.append)


def test_four_unconfigured_devices_found_and_named_one_after_another() -> None:
    rng = random.Random(42)
    identities = [LssIdentity(0x360, 0x1234, 1, rng.getrandbits(32)) for _ in range(4)]

    async def main() -> None:
        async with AsyncNetwork() as net:
            slaves = [LssSlave(i) for i in identities] + [LssSlave(ME, 5)]
            events = slaves_on(net, *slaves)
            assert await net.lss.identify_unconfigured()
            progress: list[Event] = []
            t0 = net.time()
            named = []
            for node_id in range(10, 20):
                found = await net.lss.fastscan({"vendor": 0x360}, on_event=progress.append)
                if found is None:
                    break
                await net.lss.configure_node_id(node_id)
                assert await net.lss.inquire("serial") == found.serial
                net.lss.switch_global(LssState.WAITING)
                named.append((found.serial, node_id))
            took = net.time() - t0
            await net.sleep(0.01)
            assert sorted(s for s, _ in named) == sorted(i.serial for i in identities)
            assert [s.active_node_id for s in slaves] == [
                dict(named)[i.serial] for i in identities
            ] + [5]
            assert sorted(e.node_id for e in events if isinstance(e, NodeIdAssigned)) == [
                10, 11, 12, 13,
            ]  # fmt: skip
            assert not await net.lss.identify_unconfigured()
            assert [e.field for e in progress if isinstance(e, FastscanFieldFound)][:4] == [
                "vendor", "product", "revision", "serial",
            ]  # fmt: skip
            assert isinstance(progress[0], FastscanStarted)
            assert took < 5 * 0.5 + 4 * 100 * 0.01 + 1  # windows of 10 ms, not of 500 ms

    simulate(main())


def test_select_inquire_store_bit_rate_and_the_errors_that_say_why() -> None:
    async def main() -> None:
        async with AsyncNetwork() as net:
            kept: list[tuple[int, int | None]] = []
            other = LssIdentity(0x360, 0x1234, 1, 7)
            slaves_on(
                net,
                LssSlave(ME, 5, bit_rates={3, 4}),
                LssSlave(other, 6, store=lambda n, b: kept.append((n, b)) or 0),
            )
            with pytest.raises(LssTimeoutError, match="no slave is in configuration state"):
                await net.lss.configure_node_id(9)
            with pytest.raises(LssTimeoutError, match="no slave has that identity"):
                await net.lss.select(LssIdentity(1, 2, 3, 4))
            await net.lss.select(ME)
            assert await net.lss.inquire_identity() == ME
            assert await net.lss.inquire("node_id") == 5
            with pytest.raises(LssRefusedError, match="storing is not supported") as refused:
                await net.lss.store()
            assert (refused.value.service, refused.value.error) == ("store configuration", 1)
            with pytest.raises(LssRefusedError, match="bit timing not supported"):
                await net.lss.configure_bit_rate(500)
            await net.lss.configure_bit_rate(250)
            net.lss.activate_bit_rate(0.05)
            net.lss.switch_global(LssState.WAITING)
            await net.lss.select(other)
            await net.lss.configure_node_id(8)
            await net.lss.store()
            assert kept == [(8, None)]
            net.lss.switch_global(LssState.WAITING)
            assert await net.lss.identify_remote(0x360, 0x1234, (0, 5), (5, 10))
            assert not await net.lss.identify_remote(0x360, 0x1234, (0, 5), (100, 200))
            assert await net.lss.fastscan() is None  # every device here has a node-ID

    simulate(main())


def test_a_stray_answer_goes_to_the_listeners_and_duplicates_are_refused() -> None:
    async def main() -> None:
        async with AsyncNetwork() as net:
            seen: list[object] = []
            net.add_listener(seen.append)
            slaves_on(net, LssSlave(ME), LssSlave(ME))
            with pytest.raises(LssScanError, match="2 devices answer as"):
                await net.lss.fastscan()
            net.lss.switch_global(LssState.WAITING)  # (both were selected by the scan)
            net.lss.timeout = 0.01
            await net.lss.select(ME)  # both answer: one is the answer, one is stray
            await net.sleep(0.05)
            assert any(isinstance(e, LssStrayAnswer) for e in seen)

    simulate(main())


def test_the_blocking_network_has_the_same_lss() -> None:
    with Network(simulated=True) as net:
        slave = LssSlave(ME)
        net.run(attach(net.aio, slave))
        assert net.lss.fastscan(ceiling=0.1) == ME
        net.lss.configure_node_id(12)
        net.lss.switch_global(0)
        net.sleep(0.01)
        assert slave.active_node_id == 12


@pytest.mark.interop
def test_python_canopen_lss_master_finds_and_names_a_cobus_slave() -> None:
    canopen = pytest.importorskip("canopen")
    channel = f"interop-lss-{os.getpid()}"
    stored: list[tuple[int, int | None]] = []
    slave = LssSlave(ME, store=lambda n, b: stored.append((n, b)) or 0)
    events: list[Event] = []
    with Network(interface="virtual", channel=channel) as net:
        net.run(attach(net.aio, slave, events))
        cnet = canopen.Network()
        cnet.connect(interface="virtual", channel=channel)
        try:
            cnet.lss.RESPONSE_TIMEOUT = 0.05
            found, identity = cnet.lss.fast_scan()
            assert found and identity == list(ME.fields)
            cnet.lss.configure_node_id(12)
            cnet.lss.store_configuration()
            cnet.lss.send_switch_state_global(cnet.lss.WAITING_STATE)
            net.sleep(0.05)
            assert slave.active_node_id == 12 and stored == [(12, None)]
            assert NodeIdAssigned(12) in events
            cnet.lss.send_switch_state_selective(*ME.fields)
            assert cnet.lss.inquire_node_id() == 12
            assert cnet.lss.inquire_lss_address(0x5D) == ME.serial
        finally:
            cnet.disconnect()


class _LateOnce(LssSlave):
    """Answers the probe of the serial's bit 0 later than the scan waits (a slow moment)."""

    def on_frame(self, frame: Frame, now: float) -> Out:
        d = frame.data
        late = len(d) == 8 and d[0] == 0x51 and d[5] == 0 and d[6] == 3 and d[7] == 3
        self.answer_delay = 0.015 if late else 0.0
        return super().on_frame(frame, now)


def test_a_fastscan_misled_by_a_late_answer_is_caught_by_asking_the_slave() -> None:
    async def main() -> None:
        async with AsyncNetwork() as net:
            slave = _LateOnce(LssIdentity(1, 2, 3, 0x10))
            slaves_on(net, slave)
            with pytest.raises(LssScanError, match="answers came later than the wait"):
                await net.lss.fastscan(floor=0.01, ceiling=0.5)
            assert slave.state is LssState.WAITING  # nobody left selected
            found = await net.lss.fastscan(floor=0.05, ceiling=0.5)  # a longer wait: right
            assert found == LssIdentity(1, 2, 3, 0x10)

    simulate(main())


def test_slaves_of_different_speeds_set_the_window_by_the_slowest() -> None:
    async def main() -> None:
        async with AsyncNetwork() as net:
            quick = LssSlave(LssIdentity(1, 2, 3, 0x10), answer_delay=0.001)
            slow = LssSlave(LssIdentity(1, 2, 3, 0x11), answer_delay=0.03)
            slaves_on(net, quick, slow)
            assert await net.lss.fastscan() == quick.identity

    simulate(main())


def test_a_disconnect_or_a_failing_callback_never_leaves_lss_hanging() -> None:
    async def main() -> None:
        net = AsyncNetwork()
        await net.connect()
        slaves_on(net, LssSlave(ME))

        def failing(event: Event) -> None:
            raise RuntimeError("a bug in the caller's callback")

        assert await net.lss.fastscan(on_event=failing) == ME  # reported, not stuck
        scan = asyncio.ensure_future(net.lss.fastscan())
        await net.sleep(0.01)
        with pytest.raises(LssError, match="an LSS request is under way"):
            net.lss.switch_global(LssState.WAITING)  # would cut into the scan
        await scan
        task = asyncio.ensure_future(net.lss.configure_node_id(5))
        await net.sleep(0)
        await net.disconnect()
        with pytest.raises(NetworkClosedError, match="disconnected during an LSS request"):
            await task
        with pytest.raises(NetworkClosedError, match="not connected"):
            await net.lss.inquire("serial")

    simulate(main())


def test_the_trace_decoder_follows_what_net_lss_did() -> None:
    """The bus as a sniffer sees it: cobus's own decoder tells the scan's story."""
    from cobus.trace import Decoder, LssSession

    async def main() -> list[str]:
        async with AsyncNetwork() as net:
            frames: list[tuple[Frame, float]] = []
            net.subscribe_all(lambda f, now: frames.append((f, now)))
            slaves_on(net, LssSlave(ME, store=lambda n, b: 0))
            found = await net.lss.fastscan()
            assert found == ME
            await net.lss.configure_node_id(12)
            await net.lss.store()
            net.lss.switch_global(LssState.WAITING)
            await net.sleep(0.01)
        decoder = Decoder()
        records = [r for f, t in frames for r in decoder.feed(f, t)]
        return [r.sentence for r in records if isinstance(r, LssSession)]

    sentences = simulate(main())
    assert any(s.startswith("fastscan found") and "serial 0x0000002A" in s for s in sentences)
    assert any("got node-ID 12" in s for s in sentences), sentences
    assert any("stored its configuration" in s for s in sentences), sentences


def test_identify_all_finds_every_device_of_a_product_by_halving_ranges() -> None:
    """With or without a node-ID: what 'every device here is configured' leaves a user to
    find before set-id by identity."""
    mine = [
        LssIdentity(0x360, 0x1234, 0x0001_0000, 0x2A),
        LssIdentity(0x360, 0x1234, 0x0001_0000, 0xDEAD_BEEF),
        LssIdentity(0x360, 0x1234, 0x0002_0001, 0x07),
    ]
    other = LssIdentity(0x360, 0x9999, 0x0001_0000, 0x2B)

    async def main() -> None:
        async with AsyncNetwork() as net:
            slaves_on(net, LssSlave(mine[0], 5), LssSlave(mine[1]), LssSlave(mine[2], 9))
            slaves_on(net, LssSlave(other, 6))
            seen: list[LssIdentity] = []
            found = await net.lss.identify_all(0x360, 0x1234, on_found=seen.append)
            assert sorted(found, key=lambda i: i.serial) == sorted(mine, key=lambda i: i.serial)
            assert seen == found
            assert await net.lss.identify_all(0x360, 0x1234, 0x0002_0001) == [mine[2]]
            assert await net.lss.identify_all(0x360, 0x4321) == []

    simulate(main())


def test_identify_all_makes_no_phantom_device_of_a_late_answer() -> None:
    async def main() -> None:
        async with AsyncNetwork() as net:
            late = LssSlave(LssIdentity(0xC0B, 0x401, 0, 0x1003), answer_delay=0.03)
            slaves_on(net, LssSlave(LssIdentity(0xC0B, 0x401, 0, 0x1000)), late)
            found = await net.lss.identify_all(0xC0B, 0x401, 0)
            assert [i.serial for i in found] == [0x1000, 0x1003]

    simulate(main())
