"""How fast a command starts: ``cobus --version``, ``--help`` and a one-shot ``sdo read``,
each a fresh process, beside the same with python-canopen.

python-canopen has no command line: its rows are a bare ``import canopen`` (for ``--version``
and ``--help``) and a script that opens the bus and asks one SDO (for ``sdo read``). Both
reads go to a node that does not answer on python-can's virtual bus, with a 50 ms timeout,
so that the figures are start-up, one request, and shutdown. The fastest of N runs.
"""

from __future__ import annotations

import subprocess
import sys
import time

from benchmarks.common import header, row

REPEAT = 7
TIMEOUT = 0.05

_CANOPEN_READ = f"""
import canopen
network = canopen.Network()
network.connect(interface="virtual", channel="bench-startup")
node = network.add_node(10)
node.sdo.RESPONSE_TIMEOUT = {TIMEOUT}
try:
    node.sdo.upload(0x1000, 0)
except canopen.SdoCommunicationError:
    pass
network.disconnect()
"""


def _fastest(argv: list[str]) -> float:
    """Milliseconds of the fastest of ``REPEAT`` runs of ``argv``."""
    best = float("inf")
    for _ in range(REPEAT):
        t0 = time.perf_counter()
        subprocess.run(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=False)
        best = min(best, time.perf_counter() - t0)
    return best * 1000


def main() -> None:
    python = sys.executable
    cobus = [python, "-m", "cobus"]
    bare = _fastest([python, "-c", "import canopen"])
    print(header("Start-up of a command, a fresh process (ms, fastest of 7; lower is better)"))
    print(
        row(
            "cobus --version  |  import canopen", _fastest([*cobus, "--version"]), bare, "ms", False
        )
    )
    print(row("cobus --help  |  import canopen", _fastest([*cobus, "--help"]), bare, "ms", False))
    read = [*cobus, "sdo", "read", "10", "0x1000", "-i", "virtual", "-c", "bench-startup"]
    print(
        row(
            "sdo read, no answer in 50 ms  |  canopen script",
            _fastest([*read, "--timeout", str(TIMEOUT)]),
            _fastest([python, "-c", _CANOPEN_READ]),
            "ms",
            False,
        )
    )
    print(
        row("python itself (python -c pass)", _fastest([python, "-c", "pass"]), None, "ms", False)
    )


if __name__ == "__main__":
    main()
