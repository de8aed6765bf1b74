"""Several CiA 402 drives commanded together: ``await Axes([x, y]).enable()`` takes every
axis through the state machine in lockstep — each command goes to all axes back to back
(through the master's process image they leave in the same RPDO cycle, and with synchronous
RPDOs take effect on the same SYNC) — and ``quick_stop()`` stops them all at once.
"""

from __future__ import annotations

import asyncio
import functools
from collections.abc import Sequence
from typing import Any

from cobus.profiles.cia402 import Command, PowerState, command_towards
from cobus.profiles.drive402 import AsyncDrive402, Drive402, DriveStateError, _left
from cobus.runtime.twin import BlockingTwin

__all__ = ["AsyncAxes", "Axes"]


class AsyncAxes:
    """A group of :class:`~cobus.profiles.drive402.AsyncDrive402` commanded together."""

    def __init__(self, drives: Sequence[AsyncDrive402]) -> None:
        drives = [getattr(d, "aio", d) for d in drives]
        if not drives or not all(isinstance(d, AsyncDrive402) for d in drives):
            raise TypeError("Axes takes a list of drives (Drive402 / AsyncDrive402)")
        ids = [d.node_id for d in drives]
        if len(set(ids)) != len(ids):
            raise ValueError(f"a drive is in the group twice: node-IDs {ids}")
        self.drives = list(drives)

    def __repr__(self) -> str:
        return f"<Axes {[d.node_id for d in self.drives]}>"

    async def _statuses(self) -> list[PowerState]:
        return [s.state for s in await asyncio.gather(*(d.read_statusword() for d in self.drives))]

    async def set_state(self, target: PowerState, timeout: float | None = None) -> None:
        """Take every axis to ``target`` one transition at a time, all axes together: a
        step's commands go out back to back, then each axis is waited for. A faulted axis
        raises its :class:`~cobus.profiles.drive402.DriveFault` before anything is sent."""
        for _step in range(8):
            states = await self._statuses()
            if all(state is target for state in states):
                return
            for drive, state in zip(self.drives, states, strict=True):
                if state in (PowerState.FAULT, PowerState.FAULT_REACTION_ACTIVE):
                    raise await drive._fault(f"going to {target.name} with the other axes")
            moves = [
                (drive, state, command_towards(state, target))
                for drive, state in zip(self.drives, states, strict=True)
                if state is not target
            ]
            await asyncio.gather(
                *(d._send_cw((d._cw & ~Command.mask()) | c) for d, _s, c in moves if c is not None)
            )
            await asyncio.gather(
                *(
                    d._wait(
                        functools.partial(_left, s),
                        d.timeout if timeout is None else timeout,
                        f"{s.name} -> {target.name} with the other axes",
                    )
                    for d, s, _c in moves
                )
            )
        raise DriveStateError(f"axes {self!r} did not settle in {target.name}")

    async def enable(self, timeout: float | None = None) -> None:
        """Enable every axis, in lockstep."""
        await self.set_state(PowerState.OPERATION_ENABLED, timeout)

    async def disable(self, timeout: float | None = None) -> None:
        """Switch every axis off (SWITCH_ON_DISABLED), in lockstep."""
        await self.set_state(PowerState.SWITCH_ON_DISABLED, timeout)

    async def quick_stop(self, timeout: float | None = None) -> None:
        """Quick stop on every axis at once (the commands back to back), then wait until
        each stands."""
        await asyncio.gather(
            *(d._send_cw((d._cw & ~Command.mask()) | Command.QUICK_STOP) for d in self.drives)
        )
        await asyncio.gather(
            *(
                d._wait(
                    lambda s: (
                        s.state is PowerState.SWITCH_ON_DISABLED
                        or (s.state is PowerState.QUICK_STOP_ACTIVE and s.target_reached)
                    ),
                    d.timeout if timeout is None else timeout,
                    "quick stop with the other axes",
                )
                for d in self.drives
            )
        )


class Axes(BlockingTwin, twin_of=AsyncAxes):
    """A group of :class:`~cobus.profiles.drive402.Drive402` for blocking code:
    ``Axes([x, y]).enable()``."""

    def __init__(self, drives: Any, runner: Any = None) -> None:
        if isinstance(drives, AsyncAxes):
            super().__init__(drives, runner)
            return
        drives = list(drives)
        if not drives or not all(isinstance(d, Drive402) for d in drives):
            raise TypeError("Axes takes a list of Drive402 (AsyncAxes for AsyncDrive402)")
        runner = drives[0]._runner
        aio = runner.call(lambda: AsyncAxes([d.aio for d in drives]))
        super().__init__(aio, runner)
