"""Reader for the golden frame vectors in ``shared/vectors/`` (format in its README)."""

from __future__ import annotations

from dataclasses import dataclass, field

from cobus.proto.frame import Frame
from tests.conftest import VECTORS_DIR


@dataclass
class Step:
    direction: str  # ">" sent by the master / client, "<" sent by the device
    frame: Frame


@dataclass
class Case:
    source: str
    name: str
    settings: dict[str, str] = field(default_factory=dict)
    steps: list[Step] = field(default_factory=list)
    deviations: list[str] = field(default_factory=list)

    @property
    def value_free(self) -> bool:
        return self.settings.get("value_free") == "1"


def load(name: str) -> list[Case]:
    """All cases of one vectors file, e.g. ``load("beckhoff-cia301")``."""
    path = VECTORS_DIR / f"{name}.txt"
    cases: list[Case] = []
    current: Case | None = None
    for raw in path.read_text(encoding="utf-8").splitlines():
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        if line.startswith("=="):
            current = Case(source=name, name=line[2:].strip())
            cases.append(current)
            continue
        if current is None:
            raise ValueError(f"{path}: line before the first case: {raw!r}")
        if line.startswith("@"):
            for item in line[1:].split():
                key, _, value = item.partition("=")
                current.settings[key] = value
        elif line[0] in "<>":
            current.steps.append(Step(line[0], Frame.parse(line[1:].strip())))
        elif line.startswith("~"):
            current.deviations.append(line[1:].strip())
        else:
            raise ValueError(f"{path}: unreadable vector line {raw!r}")
    return cases


def case(name: str, title: str) -> Case:
    """The case of one vectors file whose title starts with ``title``."""
    for c in load(name):
        if c.name.startswith(title):
            return c
    raise KeyError(f"no case {title!r} in {name}")
