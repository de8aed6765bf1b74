"""Argument types the command line shares."""

from __future__ import annotations

import argparse
import math

__all__ = ["seconds", "seconds_or_zero"]


def seconds(text: str) -> float:
    """A number of seconds above 0 (``nan``, ``inf`` and negatives refused)."""
    value = _number(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"{text!r}: a number of seconds above 0")
    return value


def seconds_or_zero(text: str) -> float:
    """A number of seconds, 0 or above (0 usually means "never")."""
    value = _number(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"{text!r}: a number of seconds, 0 or above")
    return value


def _number(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of seconds") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r}: a finite number of seconds")
    return value
