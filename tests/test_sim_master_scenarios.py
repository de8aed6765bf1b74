"""What the cobus master needs to drive the document devices the way their documents' masters do
(issue 6: "a scenario test driven by the master"), each on its own: from the master SYNC before
the first NMT start.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from cobus.master import (
    NetworkConfig,
)
from cobus.proto.nmt import NmtState
from tests.test_master_support import (
    Rig,
    network,
    nmt,
    rig_test,
)


def first(rig: Rig, cob_id: int, data: bytes | None = None) -> float:
    """When the first frame on ``cob_id`` (with ``data``) went over the bus."""
    return next(t for t, f in rig.on(cob_id) if data is None or f.data == data)


def place(rig: Rig, cob_id: int, data: bytes | None = None) -> int:
    """Where the first frame on ``cob_id`` (with ``data``) is in the bus order."""
    return next(
        n
        for n, (_, f) in enumerate(rig.frames)
        if f.cob_id == cob_id and (data is None or f.data == data)
    )


# ================================================================================ the master
# What the scenarios needed from the master, each on its own with the master tests' I/O node.
IO_NODE = """
  a:
    node_id: 5
    eds: io.eds
    tpdo1: {{mapping: [counter], transmission_type: 255}}
    rpdo1: {{mapping: [flags], transmission_type: {rpdo1}}}
"""


def io_network(tmp_path: Path, master: str, extra: str = "", rpdo1: int = 255) -> NetworkConfig:
    text = f"master: {master}\nnodes:" + IO_NODE.format(rpdo1=rpdo1) + extra
    return network(tmp_path, text)


@pytest.mark.parametrize("sync", [True, False], ids=["sync", "no-sync"])
def test_the_master_starts_nodes_once_its_first_sync_is_out(tmp_path: Path, sync: bool) -> None:
    """A node that needs no boot-up is ready at once; with SYNC configured the master waits
    for its first SYNC (one period) before the NMT start, as the ZAPI ACE2 requires."""
    master = "{sync_period: 50}" if sync else "{}"
    cfg = io_network(tmp_path, master, "    do_not_initialise: true\n")

    async def scenario(rig: Rig) -> None:
        rig.add(5)
        await rig.master.boot(timeout=5)
        start = place(rig, 0x000, b"\x01\x05")
        if sync:
            assert first(rig, 0x000, b"\x01\x05") == pytest.approx(0.05)
            assert place(rig, 0x80) < start
        else:
            assert first(rig, 0x000, b"\x01\x05") == 0.0 and rig.on(0x80) == []
        assert nmt(rig.devices[5]) is NmtState.OPERATIONAL

    rig_test(cfg, scenario)
