"""Names as people type them: case and separators do not matter, near misses get suggestions.

EDS names are written as the vendor wrote them (``"Producer Heartbeat Time"``,
``"Producer heartbeat time"``, ``"Producer_heartbeat_time"``); a user should not have to
guess which. :func:`match_name` finds the one meant, :func:`did_you_mean` says what is close.
"""

from __future__ import annotations

import difflib
import re
from collections.abc import Iterable

__all__ = ["did_you_mean", "match_name", "normalize_name"]

_SEPARATORS = re.compile(r"[\s_\-]+")


def normalize_name(name: str) -> str:
    """``name`` in lower case with runs of blanks, ``_`` and ``-`` as one space."""
    return _SEPARATORS.sub(" ", name).strip().casefold()


def match_name(key: str, names: Iterable[str]) -> str | None:
    """The one name of ``names`` that ``key`` means: itself, else the only name equal to it
    but for case and separators; None when there is none or more than one."""
    candidates = list(names)
    if key in candidates:
        return key
    wanted = normalize_name(key)
    found = [n for n in candidates if normalize_name(n) == wanted]
    return found[0] if len(set(found)) == 1 else None


def did_you_mean(key: str, names: Iterable[str]) -> str:
    """``" (did you mean 'A' or 'B'?)"`` for the names close to ``key``, else ``""``."""
    by_norm: dict[str, str] = {}
    for name in names:
        by_norm.setdefault(normalize_name(name), name)
    close = difflib.get_close_matches(normalize_name(key), list(by_norm), n=3, cutoff=0.6)
    if not close:
        return ""
    quoted = [repr(by_norm[c]) for c in close]
    listing = quoted[0] if len(quoted) == 1 else f"{', '.join(quoted[:-1])} or {quoted[-1]}"
    return f" (did you mean {listing}?)"
