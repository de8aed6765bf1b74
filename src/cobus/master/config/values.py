"""Reading a network file's values: the report of problems (file, line, node, key) and the
parsers of numbers, flags, choices and times, each raising :class:`BadValue` with a reason
a user can act on.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Iterable, Mapping
from typing import Any

from cobus._yaml import milliseconds
from cobus.master.errors import (
    ConfigProblem,
    Severity,
)

__all__ = [
    "BadValue",
    "Report",
    "as_bool",
    "as_choice",
    "as_int",
    "as_mapping",
    "as_ms",
    "as_number",
    "as_whole_ms",
    "suggest",
]

# ------------------------------------------------------------------------------- problems


class Report:
    """Every problem of one network file, each said once, in the order found."""

    def __init__(self, path: str) -> None:
        self.path = path
        self.problems: list[ConfigProblem] = []
        self._seen: set[str] = set()

    def add(
        self,
        severity: Severity,
        node: str | None,
        key: str | None,
        reason: str,
        line: int | None = None,
    ) -> None:
        """Note a problem (the same text twice is said once)."""
        problem = ConfigProblem(self.path, line, node, key, severity, reason)
        text = str(problem)
        if text not in self._seen:
            self._seen.add(text)
            self.problems.append(problem)

    def error(self, node: str | None, key: str | None, reason: str, line: int | None) -> None:
        """Note an error: the file cannot be used."""
        self.add(Severity.ERROR, node, key, reason, line)

    def warning(self, node: str | None, key: str | None, reason: str, line: int | None) -> None:
        """Note a warning: the file works, maybe not as meant."""
        self.add(Severity.WARNING, node, key, reason, line)

    @property
    def errors(self) -> list[ConfigProblem]:
        """The errors found so far."""
        return [p for p in self.problems if p.severity is Severity.ERROR]


class BadValue(ValueError):
    """A value that cannot be used; the text says why (a ValueError: what the public
    :class:`ObjectIndex` raises)."""


def suggest(word: str, choices: Iterable[str]) -> str:
    """ " (did you mean ...?)" with the close ones of ``choices``, or nothing."""
    close = difflib.get_close_matches(word, list(choices), n=3, cutoff=0.6)
    return f" (did you mean {', '.join(repr(c) for c in close)}?)" if close else ""


# ------------------------------------------------------------------------------- value parsers


def as_int(value: Any, low: int, high: int, what: str = "value") -> int:
    """An integer in ``low..high`` (a ``what`` named in the error)."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise BadValue(f"{value!r} is not an integer; give a {what} in {low}..{high}")
    if not low <= value <= high:
        raise BadValue(f"{value} is out of range: use {low}..{high}")
    return value


def as_bool(value: Any) -> bool:
    """true or false, as YAML writes them."""
    if not isinstance(value, bool):
        raise BadValue(f"{value!r} is not true or false (write them without quotes)")
    return value


def as_number(value: Any, low: float, high: float) -> float:
    """A number in ``low..high``."""
    if isinstance(value, bool) or not isinstance(value, int | float) or math.isnan(value):
        raise BadValue(f"{value!r} is not a number")
    if not low <= value <= high:
        raise BadValue(f"{value} is out of range: use {low:g}..{high:g}")
    return float(value)


def as_choice(value: Any, options: tuple[str, ...]) -> str:
    """One of ``options``, spelled as they are."""
    if not isinstance(value, str) or value not in options:
        raise BadValue(f"{value!r} is not one of {', '.join(options)}")
    return value


def as_ms(value: Any, high: float = 1e9) -> float:
    """A duration in milliseconds: a number (ms) or text with a unit."""
    try:
        return milliseconds(value, high)
    except ValueError as exc:
        raise BadValue(str(exc)) from None


def as_whole_ms(value: Any, high: int = 0xFFFF) -> int:
    """A duration in whole milliseconds (what an object that counts ms can hold)."""
    ms = as_ms(value, high)
    if ms != int(ms):
        raise BadValue(f"{ms:g} ms is not a whole number of milliseconds (the object counts ms)")
    return int(ms)


def as_mapping(value: Any, what: str) -> Mapping[Any, Any]:
    """``value`` as a mapping (``what`` names it in the error)."""
    if not isinstance(value, Mapping):
        raise BadValue(f"{what} must be a mapping of keys to values, not {type(value).__name__}")
    return value
