"""A name of the public API that moved: reading or setting it says where it went, instead of
an unhelpful AttributeError (or, for an attribute, a silent new attribute that does nothing)."""

from __future__ import annotations

import sys
import warnings
from pathlib import Path
from typing import Any, NoReturn

__all__ = ["Moved", "Renamed", "renamed_names", "warn_renamed"]

_COBUS = str(Path(__file__).resolve().parent)


def warn_renamed(message: str) -> None:
    """A :class:`DeprecationWarning` blamed on the first caller outside cobus: the user's
    line, also when the old name is reached through a blocking twin or a rig file (Python
    shows a DeprecationWarning only when it is blamed on ``__main__`` or the user's code)."""
    level, frame = 2, sys._getframe(1)
    while frame.f_back is not None and frame.f_code.co_filename.startswith(_COBUS):
        frame, level = frame.f_back, level + 1
    warnings.warn(message, DeprecationWarning, stacklevel=level)


class Moved:
    """``add_device = Moved("cobus.device.add_device(net, node_id, od)")`` on a class."""

    def __init__(self, instead: str) -> None:
        self._instead = instead
        self._name = "?"
        self._owner = "?"

    def __set_name__(self, owner: type, name: str) -> None:
        self._name = name
        self._owner = owner.__name__

    def _error(self) -> AttributeError:
        return AttributeError(f"{self._owner}.{self._name} has moved: use {self._instead}")

    def __get__(self, obj: object, owner: type | None = None) -> Any:
        if obj is None:
            return self
        raise self._error()

    def __set__(self, obj: object, value: object) -> NoReturn:
        raise self._error()


class Renamed:
    """``data = Renamed("manufacturer_data")`` on a class: the old name of an attribute
    still reads, for one release, with a :class:`DeprecationWarning` that gives the new one
    (one name per idea, see :mod:`cobus`)."""

    def __init__(self, new: str) -> None:
        self._new = new
        self._name = "?"
        self._owner = "?"

    def __set_name__(self, owner: type, name: str) -> None:
        self._name = name
        self._owner = owner.__name__

    def __get__(self, obj: object, owner: type | None = None) -> Any:
        if obj is None:
            return self
        warn_renamed(f"{self._owner}.{self._name} is now {self._owner}.{self._new}")
        return getattr(obj, self._new)


def renamed_names(module: str, names: dict[str, tuple[str, Any]]) -> Any:
    """A module ``__getattr__`` for public names renamed (old name -> (new name, object)):
    the old one still imports, for one release, with a :class:`DeprecationWarning`."""

    def __getattr__(name: str) -> Any:
        if name in names:
            new, value = names[name]
            warn_renamed(f"{module}.{name} is now {module}.{new}")
            return value
        raise AttributeError(f"module {module!r} has no attribute {name!r}")

    return __getattr__
