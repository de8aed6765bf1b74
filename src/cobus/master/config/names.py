"""Objects named in a network file: :class:`ObjectIndex` resolves what the file writes (EDS
names with case and separators ignored, ``record.sub``, ``record[sub]``, ``0x6041:00``)
through the one name resolver of :mod:`cobus.od`, with a hint when a name is unknown.
"""

from __future__ import annotations

import re
from typing import Any

from cobus.errors import clip
from cobus.master.config.values import BadValue
from cobus.od import (
    Array,
    Finding,
    NameLookupError,
    Object,
    ObjectDictionary,
    Variable,
    parse_address,
    resolve,
    resolve_object,
    suggestions,
)
from cobus.proto.pdo import (
    Kind,
    kind_of_type,
)

__all__ = [
    "DUMMY",
    "DUMMY_TYPES",
    "ObjectIndex",
    "dropped_value",
    "mapped_kind",
    "normalise",
    "object_named",
]


def normalise(name: str) -> str:
    """The lookup form of a name: lower case, runs of other characters as one ``_``."""
    return re.sub(r"[^0-9a-z]+", "_", name.lower()).strip("_")


#: A gap in a PDO mapping, as a network file writes it ("dummy8") and the data types of CiA
#: 301 that stand for it.
DUMMY = re.compile(r"\s*dummy\s*(8|16|32)\s*\Z")
DUMMY_TYPES = {8: 0x0005, 16: 0x0006, 32: 0x0007}


def object_named(od: ObjectDictionary, text: str) -> Object | None:
    """The object ``text`` names as a whole (None: it names none, or a sub-object)."""
    try:
        return resolve_object(od, text, suggest=False)
    except NameLookupError:
        return None


class ObjectIndex:
    """Finds a node's objects as a file names them (through :func:`cobus.od.resolve`), with
    the file named in each error, and names its signals (:meth:`canonical`)."""

    #: Unknown names that get "did you mean" (a close-match search each); the ones after
    #: them get none, so that a file of 5,000 unknown names costs no minutes.
    SUGGESTIONS = 20
    #: Names longer than this get no suggestions (a close-match search grows with the
    #: product of the lengths).
    SUGGEST_LENGTH = 100

    def __init__(self, od: ObjectDictionary, file: str) -> None:
        self.od = od
        self.file = file
        self._suggestions = self.SUGGESTIONS
        #: The variables by signal-name key (several: the name is shared).
        self._names: dict[str, list[Variable]] = {}
        for obj in od:
            if obj.index < 0x1000:
                continue
            if isinstance(obj, Variable):
                self._names.setdefault(normalise(obj.name), []).append(obj)
                continue
            parent = normalise(obj.name)
            for var in obj:
                self._names.setdefault(f"{parent}.{normalise(var.name)}", []).append(var)
                self._names.setdefault(f"{parent}[{var.subindex}]", []).append(var)

    def canonical(self, var: Variable) -> str:
        """The signal name of ``var``: its normalised name (``record.sub`` for sub-objects);
        ``record[n]`` when sub-objects share a name, ``name_iiii`` when objects do."""
        if var.parent is None:
            key = normalise(var.name)
            return key if len(self._names.get(key, ())) < 2 else f"{key}_{var.index:04x}"
        parent = normalise(var.parent.name)
        key = f"{parent}.{normalise(var.name)}"
        if len(self._names.get(key, ())) < 2:
            return key
        key = f"{parent}[{var.subindex}]"
        return key if len(self._names.get(key, ())) < 2 else f"{key}_{var.index:04x}"

    def resolve(self, text: Any) -> Variable:
        """The variable ``text`` names, in every form :func:`cobus.od.resolve` takes; a
        ValueError says why none (with close names) or which several."""
        if not isinstance(text, str):
            raise BadValue(
                f"{text!r} is not an object name or address; write a name from the EDS or an "
                'address in quotes, e.g. "0x6041:00"'
            )
        try:
            var = resolve(self.od, text, suggest=False)
            if parse_address(text) is None and var.subindex == 0 and var.parent is not None:
                whole = object_named(self.od, text)  # (a record's own name?)
                if whole is var.parent:
                    subs = ", ".join(repr(f"{whole.name}.{v.name}") for v in list(whole)[1:4])
                    raise BadValue(
                        f"{text!r} is {'an array' if isinstance(whole, Array) else 'a record'} "
                        f"in {self.file}: name one "
                        f"of its sub-objects ({subs}...) or give the address"
                    )
            return var
        except NameLookupError as exc:
            if exc.candidates:
                where = ", ".join(
                    f"0x{c.index:04X}:{getattr(c, 'subindex', 0):02X}" for c in exc.candidates
                )
                raise BadValue(
                    f"{text!r} names several objects in {self.file} ({where}); use the address"
                ) from None
            address = parse_address(text)
            if address is not None:
                index, sub = address
                raise BadValue(f"{self.file} has no object 0x{index:04X}:{sub or 0:02X}") from None
            if exc.found is not None:
                raise BadValue(f"{self.file}: {exc}") from None
            raise BadValue(
                f"{self.file} has no object named {clip(repr(text), 120)}{self._hint(text)}"
            ) from None

    def _hint(self, text: str) -> str:
        """ " (did you mean ...?)" for the first :attr:`SUGGESTIONS` unknown names."""
        if len(text) > self.SUGGEST_LENGTH:
            return ""
        if self._suggestions <= 0:
            return " (no suggestions after the first ones: fix those first)"
        self._suggestions -= 1
        close = suggestions(self.od, text)
        if not close:
            return ""
        return f" (did you mean {', '.join(repr(c) for c in close)}?)"


_SECTION = re.compile(r"([0-9A-Fa-f]{4})(?:sub([0-9A-Fa-f]+))?\Z")


def dropped_value(od: ObjectDictionary, finding: Finding) -> bool:
    """Whether ``finding`` is a ParameterValue the reader could not keep."""
    if not finding.reason.startswith("ParameterValue") or finding.section is None:
        return False
    match = _SECTION.match(finding.section)
    if match is None:
        return False
    var = od.get_variable(int(match.group(1), 16), int(match.group(2) or "0", 16))
    return var is not None and var.parameter_value is None


def mapped_kind(var: Variable, bits: int) -> Kind:
    """proto's rule (:func:`~cobus.proto.pdo.kind_of_type`); a type without a Kind (a
    string, a time) is kept as its bytes in the process image."""
    kind = kind_of_type(var.data_type)
    if kind is not None:
        return kind
    if bits % 8:
        raise BadValue(
            f"0x{var.index:04X}:{var.subindex:02X} ({var.data_type.name}) cannot be mapped "
            f"with {bits} bits"
        )
    return Kind.BYTES
