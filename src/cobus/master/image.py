"""The process image: named, scaled signals carried by the nodes' PDOs.

Inputs come from the nodes' TPDOs, outputs go to their RPDOs. A signal is named
``"<node>.<signal>"``: the signal is the alias the network file gives, or the object's
EDS name in lookup form (``position_actual_value``; ``record.sub`` for sub-objects). An
aliased signal is found under both names. Values are engineering values:
``raw * scale + offset`` when the network file scales the signal.
"""

from __future__ import annotations

import difflib
from collections.abc import Callable, Iterator, Mapping
from typing import Any

from cobus.master.config import NetworkConfig, PdoLayout, Signal
from cobus.master.errors import SignalError, SignalValueError
from cobus.proto.pdo import Kind, PdoError

__all__ = ["Inputs", "Outputs", "ProcessImage"]


def _raw_zero(sig: Signal) -> Any:
    if sig.kind is Kind.BOOL:
        return False
    if sig.kind is Kind.BYTES:
        return bytes(sig.bits // 8)
    if sig.kind in (Kind.REAL32, Kind.REAL64):
        return 0.0
    return 0


class ProcessImage:
    """Every signal of a network, with its current value."""

    def __init__(self, config: NetworkConfig) -> None:
        self.inputs_by_name: dict[str, Signal] = {}
        self.outputs_by_name: dict[str, Signal] = {}
        self._in_lookup: dict[str, str] = {}
        self._out_lookup: dict[str, str] = {}
        self._in_values: dict[str, Any] = {}
        self._out_values: dict[str, Any] = {}
        #: Raw values of each RPDO (node_id, number), in mapping order (dummies left out).
        self._rpdo_raw: dict[tuple[int, int], list[Any]] = {}
        self._rpdo_layouts: dict[tuple[int, int], PdoLayout] = {}
        #: Each output's places: one per RPDO that maps its object.
        self._out_places: dict[str, list[Signal]] = {}
        self._tpdo_signals: dict[tuple[int, int], tuple[Signal | None, ...]] = {}
        for node in config.nodes.values():
            canon = {alias: canonical for alias, canonical in node.aliases.items()}
            for layout in node.tpdos:
                self._tpdo_signals[(node.node_id, layout.number)] = layout.positions
                for sig in layout.signals:
                    self.inputs_by_name[sig.name] = sig
                    self._in_values[sig.name] = sig.zero
                    self._register(self._in_lookup, node.name, sig, canon)
            for layout in node.rpdos:
                if layout.linked:
                    continue
                key = (node.node_id, layout.number)
                self._rpdo_layouts[key] = layout
                raw: list[Any] = []
                for position in layout.positions:
                    # only a linked RPDO (left out above) has positions without a signal
                    assert position is not None
                    out: Signal = position
                    raw.append(_raw_zero(out))
                    places = self._out_places.setdefault(out.name, [])
                    if not places:
                        self.outputs_by_name[out.name] = out
                        self._out_values[out.name] = out.zero
                        self._register(self._out_lookup, node.name, out, canon)
                    places.append(out)
                self._rpdo_raw[key] = raw

    @staticmethod
    def _register(table: dict[str, str], node: str, sig: Signal, canon: dict[str, str]) -> None:
        table[sig.name] = sig.name
        local = sig.name[len(node) + 1 :]
        canonical = canon.get(local)
        if canonical is not None:
            table.setdefault(f"{node}.{canonical}", sig.name)

    # --- lookups
    def _find(self, table: dict[str, str], key: Any, what: str) -> str:
        name = table.get(key) if isinstance(key, str) else None
        if name is None:
            close = difflib.get_close_matches(str(key), list(table), n=3, cutoff=0.5)
            hint = f"; close: {', '.join(close)}" if close else ""
            raise SignalError(
                f"no {what} signal {key!r} in the process image (names are "
                f"'<node>.<signal>' from the network file){hint}"
            )
        return name

    def input_signal(self, key: str) -> Signal:
        """The input signal named ``key``; :class:`SignalError` with close names if none."""
        return self.inputs_by_name[self._find(self._in_lookup, key, "input")]

    def output_signal(self, key: str) -> Signal:
        """The output signal named ``key``; :class:`SignalError` with close names if none."""
        return self.outputs_by_name[self._find(self._out_lookup, key, "output")]

    # --- inputs
    def read_input(self, key: str) -> Any:
        """The scaled value of the input signal ``key``."""
        return self._in_values[self._find(self._in_lookup, key, "input")]

    def update_tpdo(self, node_id: int, number: int, raw: tuple[Any, ...]) -> None:
        """Store the values of a received TPDO."""
        positions = self._tpdo_signals.get((node_id, number), ())
        values = self._in_values
        for sig, value in zip(positions, raw, strict=False):
            if sig is not None:
                values[sig.name] = sig.to_engineering(value)

    def zero_inputs(self, node_id: int, number: int | None = None) -> None:
        """Set the inputs of a node (or of one of its TPDOs) to 0."""
        for (node, n), positions in self._tpdo_signals.items():
            if node != node_id or (number is not None and n != number):
                continue
            for sig in positions:
                if sig is not None:
                    self._in_values[sig.name] = sig.zero

    # --- outputs
    def read_output(self, key: str) -> Any:
        """The scaled value of the output signal ``key``."""
        return self._out_values[self._find(self._out_lookup, key, "output")]

    def set_output(self, key: str, value: Any) -> list[tuple[int, int, bool]]:
        """Set an output; returns (node_id, RPDO number, changed) of each RPDO that carries
        it. The value is checked against the mapped object's type and limits first."""
        name = self._find(self._out_lookup, key, "output")
        sig = self.outputs_by_name[name]
        try:
            raw = sig.to_raw(value)
            if sig.kind is Kind.BOOL:
                raw = bool(raw)
            elif (sig.low is not None and raw < sig.low) or (
                sig.high is not None and raw > sig.high
            ):
                raise ValueError(
                    f"the raw value {raw} is outside the object's limits {sig.low}..{sig.high}"
                )
            for place in self._out_places[name]:
                candidate = list(self._rpdo_raw[(place.node_id, place.pdo)])
                candidate[place.position] = raw
                self._rpdo_layouts[(place.node_id, place.pdo)].codec.pack(candidate)
        except (PdoError, SignalValueError, TypeError, ValueError, OverflowError) as exc:
            unit = f" {sig.unit}" if sig.unit else ""
            raise SignalValueError(
                f"{name} cannot carry {value!r}{unit}: {exc} (0x{sig.index:04X}:"
                f"{sig.subindex:02X} is {sig.data_type.name}, {sig.bits} bits"
                + (f", scale {sig.scale:g}" if sig.scale is not None else "")
                + ")"
            ) from None
        changes = []
        for place in self._out_places[name]:
            raw_values = self._rpdo_raw[(place.node_id, place.pdo)]
            changed = raw_values[place.position] != raw
            raw_values[place.position] = raw
            changes.append((place.node_id, place.pdo, changed))
        self._out_values[name] = value
        return changes

    def rpdo_data(self, node_id: int, number: int) -> bytes:
        """The data of RPDO ``number`` of a node from the current outputs."""
        key = (node_id, number)
        return self._rpdo_layouts[key].codec.pack(self._rpdo_raw[key])

    def has_rpdo(self, node_id: int, number: int) -> bool:
        """Whether RPDO ``number`` of ``node_id`` carries outputs of the image."""
        return (node_id, number) in self._rpdo_layouts


class Inputs(Mapping[str, Any]):
    """``master.inputs["drive1.position"]``: the last value of each input signal (read-only)."""

    def __init__(self, image: ProcessImage) -> None:
        self._image = image

    def __getitem__(self, key: str) -> Any:
        return self._image.read_input(key)

    def __iter__(self) -> Iterator[str]:
        return iter(self._image.inputs_by_name)

    def __len__(self) -> int:
        return len(self._image.inputs_by_name)

    def __contains__(self, key: object) -> bool:
        return isinstance(key, str) and key in self._image._in_lookup

    def signal(self, key: str) -> Signal:
        """What the signal is: node, PDO, object, scaling."""
        return self._image.input_signal(key)


class Outputs(Mapping[str, Any]):
    """``master.outputs["drive1.controlword"] = 0x0F``: set output signals; reading gives the
    value last set. Outputs of nodes that are not operational are kept and sent once the
    node is started."""

    def __init__(self, image: ProcessImage, setter: Callable[[str, Any], None]) -> None:
        self._image = image
        self._setter = setter

    def __getitem__(self, key: str) -> Any:
        return self._image.read_output(key)

    def __setitem__(self, key: str, value: Any) -> None:
        self._setter(key, value)

    def update(self, values: Mapping[str, Any]) -> None:
        """Set several outputs."""
        for key, value in values.items():
            self._setter(key, value)

    def __iter__(self) -> Iterator[str]:
        return iter(self._image.outputs_by_name)

    def __len__(self) -> int:
        return len(self._image.outputs_by_name)

    def __contains__(self, key: object) -> bool:
        return isinstance(key, str) and key in self._image._out_lookup

    def signal(self, key: str) -> Signal:
        """The output signal named ``key`` (its node, PDO, scale and unit)."""
        return self._image.output_signal(key)
