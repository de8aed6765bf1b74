"""Mutated EDS/DCF and YAML inputs are refused with cobus's typed errors only (a bounded run;
``make fuzz`` runs 20,000 + 5,000, with damaged alarm histories and BLF bombs, under a memory
and time cap). The mutators and targets are in tests/fuzz_inputs.py; inputs that once broke a
loader are kept under tests/data/fuzz/."""

from __future__ import annotations

import random
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cobus.errors import CobusError
from cobus.sim import Rig
from cobus.sim.rig import RigError
from tests.fuzz_inputs import (
    EXAMPLES,
    eds_files,
    mutate,
    scratch,
    try_eds,
    try_yaml,
    yaml_cases,
)

EDS = [(p.name, p.read_bytes()) for p in eds_files()]
YAML = [(kind, p, p.read_bytes()) for kind, p in yaml_cases()]
_CHECKS = [HealthCheck.too_slow, HealthCheck.function_scoped_fixture]


def test_the_corpus_and_the_examples_are_there() -> None:
    assert len(EDS) >= 15
    assert {kind for kind, _, _ in YAML} == {"network", "rig", "parameters", "netvars"}


@settings(max_examples=120, deadline=None, derandomize=True, suppress_health_check=_CHECKS)
@given(seed=st.integers(0, 2**32 - 1), which=st.integers(0, 10_000))
def test_mutated_eds_files_give_eds_errors_only(seed: int, which: int) -> None:
    name, data = EDS[which % len(EDS)]
    try_eds(mutate(data, random.Random(seed)), name)


@settings(max_examples=200, deadline=None, derandomize=True, suppress_health_check=_CHECKS)
@given(seed=st.integers(0, 2**32 - 1), which=st.integers(0, 10_000))
def test_mutated_yaml_files_give_typed_errors_only(
    seed: int, which: int, tmp_path_factory: pytest.TempPathFactory
) -> None:
    kind, path, data = YAML[which % len(YAML)]
    folder = scratch(path, tmp_path_factory.getbasetemp() / "fuzz")
    try_yaml(kind, mutate(data, random.Random(seed)), path, folder)


@pytest.mark.parametrize("kept", sorted((Path(__file__).parent / "data/fuzz").glob("*")))
def test_inputs_that_once_broke_a_loader(kept: Path, tmp_path: Path) -> None:
    kind = kept.name.split("-")[0]
    if kind == "eds":  # (this one: a mapping count of billions looped in render_markdown)
        try_eds(kept.read_bytes(), kept.name)
        return
    source = {
        "network": EXAMPLES / "networks/line.yml",
        "rig": Path(__file__).parent.parent / "src/cobus/sim/rigs/thesis.yaml",
    }[kind]
    try_yaml(kind, kept.read_bytes(), source, scratch(source, tmp_path))


def test_a_rig_file_that_is_no_utf8_or_holds_a_huge_number_is_a_rig_error(
    tmp_path: Path,
) -> None:
    bad = tmp_path / "rig.yaml"
    bad.write_bytes(b"bus: embedded\ndevices:\n  - {node: 5, kind: cia401_io, name: \xc3x}\n")
    with pytest.raises(RigError, match=r"rig.yaml:3: not UTF-8 text \(byte 0xC3\)"):
        Rig.load(bad)
    with pytest.raises(RigError, match=r"<rig>:2:.*digits"):
        Rig.loads("bus: embedded\ndevices: [{node: " + "9" * 5000 + ", kind: cia401_io}]\n")
    with pytest.raises(CobusError):
        Rig.loads("devices: " + "[" * 5000)
