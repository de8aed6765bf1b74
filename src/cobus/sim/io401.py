"""A CiA 401 I/O module (kind ``cia401_io``): digital and analogue inputs and outputs.

Objects (CiA 401): 6000h digital inputs (bytes, with the polarity 6002h), the interrupt
objects 6005h (global enable), 6006h (any change), 6007h (low-to-high), 6008h (high-to-low);
6200h digital outputs with polarity 6202h, filter mask 6208h (a write changes only the bits
whose mask bit is 1), error mode 6206h and error value 6207h; 6003h the input filter constant
(kept, not modelled: the simulated inputs do not bounce); 6401h
analogue inputs with the global interrupt enable 6423h and the delta 6426h; 6411h analogue
outputs with error mode 6443h and error value 6444h.

Default PDOs: TPDO1 the digital input bytes and TPDO2 the analogue inputs 1-4 (both
event-driven, type 255), RPDO1 the digital output bytes and RPDO2 the analogue outputs 1-4.
A TPDO that maps an input goes out when the input changes and the interrupt objects let the
change through (digital: 6005h and the masks; analogue: 6423h and a change of at least 6426h
since the value last sent); acyclic synchronous TPDOs (type 0) go out at the next SYNC
instead.

The physical side: :meth:`SimulatedIo401.set_digital_input` and
:meth:`SimulatedIo401.set_analog_input` (tests, an operator panel; call them on the network's
loop), :meth:`SimulatedIo401.digital_output` and :meth:`SimulatedIo401.analog_output` read what
the outputs drive. Channels count from 1: digital
channel 1 is bit 0 of 6000h sub 1, channel 9 bit 0 of sub 2; analogue channel n is sub n.
On a communication error (NMT stopped, heartbeat or life guarding lost) the outputs whose
error mode bit is set take their error value until the master writes the outputs again.

A **speed potentiometer** (option ``potentiometer``: a channel, or ``{channel, position}``)
is an analogue input whose knob position 0..1 gives 0..32767
(:meth:`SimulatedIo401.set_potentiometer`), as the thesis rig's speed set-point input.
"""

from __future__ import annotations

import contextlib
from collections.abc import Mapping
from functools import partial
from typing import Any

from cobus._moved import renamed_names
from cobus.device import (
    Device,
    DeviceConfigError,
    DeviceEvent,
    DictionaryBuilder,
    EntryWritten,
    HeartbeatLost,
    LifeGuardingLost,
    RpdoReceived,
    StateChanged,
)
from cobus.device.events import Booted
from cobus.od import DataType, ObjectDictionary
from cobus.proto.nmt import NmtState
from cobus.runtime.network import AsyncNetwork
from cobus.sim.base import SimulationError
from cobus.sim.generic import CanopenSimDevice

__all__ = ["ChannelError", "SimulatedIo401"]

_DEVICE_TYPE_401 = 0x0191
_I16_MAX = 0x7FFF
_I16_MIN = -0x8000


class ChannelError(SimulationError, ValueError):
    """An input or output channel that the module does not have, or a value it cannot hold."""


def _count(value: Any, what: str, high: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= high:
        raise SimulationError(f"cia401_io: {what} {value!r} must be a count from 0 to {high}")
    return value


class SimulatedIo401(CanopenSimDevice):
    """A CiA 401 I/O module (see the module docstring).

    Options: ``digital_inputs`` / ``digital_outputs`` (channels, default 16 / 8),
    ``analog_inputs`` / ``analog_outputs`` (default 4 / 2), ``potentiometer`` (see the
    module docstring), and those of
    :class:`~cobus.sim.generic.CanopenSimDevice`.
    """

    kind = "cia401_io"

    def __init__(
        self,
        network: AsyncNetwork,
        node_id: int,
        *,
        digital_inputs: int = 16,
        digital_outputs: int = 8,
        analog_inputs: int = 4,
        analog_outputs: int = 2,
        potentiometer: int | Mapping[str, Any] | None = None,
        **options: Any,
    ) -> None:
        self.digital_inputs = _count(digital_inputs, "digital_inputs", 8 * 254)
        self.digital_outputs = _count(digital_outputs, "digital_outputs", 8 * 254)
        self.analog_inputs = _count(analog_inputs, "analog_inputs", 254)
        self.analog_outputs = _count(analog_outputs, "analog_outputs", 254)
        self._in_bytes = (self.digital_inputs + 7) // 8
        self._out_bytes = (self.digital_outputs + 7) // 8
        # the physical world: survives power cycles
        self._din = [0] * self._in_bytes
        self._ain = [0] * self.analog_inputs
        self._ai_sent = [0] * self.analog_inputs
        self._error_state = False
        #: the output bytes in effect: a write of 6200h changes only the bits its filter
        #: mask 6208h lets through
        self._dout = [0] * self._out_bytes
        self.pot_channel: int | None = None
        super().__init__(network, node_id, **options)
        if potentiometer is None:
            return
        if isinstance(potentiometer, Mapping):
            unknown = set(potentiometer) - {"channel", "position"}
            if unknown:
                raise SimulationError(
                    f"{self.name}: potentiometer takes channel and position, not "
                    f"{', '.join(sorted(unknown))}"
                )
            channel = potentiometer.get("channel", 1)
            position = potentiometer.get("position", 0.0)
        else:
            channel, position = potentiometer, 0.0
        self._check_analog_in(channel)
        self.pot_channel = channel
        self.set_potentiometer(position)

    # ------------------------------------------------------------------ dictionary
    def build_od(self) -> ObjectDictionary:
        kinds = (
            (0x01 if self.digital_inputs else 0)
            | (0x02 if self.digital_outputs else 0)
            | (0x04 if self.analog_inputs else 0)
            | (0x08 if self.analog_outputs else 0)
        )
        b = DictionaryBuilder(
            device_type=kinds << 16 | _DEVICE_TYPE_401,
            device_name="cobus I/O module",
            vendor_id=0x00C0B005,
            product_code=401,
            revision=1,
            hardware_version="sim",
            software_version="1.0",
        )
        U8, I16 = DataType.UNSIGNED8, DataType.INTEGER16
        if self._in_bytes:
            n = self._in_bytes
            b.array(0x6000, "Read input 8-bit", U8, n, access="ro", mappable=True, default=0)
            b.array(0x6002, "Polarity input 8-bit", U8, n, default=0)
            b.array(0x6003, "Filter constant input 8-bit", U8, n, default=0)
            b.variable(
                0x6005, "Global interrupt enable digital 8-bit", DataType.BOOLEAN, default=True
            )
            b.array(0x6006, "Interrupt mask any change 8-bit", U8, n, default=0xFF)
            b.array(0x6007, "Interrupt mask low-to-high 8-bit", U8, n, default=0)
            b.array(0x6008, "Interrupt mask high-to-low 8-bit", U8, n, default=0)
            b.tpdo(1, [(0x6000, s) for s in range(1, min(n, 8) + 1)], transmission_type=255)
        if self._out_bytes:
            n = self._out_bytes
            b.array(0x6200, "Write output 8-bit", U8, n, access="rww", mappable=True, default=0)
            b.array(0x6202, "Change polarity output 8-bit", U8, n, default=0)
            b.array(0x6206, "Error mode output 8-bit", U8, n, default=0xFF)
            b.array(0x6207, "Error value output 8-bit", U8, n, default=0)
            b.array(0x6208, "Filter mask output 8-bit", U8, n, default=0xFF)
            b.rpdo(1, [(0x6200, s) for s in range(1, min(n, 8) + 1)], transmission_type=255)
        if self.analog_inputs:
            n = self.analog_inputs
            b.array(0x6401, "Read analogue input 16-bit", I16, n, access="ro", mappable=True)
            b.variable(
                0x6423, "Analogue input global interrupt enable", DataType.BOOLEAN, default=False
            )
            b.array(0x6426, "Analogue input interrupt delta", DataType.UNSIGNED32, n, default=0)
            b.tpdo(2, [(0x6401, s) for s in range(1, min(n, 4) + 1)], transmission_type=255)
        if self.analog_outputs:
            n = self.analog_outputs
            b.array(0x6411, "Write analogue output 16-bit", I16, n, access="rww", mappable=True)
            b.array(0x6443, "Analogue output error mode", U8, n, default=1)
            b.array(0x6444, "Analogue output error value", DataType.INTEGER32, n, default=0)
            b.rpdo(2, [(0x6411, s) for s in range(1, min(n, 4) + 1)], transmission_type=255)
        return b.build()

    def bind(self, device: Device) -> None:
        for sub in range(1, self._in_bytes + 1):
            device.on_read(0x6000, sub, partial(self._din_logical, sub))
        for sub in range(1, self.analog_inputs + 1):
            device.on_read(0x6401, sub, partial(self.analog_input, sub))

    def on_power_on(self) -> None:
        self._error_state = False
        self._dout = [0] * self._out_bytes
        self._ai_sent = list(self._ain)

    def on_event(self, event: DeviceEvent) -> None:
        stopped = isinstance(event, StateChanged) and event.new is NmtState.STOPPED
        if stopped or isinstance(event, HeartbeatLost | LifeGuardingLost):
            self._error_state = True
        elif isinstance(event, Booted):
            self._error_state = False
        elif isinstance(event, RpdoReceived):
            if any(index in (0x6200, 0x6411) for index, _ in event.entries):
                self._error_state = False
            for (index, sub), value in zip(event.entries, event.values, strict=True):
                if index == 0x6200:
                    self._output_written(sub, int(value))
        elif isinstance(event, EntryWritten) and event.index in (0x6200, 0x6411):
            self._error_state = False
            if event.index == 0x6200:
                self._output_written(event.subindex, int(event.value))

    def _output_written(self, sub: int, value: int) -> None:
        if not 1 <= sub <= self._out_bytes:
            return
        mask = int(self._get(0x6208, sub, 0xFF))
        self._dout[sub - 1] = (value & mask | self._dout[sub - 1] & ~mask) & 0xFF

    # ------------------------------------------------------------------ inputs
    def _din_logical(self, sub: int) -> int:
        polarity = int(self._get(0x6002, sub, 0))
        return (self._din[sub - 1] ^ polarity) & 0xFF

    def _get(self, index: int, sub: int, default: Any) -> Any:
        device = self._device
        if device is None:
            return default
        return device.get(index, sub)

    def _check_digital_in(self, channel: int) -> None:
        if isinstance(channel, bool) or not isinstance(channel, int):
            raise ChannelError(f"digital input channel {channel!r} is not a number")
        if not 1 <= channel <= self.digital_inputs:
            raise ChannelError(
                f"{self.name} has digital inputs 1..{self.digital_inputs}, not {channel}"
            )

    def _check_analog_in(self, channel: int) -> None:
        if isinstance(channel, bool) or not isinstance(channel, int):
            raise ChannelError(f"analogue input channel {channel!r} is not a number")
        if not 1 <= channel <= self.analog_inputs:
            raise ChannelError(
                f"{self.name} has analogue inputs 1..{self.analog_inputs}, not {channel}"
            )

    def digital_input(self, channel: int) -> bool:
        """The level at the digital input terminal ``channel`` (before the polarity 6002h)."""
        self._check_digital_in(channel)
        byte, bit = divmod(channel - 1, 8)
        return bool(self._din[byte] >> bit & 1)

    def set_digital_input(self, channel: int, value: bool) -> None:
        """Drive the digital input terminal ``channel`` high or low."""
        self._check_digital_in(channel)
        byte, bit = divmod(channel - 1, 8)
        sub = byte + 1
        before = self._din_logical(sub) if self.running else 0
        if value:
            self._din[byte] |= 1 << bit
        else:
            self._din[byte] &= ~(1 << bit) & 0xFF
        if not self.running:
            return
        after = self._din_logical(sub)
        changed = before ^ after
        if not changed or not self._get(0x6005, 0, False):
            return
        rising, falling = changed & after, changed & before
        hit = (
            changed & self._get(0x6006, sub, 0)
            | rising & self._get(0x6007, sub, 0)
            | falling & self._get(0x6008, sub, 0)
        )
        if hit:
            self._send_tpdos_of(0x6000, sub)

    def set_digital_inputs(self, values: Mapping[int, bool]) -> None:
        """Drive several digital inputs (channel -> level)."""
        for channel, value in values.items():
            self.set_digital_input(channel, value)

    def analog_input(self, channel: int) -> int:
        """The raw value of analog input ``channel`` (1-based)."""
        self._check_analog_in(channel)
        return self._ain[channel - 1]

    def set_analog_input(self, channel: int, value: int) -> None:
        """Put ``value`` (INTEGER16 counts) on the analogue input ``channel``."""
        self._check_analog_in(channel)
        if isinstance(value, bool) or not isinstance(value, int):
            raise ChannelError(f"analogue input value {value!r} is not an integer (counts)")
        if not _I16_MIN <= value <= _I16_MAX:
            raise ChannelError(
                f"analogue input value {value} does not fit INTEGER16 ({_I16_MIN}..{_I16_MAX})"
            )
        self._ain[channel - 1] = value
        if not self.running or not self._get(0x6423, 0, False):
            return
        delta = self._get(0x6426, channel, 0)
        if value != self._ai_sent[channel - 1] and abs(value - self._ai_sent[channel - 1]) >= delta:
            self._ai_sent[channel - 1] = value
            self._send_tpdos_of(0x6401, channel)

    @property
    def potentiometer(self) -> float | None:
        """The knob position 0..1 of the speed potentiometer (None: the module has none)."""
        if self.pot_channel is None:
            return None
        return self._ain[self.pot_channel - 1] / _I16_MAX

    def set_potentiometer(self, position: float) -> None:
        """Turn the speed potentiometer to ``position`` (0 = stop .. 1 = full scale)."""
        if self.pot_channel is None:
            raise ChannelError(
                f"{self.name} has no potentiometer: give the option potentiometer: CHANNEL"
            )
        if isinstance(position, bool) or not isinstance(position, int | float):
            raise ChannelError(f"potentiometer position {position!r} is not a number")
        if not 0 <= position <= 1:
            raise ChannelError(f"potentiometer position {position} is outside 0..1")
        self.set_analog_input(self.pot_channel, round(position * _I16_MAX))

    def _send_tpdos_of(self, index: int, sub: int) -> None:
        """Trigger every TPDO that maps ``index:sub`` (as the interrupt of CiA 401 does)."""
        device = self._device
        if device is None:
            return
        for number in range(1, 513):
            mapping = 0x1A00 + number - 1
            if mapping not in device.od:
                if number > 4:
                    break
                continue
            count = device.get(mapping, 0)
            for entry_sub in range(1, count + 1):
                value = device.get(mapping, entry_sub)
                if value >> 16 == index and (value >> 8) & 0xFF == sub:
                    with contextlib.suppress(DeviceConfigError):  # not valid: nothing to send
                        device.send_tpdo(number)
                    break

    # ------------------------------------------------------------------ outputs
    def digital_output(self, channel: int) -> bool:
        """Whether the digital output terminal ``channel`` is driven (off without power)."""
        if isinstance(channel, bool) or not isinstance(channel, int):
            raise ChannelError(f"digital output channel {channel!r} is not a number")
        if not 1 <= channel <= self.digital_outputs:
            raise ChannelError(
                f"{self.name} has digital outputs 1..{self.digital_outputs}, not {channel}"
            )
        device = self._device
        if device is None:
            return False
        byte, bit = divmod(channel - 1, 8)
        sub = byte + 1
        level = (self._dout[byte] ^ device.get(0x6202, sub)) >> bit & 1
        if self._error_state and device.get(0x6206, sub) >> bit & 1:
            level = device.get(0x6207, sub) >> bit & 1
        return bool(level)

    def analog_output(self, channel: int) -> int:
        """The value the analogue output ``channel`` drives (0 without power)."""
        if isinstance(channel, bool) or not isinstance(channel, int):
            raise ChannelError(f"analogue output channel {channel!r} is not a number")
        if not 1 <= channel <= self.analog_outputs:
            raise ChannelError(
                f"{self.name} has analogue outputs 1..{self.analog_outputs}, not {channel}"
            )
        device = self._device
        if device is None:
            return 0
        if self._error_state and device.get(0x6443, channel):
            return int(device.get(0x6444, channel))
        return int(device.get(0x6411, channel))

    @property
    def in_error_state(self) -> bool:
        """The outputs show their error values (communication error since the last write)."""
        return self._error_state

    # ------------------------------------------------------------------ panel
    def status(self) -> dict[str, Any]:
        out = super().status()
        out["inputs"] = "".join(
            "1" if self._din[(c - 1) // 8] >> ((c - 1) % 8) & 1 else "0"
            for c in range(1, self.digital_inputs + 1)
        )
        out["outputs"] = "".join(
            "1" if self.digital_output(c) else "0" for c in range(1, self.digital_outputs + 1)
        )
        out["analog_in"] = list(self._ain)
        out["analog_out"] = [self.analog_output(c) for c in range(1, self.analog_outputs + 1)]
        if self.pot_channel is not None:
            out["potentiometer"] = round(self.potentiometer or 0.0, 3)
        return out


#: One name per idea: :class:`cobus.profiles.io401.Io401` drives a real one.
__getattr__ = renamed_names(__name__, {"Io401": ("SimulatedIo401", SimulatedIo401)})
