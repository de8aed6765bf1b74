import asyncio

import pytest

from cobus.runtime.loop import SimulatedEventLoop, SimulationStalledError


def run(coro):
    loop = SimulatedEventLoop()
    try:
        return loop.run_until_complete(coro), loop
    finally:
        loop.close()


def test_sleep_jumps_the_clock_without_waiting():
    async def main():
        loop = asyncio.get_running_loop()
        t0 = loop.time()
        await asyncio.sleep(3600)
        return loop.time() - t0

    elapsed, _ = run(main())  # (had it waited an hour, the suite's timeout would say so)
    assert elapsed == pytest.approx(3600)


def test_timers_fire_in_order_and_at_their_virtual_time():
    seen: list[tuple[str, float]] = []

    async def main():
        loop = asyncio.get_running_loop()
        loop.call_later(0.3, lambda: seen.append(("c", loop.time())))
        loop.call_later(0.1, lambda: seen.append(("a", loop.time())))
        loop.call_later(0.2, lambda: seen.append(("b", loop.time())))
        await asyncio.sleep(1)

    run(main())
    assert [name for name, _ in seen] == ["a", "b", "c"]
    assert [t for _, t in seen] == pytest.approx([0.1, 0.2, 0.3])


def test_wait_for_times_out_on_virtual_time():
    async def main():
        fut = asyncio.get_running_loop().create_future()
        with pytest.raises(TimeoutError):
            await asyncio.wait_for(fut, 5.0)
        return asyncio.get_running_loop().time()

    now, _ = run(main())
    assert now == pytest.approx(5.0)


def test_a_wait_that_can_never_end_is_reported():
    async def main():
        await asyncio.get_running_loop().create_future()

    with pytest.raises(SimulationStalledError, match="can never finish"):
        run(main())


def test_poll_hook_input_is_handled_before_the_clock_moves():
    pending = [1, 2]
    got: list[tuple[int, float]] = []

    async def main():
        loop = asyncio.get_running_loop()
        assert isinstance(loop, SimulatedEventLoop)

        def hook() -> bool:
            if not pending:
                return False
            item = pending.pop(0)
            loop.call_soon(lambda: got.append((item, loop.time())))
            return True

        loop.add_poll_hook(hook)
        await asyncio.sleep(10)
        loop.remove_poll_hook(hook)

    run(main())
    assert got == [(1, 0.0), (2, 0.0)]


def test_thread_safe_calls_still_work():
    async def main():
        loop = asyncio.get_running_loop()
        fut = loop.create_future()
        loop.call_soon_threadsafe(fut.set_result, 42)
        return await fut

    value, _ = run(main())
    assert value == 42
