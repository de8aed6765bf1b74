"""What the command line prints: rich tables and colour on a terminal; piped into a file, a
pager or another program, plain text with every value whole.

rich falls back to 80 columns when its output is not a terminal, and then cuts cells
(``0x0…``): a piped table here is laid out as wide as its content, without box-drawing
characters, colour or trailing blanks, one row per line.
"""

from __future__ import annotations

import sys
from typing import Any, TextIO

__all__ = ["console", "print_table", "table", "terminal"]

#: The width a piped table may take: wider than any row, so that no cell is cut or wrapped.
_PIPED_WIDTH = 100_000


def terminal(stream: TextIO | None = None) -> bool:
    """Whether ``stream`` (default: stdout) is a terminal."""
    stream = sys.stdout if stream is None else stream
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):  # (a closed or odd stream)
        return False


def console(*, stderr: bool = False) -> Any:
    """A rich console on stdout (or stderr): as rich makes it on a terminal; else without
    colour and as wide as its content."""
    from rich.console import Console

    stream = sys.stderr if stderr else sys.stdout
    if terminal(stream):
        return Console(file=stream, highlight=False)
    return Console(
        file=stream, highlight=False, width=_PIPED_WIDTH, color_system=None, soft_wrap=True
    )


def table(*columns: str, title: str | None = None, stderr: bool = False) -> Any:
    """A rich table with these column headers: boxed on a terminal (a value too wide for it
    wraps), plain columns apart by two blanks when piped (print it with
    :func:`print_table`)."""
    from rich.table import Table

    if terminal(sys.stderr if stderr else sys.stdout):
        boxed = Table(*columns, title=title)
        for column in boxed.columns:  # a narrow terminal wraps a value, never cuts it (0x0…)
            column.overflow = "fold"
        return boxed
    return Table(
        *columns,
        title=title,
        title_justify="left",
        box=None,
        pad_edge=False,
        padding=(0, 2, 0, 0),
        show_edge=False,
    )


def print_table(rows: Any, *, stderr: bool = False) -> None:
    """Print a table (or any rich renderable): on a terminal as rich does; piped, as plain
    lines without trailing blanks."""
    out = console(stderr=stderr)
    if terminal(out.file):
        out.print(rows)
        return
    with out.capture() as captured:
        out.print(rows)
    text = "\n".join(line.rstrip() for line in captured.get().splitlines())
    out.file.write(text + "\n")
    out.file.flush()
