"""The helpers with which each service defines its communication objects for
:func:`~cobus.device.minimal_od` (``define_objects(od, ...)`` in ``sync.py``, ``emcy.py`` ...):
every service owns its objects, their defaults and access, beside the code that serves them."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from cobus.od import Access, Array, DataType, ObjectDictionary, Record, Variable

__all__ = ["CONST", "RO", "RW", "U8", "U16", "U32", "composite", "var"]

U8, U16, U32 = DataType.UNSIGNED8, DataType.UNSIGNED16, DataType.UNSIGNED32
RO, RW, CONST = Access.RO, Access.RW, Access.CONST


def var(
    index: int,
    sub: int,
    name: str,
    dt: DataType,
    access: Access,
    default: Any,
    *,
    mappable: bool = False,
) -> Variable:
    """One variable with its default value."""
    return Variable(index, sub, name, dt, access, mappable, default=default)


def composite(
    od: ObjectDictionary,
    obj: Record | Array,
    subs: Iterable[tuple[int, str, DataType, Any]],
    *,
    first: Access = RO,
    rest: Access = RW,
) -> None:
    """Fill ``obj`` with sub 0 (the first item, access ``first``) and its entries (``rest``)
    and add it to ``od``."""
    index = obj.index
    for n, (sub, name, dt, default) in enumerate(subs):
        obj.add(Variable(index, sub, name, dt, rest if n else first, default=default))
    od.add(obj)
