"""Which objects of a device are commands or process data rather than parameters.

A parameter is configuration: written once and saved, it makes the device do nothing by
itself. A command makes it act the moment it is written: a controlword, a mode of operation,
a set-point, an output, the save and restore commands. Nothing may write a command as a side
effect (a parameter set applied, a snapshot restored): :class:`CommandObjects` names them, so
that each write path can leave them out or refuse them and say why.

A command is known three ways:

- by its profile: the CiA 402 controlword, modes of operation, targets and offsets (on each of
  the eight axes, 800h apart) and digital outputs; the CiA 401 outputs; 1010h/1011h;
- by the device's EDS: an object its RPDO mapping (1600h-17FFh) receives is process data that
  the application sends (the ZAPI ACE2's speed set-point and controlword at 2200h/2201h);
- by a dialect's own table (the EC motor's control word, targets and mode), given as ``table``.

:func:`process_data_of` adds what a snapshot leaves out besides: objects the EDS marks ``rww``
(written by an RPDO) - configuration that happens to be mappable is captured only when named.
"""

from __future__ import annotations

from collections.abc import Mapping

from cobus.od._checks import mapping_entries
from cobus.od._model import Access, Array, ObjectDictionary, Record, Variable

__all__ = ["CommandObjects", "process_data_of"]

_AXES = 8  # CiA 402 logical devices: axis n at 6000h + (n - 1) * 800h
_AXIS_STEP = 0x800

#: CiA 402 objects that make a drive act (by their axis-1 index), and the sub-index that does
#: (None: every sub-index).
_CIA402: dict[int, tuple[str, int | None]] = {
    0x6040: ("the CiA 402 controlword: it switches the drive on, off and into motion", None),
    0x6060: ("the CiA 402 modes of operation: it changes how the drive moves", None),
    0x6042: ("a CiA 402 set-point (vl target velocity)", None),
    0x6071: ("a CiA 402 set-point (target torque)", None),
    0x607A: ("a CiA 402 set-point (target position)", None),
    0x60B0: ("a CiA 402 set-point (position offset)", None),
    0x60B1: ("a CiA 402 set-point (velocity offset)", None),
    0x60B2: ("a CiA 402 set-point (torque offset)", None),
    0x60C1: ("a CiA 402 set-point (interpolation data record)", None),
    0x60FE: ("the CiA 402 digital outputs: it switches the drive's outputs", 1),
    0x60FF: ("a CiA 402 set-point (target velocity)", None),
}

#: CiA 401 outputs: writing them switches the module's outputs.
_CIA401: dict[int, str] = {
    0x6200: "a CiA 401 output (write outputs 8-bit)",
    0x6220: "a CiA 401 output (write outputs 1-bit)",
    0x6300: "a CiA 401 output (write outputs 16-bit)",
    0x6320: "a CiA 401 output (write outputs 32-bit)",
    0x6410: "a CiA 401 analogue output (8-bit)",
    0x6411: "a CiA 401 analogue output (16-bit)",
    0x6412: "a CiA 401 analogue output (32-bit)",
    0x6413: "a CiA 401 analogue output (float)",
    0x6414: "a CiA 401 analogue output (manufacturer-specific)",
}

_STORAGE = {
    0x1010: "the save command (1010h): it makes the node store its parameters",
    0x1011: "the restore command (1011h): it brings back the factory defaults",
}


class CommandObjects:
    """The command objects of one device: ``reason(index, subindex)`` says why writing the
    object is a command (None: it is not one).

    ``od``: the device's dictionary (its RPDO mapping adds the objects it receives as
    process data; its device type says which profile its own objects follow); without one,
    the CiA 401 and 402 tables both apply - and so they do, whatever the device type, to an
    object the dictionary does not have (a set written for another device is refused rather
    than trusted). ``table``: a dialect's own commands by index (then the CiA tables do not
    apply).
    """

    def __init__(
        self, od: ObjectDictionary | None = None, *, table: Mapping[int, str] | None = None
    ) -> None:
        self.table = table
        self._od = od
        profile = _profile(od)
        self._cia402 = table is None and profile in (None, 402)
        self._cia401 = table is None and profile in (None, 401)
        self._mapped = _rpdo_mapped(od) if od is not None else {}

    def reason(self, index: int, subindex: int) -> str | None:
        """Why a write to ``index``:``subindex`` makes the device act, or None."""
        if self.table is not None:
            text = self.table.get(index)
            if text is not None:
                return text
        elif index in _STORAGE:
            return _STORAGE[index]
        # (an object the dictionary lacks is judged by every CiA table: it may be the other
        # device's)
        foreign = self.table is None and (
            self._od is None or self._od.get_variable(index, subindex) is None
        )
        if (self._cia402 or foreign) and 0x6000 <= index < 0x6000 + _AXES * _AXIS_STEP:
            axis, offset = divmod(index - 0x6000, _AXIS_STEP)
            entry = _CIA402.get(0x6000 + offset)
            if entry is not None and entry[1] in (None, subindex):
                return entry[0] + (f" (axis {axis + 1})" if axis else "")
        if (self._cia401 or foreign) and index in _CIA401:
            return _CIA401[index]
        rpdo = self._mapped.get((index, subindex))
        if rpdo is not None:
            return f"process data the device receives: the EDS maps it to RPDO {rpdo}"
        return None


def process_data_of(var: Variable, commands: CommandObjects) -> str | None:
    """Why ``var`` is a command or process data rather than a parameter (None: it is a
    parameter, as far as the dictionary tells)."""
    reason = commands.reason(var.index, var.subindex)
    if reason is not None:
        return reason
    if var.access is Access.RWW:
        return "process data: the EDS marks it rww (written by an RPDO)"
    if var.access is Access.WO:
        return "write-only: a command or process data, never read back"
    return None


def _profile(od: ObjectDictionary | None) -> int | None:
    """The device profile 1000h names (None: unknown, or a manufacturer's 0)."""
    if od is None:
        return None
    var = od.get_variable(0x1000, 0)
    value = var.value if var is not None else None
    if not isinstance(value, int) or not value & 0xFFFF:
        return None
    return value & 0xFFFF


def _rpdo_mapped(od: ObjectDictionary) -> dict[tuple[int, int], int]:
    """(index, sub-index) → the RPDO (1-512) the dictionary's mapping receives it in."""
    out: dict[tuple[int, int], int] = {}
    for number in range(512):
        obj = od.get(0x1600 + number)
        if not isinstance(obj, Record | Array):
            continue
        for _entry, index, subindex, _bits in mapping_entries(obj):
            if index >= 0x1000:  # (below: dummy entries of a data type)
                out.setdefault((index, subindex), number + 1)
    return out
