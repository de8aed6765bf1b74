"""The root of every error cobus raises on purpose.

Each layer derives its own typed errors from :class:`CobusError`, so an application can catch
everything cobus reports with one ``except`` and still tell the causes apart.
"""


class CobusError(Exception):
    """Base class of all errors raised by cobus."""


#: The most characters of a value (or of one problem's reason) a message shows.
CLIP = 300


def clip(text: str, limit: int = CLIP) -> str:
    """``text`` cut in its middle to about ``limit`` characters, saying how many were left out:
    a message names a value, it never prints a megabyte of it."""
    if len(text) <= limit:
        return text
    head = limit * 2 // 3
    tail = limit - head
    return f"{text[:head]}…({len(text) - limit:,} characters left out)…{text[-tail:]}"


#: The most problems a message lists; the error keeps them all.
SHOWN_PROBLEMS = 50


def listing(head: str, items: list[str], limit: int = SHOWN_PROBLEMS) -> str:
    """``head`` and the first ``limit`` of ``items`` indented one per line, then how many
    more there are: a file with 5,000 problems gives a message to read, not a megabyte."""
    lines = [head, *(f"  {item}" for item in items[:limit])]
    if len(items) > limit:
        lines.append(f"  ... and {len(items) - limit:,} more (fix these first)")
    return "\n".join(lines)
