"""Enumerations that print as people read them.

An :class:`enum.IntEnum` prints as its number (``str(NmtState.OPERATIONAL) == "5"``), which
tells a reader nothing. :class:`NamedIntEnum` prints its name instead; formatting with a spec
(``f"{state:02X}"``) still formats the number, and the value still compares as an int.
"""

from __future__ import annotations

import enum

__all__ = ["NamedIntEnum"]


class NamedIntEnum(enum.IntEnum):
    """An :class:`enum.IntEnum` whose ``str()`` (and ``f"{x}"``) is its name."""

    def __str__(self) -> str:
        return self.name
