import asyncio
from collections.abc import Mapping
from typing import ClassVar

import pytest

from cobus.runtime import AsyncNetwork, HandlerFailed
from cobus.sim import SimulatedDevice, UnknownFaultError, UnknownQuirkError
from tests.util import simulate


class Lamp(SimulatedDevice):
    kind = "lamp"
    QUIRKS: ClassVar[Mapping[str, str]] = {"flicker": "blinks when switched on"}
    FAULTS: ClassVar[Mapping[str, str]] = {"burn_out": "the bulb dies"}

    def __init__(self, network, node_id, **options):
        super().__init__(network, node_id, **options)
        self.ticks: list[float] = []

    def start(self):
        super().start()
        self.every(0.1, self.ticks.append)

    def inject(self, fault, **params):
        if fault == "burn_out":
            raise ZeroDivisionError("filament")
        super().inject(fault, **params)


def test_quirks_default_on_and_switch_off_by_name():
    async def main():
        async with AsyncNetwork() as net:
            assert Lamp(net, 3).quirks == {"flicker": True}
            assert Lamp(net, 3, quirks={"flicker": False}).quirks == {"flicker": False}
            with pytest.raises(UnknownQuirkError, match="quirks are: flicker"):
                Lamp(net, 3, quirks={"sparkle": True})

    simulate(main())


def test_ticks_follow_the_network_clock_and_stop_without_power():
    async def main():
        async with AsyncNetwork() as net:
            lamp = Lamp(net, 3)
            lamp.start()
            await net.sleep(0.35)
            lamp.inject("power_loss")
            await net.sleep(1)
            assert not lamp.powered
            lamp.inject("power_return")
            await net.sleep(0.25)
            return lamp.ticks, lamp.status()

    ticks, status = simulate(main())
    assert ticks == pytest.approx([0.1] * 5)
    assert status == {"node_id": 3, "kind": "lamp", "name": "lamp3", "powered": True}


def test_unknown_fault_lists_the_known_ones():
    async def main():
        async with AsyncNetwork() as net:
            with pytest.raises(UnknownFaultError, match="burn_out, power_loss, power_return"):
                Lamp(net, 3).inject("meltdown")

    simulate(main())


def test_a_failing_model_tick_is_reported_not_fatal():
    async def main():
        async with AsyncNetwork() as net:
            events = []
            net.add_listener(events.append)
            lamp = Lamp(net, 3)
            lamp.powered = True

            def bad(dt):
                raise RuntimeError("model bug")

            lamp.every(0.1, bad)
            await net.sleep(0.35)
            return events

    events = simulate(main())
    failures = [e for e in events if isinstance(e, HandlerFailed)]
    assert len(failures) == 3 and "model bug" in failures[0].error


def test_a_model_stops_with_its_network_instead_of_failing_on_it():
    """A model tick due while the network disconnects (a rig closed with a motor turning)
    neither runs on the closed network nor reports a failure; connected again, it goes on."""

    async def main():
        net = AsyncNetwork()
        await net.connect()
        events = []
        net.add_listener(events.append)
        lamp = Lamp(net, 3)
        lamp.start()

        def clocked(dt: float) -> None:
            net.time()  # raises NetworkClosedError once closed

        lamp.every(0.1, clocked)
        await net.sleep(0.25)
        await net.disconnect()
        await asyncio.sleep(0.5)  # the loop runs on: the timers fall due
        resting = len(lamp.ticks)
        await net.connect()  # connected again: the model goes on
        await net.sleep(0.25)
        await net.disconnect()
        return resting, lamp.ticks, events

    resting, ticks, events = simulate(main())
    assert resting == 2 and len(ticks) >= 4
    assert ticks == pytest.approx([0.1] * len(ticks))  # the rest is no step of the model
    assert not [e for e in events if isinstance(e, HandlerFailed)]
