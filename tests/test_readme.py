"""Every Python snippet of the README runs as it stands, from the repository's root (in a
scratch copy of it: examples/ linked, files the snippets write land in a temporary folder)."""

from __future__ import annotations

import asyncio
import contextlib
import io
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SNIPPET = re.compile(r"^```python\n(.*?)^```", re.S | re.M)


def snippets() -> list[tuple[str, str]]:
    text = (ROOT / "README.md").read_text()
    found = []
    for match in SNIPPET.finditer(text):
        heading = [h for h in re.findall(r"^#+ (.*)$", text[: match.start()], re.M)][-1]
        found.append((heading, match.group(1)))
    return found


def test_the_readme_has_snippets_for_every_part_it_promises():
    headings = {h for h, _ in snippets()}
    assert {
        "Talk to a node (blocking)",
        "Drive a motor",
        "The same with asyncio",
        "Be a device",
        "Run a network as its master",
        "Simulated time",
        "Keep parameters up to date",
        "Alarms with a history",
        "Network variables between controllers",
    } <= headings


@pytest.mark.parametrize(("heading", "code"), snippets(), ids=[h for h, _ in snippets()])
def test_readme_snippet_runs(heading, code, tmp_path, monkeypatch):
    (tmp_path / "examples").symlink_to(ROOT / "examples")
    monkeypatch.chdir(tmp_path)
    out = io.StringIO()
    policy = asyncio.get_event_loop_policy()
    try:
        with contextlib.redirect_stdout(out):
            exec(compile(code, f"README.md: {heading}", "exec"), {"__name__": "__main__"})
    finally:
        asyncio.set_event_loop_policy(policy)  # a snippet may have set its own loop
        asyncio.set_event_loop(None)
    assert out.getvalue(), "every snippet shows something"
    expected = {
        "Talk to a node (blocking)": "0x637 OPERATIONAL",
        "The same with asyncio": "0x7305 ",
        "Be a device": "set-point written: 500\npressure: 1234",
        "Run a network as its master": "RUNNING",
        "Simulated time": "60.000 s, 60000 frames",
        "Keep parameters up to date": "re-parameterised, 3 of 3 written, saved and verified\n"
        "node 10 'servo': up to date (3 parameters)",
        "Alarms with a history": "node 10 emcy 7121h: Motor blocked\n1 0",
        "Network variables between controllers": "12.5 2.5 17",
    }
    assert expected.get(heading, "") in out.getvalue(), out.getvalue()


def test_every_picture_of_the_readme_is_there():
    text = (ROOT / "README.md").read_text()
    pictures = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", text)
    assert pictures, "the README shows the panel"
    for picture in pictures:
        assert (ROOT / picture).is_file(), picture
