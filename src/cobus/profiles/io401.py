"""A CiA 401 I/O module from the master side: digital inputs and outputs by name, polarity,
filters and filter masks, interrupt masks, analogue channels with scaling and interrupt
deltas, change callbacks::

    io = Io401(net.add_remote(9), inputs={"door": 1}, outputs={"lamp": 1},
               analog_inputs={"pot": AnalogChannel(1, scale=100 / 32767, unit="%")})
    io.set_output("lamp", True)
    print(io.read_input("door"), io.read_analog("pot"), "%")

Channels count from 1 (CiA 401): digital channel n is bit (n - 1) % 8 of sub-index
(n - 1) // 8 + 1 of 6000h (inputs) / 6200h (outputs); analogue channel n is sub-index n of
6401h / 6411h. Inputs come from a TPDO where one maps them (``node.tpdo.read()`` on a bare
node, the network file on a managed one) and it came after this object's last write, by SDO
otherwise; outputs go through the master's
process image where an RPDO maps them, by SDO otherwise. Each output byte is written whole:
the other bits stay as last read or set.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from cobus.errors import CobusError
from cobus.od import DataType, decode, encode
from cobus.profiles._port import DrivePort, port_for
from cobus.runtime._service import Callbacks
from cobus.runtime.twin import BlockingTwin

__all__ = ["AnalogChannel", "AsyncIo401", "Io401", "IoChange", "IoError"]

_D = DataType
_TYPES: dict[int, DataType] = {
    0x6000: _D.UNSIGNED8,
    0x6002: _D.UNSIGNED8,
    0x6003: _D.UNSIGNED8,
    0x6005: _D.BOOLEAN,
    0x6006: _D.UNSIGNED8,
    0x6007: _D.UNSIGNED8,
    0x6008: _D.UNSIGNED8,
    0x6200: _D.UNSIGNED8,
    0x6202: _D.UNSIGNED8,
    0x6206: _D.UNSIGNED8,
    0x6207: _D.UNSIGNED8,
    0x6208: _D.UNSIGNED8,
    0x6401: _D.INTEGER16,
    0x6411: _D.INTEGER16,
    0x6423: _D.BOOLEAN,
    0x6426: _D.UNSIGNED32,
}


class IoError(CobusError, ValueError):
    """A channel name or number the module does not have, or a value it cannot take."""


@dataclass(frozen=True)
class AnalogChannel:
    """An analogue channel (1..254) and its scaling: engineering value = raw x ``scale`` +
    ``offset``, in ``unit``."""

    channel: int
    scale: float = 1.0
    offset: float = 0.0
    unit: str = ""


@dataclass(frozen=True)
class IoChange:
    """A named input changed (as a TPDO brought it): ``value`` is a bool for a digital
    input, the scaled value for an analogue one."""

    name: str
    value: Any
    time: float

    def __str__(self) -> str:
        return f"{self.name} = {self.value}"


def _channel(what: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= 254 * 8:
        raise IoError(f"{what}: channel {value!r} must be an integer from 1")
    return value


class AsyncIo401:
    """A CiA 401 module on ``node`` (a :class:`~cobus.runtime.remote.AsyncRemoteNode` or a node the
    master manages); see the module docstring. ``inputs`` / ``outputs`` name digital
    channels, ``analog_inputs`` / ``analog_outputs`` name analogue ones (a channel number,
    or an :class:`AnalogChannel` with its scaling)."""

    #: The node-ID of the module.
    node_id: int

    def __init__(
        self,
        node: Any,
        *,
        inputs: Mapping[str, int] | None = None,
        outputs: Mapping[str, int] | None = None,
        analog_inputs: Mapping[str, int | AnalogChannel] | None = None,
        analog_outputs: Mapping[str, int | AnalogChannel] | None = None,
    ) -> None:
        # the channels are checked before the port listens to anything
        self._inputs = {n: _channel(n, c) for n, c in (inputs or {}).items()}
        self._outputs = {n: _channel(n, c) for n, c in (outputs or {}).items()}
        self._ain = {n: self._analog(n, c) for n, c in (analog_inputs or {}).items()}
        self._aout = {n: self._analog(n, c) for n, c in (analog_outputs or {}).items()}
        self._port: DrivePort = port_for(node)
        self.node_id = self._port.node_id
        self._out_bytes: dict[int, int] = {}
        self._written_at = -math.inf
        self._last: dict[str, Any] = {}
        self._callbacks: Callbacks[IoChange] = Callbacks(
            self._port.network, f"I/O module {self.node_id}"
        )
        self._port.add_input_callback(self._on_input)

    def __repr__(self) -> str:
        return f"<Io401 node {self.node_id}>"

    @staticmethod
    def _analog(name: str, spec: int | AnalogChannel) -> AnalogChannel:
        channel = spec if isinstance(spec, AnalogChannel) else AnalogChannel(spec)
        _channel(name, channel.channel)
        if channel.channel > 254:
            raise IoError(f"{name}: analogue channel {channel.channel} must be 1..254")
        if not channel.scale or not math.isfinite(channel.scale):
            raise IoError(f"{name}: scale {channel.scale!r} must be a finite number, not 0")
        return channel

    # ------------------------------------------------------------------ lookups
    def _digital(self, table: dict[str, int], key: str | int, what: str) -> int:
        if isinstance(key, str):
            channel = table.get(key)
            if channel is None:
                names = ", ".join(table) or "none named"
                raise IoError(f"I/O module {self.node_id} has no {what} {key!r} ({names})")
            return channel
        return _channel(what, key)

    def _analog_of(self, table: dict[str, AnalogChannel], key: str | int) -> AnalogChannel:
        if isinstance(key, str):
            channel = table.get(key)
            if channel is None:
                names = ", ".join(table) or "none named"
                raise IoError(f"I/O module {self.node_id} has no analogue {key!r} ({names})")
            return channel
        return self._analog(str(key), key)

    async def _read(self, index: int, subindex: int) -> Any:
        got = self._port.input(index, subindex)
        if got is not None and got[1] > self._written_at:  # (a polarity write changes it)
            return got[0]
        dt = _TYPES[index]
        data = await self._port.upload(index, subindex)
        return decode(dt, data[: dt.size or len(data)])

    async def _write(self, index: int, subindex: int, value: Any) -> None:
        await self._port.download(index, subindex, encode(_TYPES[index], value))
        self._written_at = self._port.network.time()

    # ------------------------------------------------------------------ digital
    async def read_input(self, key: str | int) -> bool:
        """A digital input (after the module's polarity 6002h)."""
        channel = self._digital(self._inputs, key, "input")
        byte = int(await self._read(0x6000, (channel - 1) // 8 + 1))
        return bool(byte >> (channel - 1) % 8 & 1)

    async def read_inputs(self) -> dict[str, bool]:
        """Every named digital input."""
        return {name: await self.read_input(name) for name in self._inputs}

    async def set_output(self, key: str | int, on: bool) -> None:
        """Switch a digital output (before the module's polarity 6202h)."""
        if not isinstance(on, bool):
            raise IoError(f"output value {on!r}: True or False")
        channel = self._digital(self._outputs, key, "output")
        sub = (channel - 1) // 8 + 1
        if sub not in self._out_bytes:
            dt = _TYPES[0x6200]
            data = await self._port.upload(0x6200, sub)
            self._out_bytes[sub] = int(decode(dt, data[:1]))
        bit = 1 << (channel - 1) % 8
        byte = self._out_bytes[sub] | bit if on else self._out_bytes[sub] & ~bit
        self._out_bytes[sub] = byte
        if not self._port.set_outputs({(0x6200, sub): byte}):
            await self._write(0x6200, sub, byte)  # acknowledged, in any NMT state

    async def set_outputs(self, values: Mapping[str | int, bool]) -> None:
        """Switch several digital outputs."""
        for key, on in values.items():
            await self.set_output(key, on)

    async def set_polarity(self, key: str | int, inverted: bool, *, output: bool = False) -> None:
        """Invert a digital input (6002h) or, with ``output``, an output (6202h)."""
        table, index = (self._outputs, 0x6202) if output else (self._inputs, 0x6002)
        channel = self._digital(table, key, "output" if output else "input")
        sub = (channel - 1) // 8 + 1
        byte = int(await self._read(index, sub))
        bit = 1 << (channel - 1) % 8
        await self._write(index, sub, byte | bit if inverted else byte & ~bit)

    async def set_filter(self, key: str | int, on: bool, *, output: bool = False) -> None:
        """An input's filter (6003h "filter constant": the module debounces it) or, with
        ``output``, an output's filter mask bit (6208h: off, writes leave the output as it
        is)."""
        table, index = (self._outputs, 0x6208) if output else (self._inputs, 0x6003)
        channel = self._digital(table, key, "output" if output else "input")
        sub = (channel - 1) // 8 + 1
        byte = int(await self._read(index, sub))
        bit = 1 << (channel - 1) % 8
        await self._write(index, sub, byte | bit if on else byte & ~bit)

    async def set_interrupt(
        self,
        key: str | int,
        *,
        any_change: bool = True,
        rising: bool = False,
        falling: bool = False,
    ) -> None:
        """Which changes of a digital input make the module send its TPDO: any change
        (6006h), low-to-high (6007h), high-to-low (6008h)."""
        channel = self._digital(self._inputs, key, "input")
        sub = (channel - 1) // 8 + 1
        bit = 1 << (channel - 1) % 8
        for index, on in ((0x6006, any_change), (0x6007, rising), (0x6008, falling)):
            byte = int(await self._read(index, sub))
            await self._write(index, sub, byte | bit if on else byte & ~bit)

    async def enable_interrupts(self, digital: bool = True, analog: bool = True) -> None:
        """The global interrupt enables: digital 6005h, analogue 6423h."""
        await self._write(0x6005, 0, digital)
        await self._write(0x6423, 0, analog)

    # ------------------------------------------------------------------ analogue
    async def read_analog(self, key: str | int) -> float:
        """An analogue input, scaled (raw 6401h x scale + offset)."""
        channel = self._analog_of(self._ain, key)
        raw = int(await self._read(0x6401, channel.channel))
        return raw * channel.scale + channel.offset

    async def set_analog(self, key: str | int, value: float) -> None:
        """Set an analogue output given in its engineering unit (6411h, rounded to raw)."""
        channel = self._analog_of(self._aout, key)
        raw = round((value - channel.offset) / channel.scale)
        if not -32768 <= raw <= 32767:
            raise IoError(f"{key}: {value} {channel.unit} is raw {raw}, outside INTEGER16")
        if not self._port.set_outputs({(0x6411, channel.channel): raw}):
            await self._write(0x6411, channel.channel, raw)

    async def set_delta(self, key: str | int, delta: float) -> None:
        """The change of an analogue input (in its unit) that makes the module send it
        (6426h)."""
        channel = self._analog_of(self._ain, key)
        raw = round(abs(delta / channel.scale))
        await self._write(0x6426, channel.channel, raw)

    # ------------------------------------------------------------------ changes
    def add_callback(self, callback: Callable[[IoChange], object]) -> None:
        """Call ``callback(change)`` when a TPDO brings a named input with a new value."""
        self._callbacks.add(callback)

    def remove_callback(self, callback: Callable[[IoChange], object]) -> None:
        """Stop calling ``callback``."""
        self._callbacks.remove(callback)

    def _on_input(self, number: int, now: float) -> None:
        for name, channel in self._inputs.items():
            got = self._port.input(0x6000, (channel - 1) // 8 + 1)
            if got is not None and got[1] == now:
                self._changed(name, bool(int(got[0]) >> (channel - 1) % 8 & 1), now)
        for name, analog in self._ain.items():
            got = self._port.input(0x6401, analog.channel)
            if got is not None and got[1] == now:
                self._changed(name, int(got[0]) * analog.scale + analog.offset, now)

    def _changed(self, name: str, value: Any, now: float) -> None:
        if name not in self._last or self._last[name] != value:
            self._last[name] = value
            self._callbacks(IoChange(name, value, now))

    def close(self) -> None:
        """Stop listening to the module."""
        self._port.remove_input_callback(self._on_input)
        self._port.close()


class Io401(BlockingTwin, twin_of=AsyncIo401):
    """A CiA 401 module for blocking code: ``Io401(net.add_remote(9), inputs={...})`` or
    ``Io401(master, "io", ...)`` on a node a blocking master manages."""

    def __init__(self, node: Any, name: Any = None, **options: Any) -> None:
        if isinstance(node, AsyncIo401):  # a twin made for an async module
            super().__init__(node, name)
            return
        runner = getattr(node, "_runner", None)
        if runner is None:
            raise TypeError("Io401 takes a node of a blocking Network; use AsyncIo401")
        target = node.aio
        if name is not None:
            if not callable(getattr(target, "node", None)):
                raise TypeError("Io401(master, name): the name is for a master's node")
            target = runner.call(target.node, name)
        aio = runner.call(lambda: AsyncIo401(target, **options))
        super().__init__(aio, runner)
