"""The documents' code tables as data files (``cobus/profiles/tables/*.yaml``): the profiles,
the simulators and the alarm handler read the same ones."""

from __future__ import annotations

import functools
from importlib import resources
from typing import Any

import yaml

__all__ = ["table"]


@functools.cache
def table(name: str) -> Any:
    """The data of ``tables/NAME.yaml`` (read once)."""
    text = (resources.files("cobus.profiles") / "tables" / f"{name}.yaml").read_text("utf-8")
    return yaml.safe_load(text)
