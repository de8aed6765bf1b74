"""Run every benchmark and print its figures: ``python benchmarks/run.py [name ...]``.

Each ``benchmarks/bench_*.py`` has a ``main()`` that prints a table with cobus and
python-canopen side by side. Timing is measured here, never asserted in the test suite.
"""

from __future__ import annotations

import importlib
import platform
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))


#: Run only when named: minutes under valgrind, where the others take seconds.
BY_NAME_ONLY = {"instructions"}


def main(argv: list[str]) -> int:
    names = argv or sorted(
        name
        for name in (p.stem[len("bench_") :] for p in HERE.glob("bench_*.py"))
        if name not in BY_NAME_ONLY
    )
    print(f"cobus benchmarks on Python {platform.python_version()}, {platform.machine()}")
    for name in names:
        module = importlib.import_module(f"benchmarks.bench_{name}")
        module.main()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
