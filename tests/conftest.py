"""Shared test fixtures: where the shared corpus lives."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SHARED = Path(os.environ.get("COBUS_SHARED", ROOT.parent / "shared"))
EDS_DIR = SHARED / "eds"
VECTORS_DIR = SHARED / "vectors"


def corpus_files() -> list[Path]:
    """Every EDS/DCF file of the shared corpus, sorted."""
    return sorted(p for p in EDS_DIR.iterdir() if p.suffix.lower() in (".eds", ".dcf"))


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    if not SHARED.is_dir():
        pytest.fail(f"the shared folder is missing at {SHARED} (set COBUS_SHARED)")
    return SHARED
