"""Inputs that used to cost minutes or gigabytes (issue 39): each is refused or read within
seconds and a bounded amount of memory, with a typed error that says what to fix. What could
run away runs in a child Python under an address-space cap and a time limit."""

from __future__ import annotations

import json
import textwrap
from pathlib import Path

import pytest

from cobus._yaml import MAX_ALIAS_VALUES, read_yaml
from cobus.errors import clip
from tests.fuzz_inputs import EXAMPLES, ROOT, alias_bomb
from tests.util import bounded_python

# (example file, loader call, a key whose value a message names) of the four YAML inputs.
YAML_INPUTS = {
    "network": (
        EXAMPLES / "networks/thesis.yml",
        "from cobus.master import load_network as load",
        b"node_id",
    ),
    "rig": (
        ROOT / "src/cobus/sim/rigs/thesis.yaml",
        "from cobus.sim import Rig; load = Rig.load",
        b"bus",
    ),
    "parameters": (
        EXAMPLES / "parameters/servo.yml",
        "from cobus.blocks.parameters import load_parameters as load",
        b"profile velocity",
    ),
    "netvars": (
        EXAMPLES / "netvars/plant.yml",
        "from cobus.blocks.netvar_lists import load_netvars as load",
        b"interval",
    ),
}


def load_bounded(kind: str, path: Path) -> dict[str, str]:
    """Load ``path`` as ``kind`` in a capped child: what came out, as JSON."""
    _, loader, _ = YAML_INPUTS[kind]
    code = textwrap.dedent(
        f"""
        import json, time
        {loader}
        from cobus.errors import CobusError
        t0 = time.perf_counter()
        try:
            load({str(path)!r})
            out = {{"error": None, "message": ""}}
        except CobusError as exc:
            out = {{"error": type(exc).__name__, "message": str(exc)}}
        out["seconds"] = time.perf_counter() - t0
        print(json.dumps(out))
        """
    )
    status, stdout, stderr = bounded_python(code, memory_mb=1500, seconds=60, cwd=path.parent)
    assert status == 0, f"{kind}: exit {status}: {stderr[-2000:]}"
    result: dict[str, str] = json.loads(stdout)
    return result


@pytest.mark.parametrize("kind", sorted(YAML_INPUTS))
def test_an_alias_bomb_is_refused_at_once_in_every_yaml_input(kind: str, tmp_path: Path) -> None:
    source, _, key = YAML_INPUTS[kind]
    target = tmp_path / source.name
    bomb = alias_bomb(source.read_bytes(), key=key)
    assert b": *l9 " in bomb and len(bomb) - source.stat().st_size < 600
    target.write_bytes(bomb)
    for other in source.parent.glob("*.eds"):  # (what a network file names)
        (tmp_path / other.name).write_bytes(other.read_bytes())
    result = load_bounded(kind, target)
    assert result["error"] is not None
    assert "alias" in result["message"] and "100,000 values" in result["message"]
    assert len(result["message"]) < 2000


def test_a_self_referring_alias_is_refused() -> None:
    data, problems = read_yaml("a: &a [1, *a]\n")
    assert data is None
    assert problems[0].line == 1 and "refers to a value it is part of" in problems[0].reason


def test_anchors_and_merge_keys_within_the_budget_still_read() -> None:
    text = "defaults: &d {heartbeat_time: 100, sdo_timeout: 500}\na: {<<: *d, node_id: 5}\n"
    data, problems = read_yaml(text)
    assert problems == []
    assert data["a"] == {"heartbeat_time": 100, "sdo_timeout": 500, "node_id": 5}
    wide = (
        "x: &x ["
        + ", ".join(["1"] * 1000)
        + "]\n"
        + "".join(f"k{i}: *x\n" for i in range(MAX_ALIAS_VALUES // 1001 - 1))
    )
    assert read_yaml(wide)[1] == []  # (just under the budget)


def test_a_huge_value_is_clipped_in_every_message(tmp_path: Path) -> None:
    huge = "x" * 1_000_000
    (tmp_path / "net.yml").write_text(f"master: {{node_id: {huge}}}\nnodes: {{}}\n")
    result = load_bounded("network", tmp_path / "net.yml")
    assert result["error"] == "NetworkConfigError"
    assert "characters left out" in result["message"] and len(result["message"]) < 2000


def test_clip_keeps_both_ends_and_says_how_much_is_left_out() -> None:
    assert clip("short") == "short"
    text = clip("a" * 200 + "b" * 1000 + "c" * 100)
    assert text.startswith("a" * 200) and text.endswith("c" * 100)
    assert "(1,000 characters left out)" in text
