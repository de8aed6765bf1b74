"""``cobus lss assign-all --network FILE``: which node-ID each device found gets, by the
network file's nodes, and the serial numbers written back into the file.

A device whose identity a node of the file gives (vendor, product, serial; the revision
too when the node gives one) gets that node's ID. One the file knows by vendor and product
(and revision, if given) but by no serial gets the ID of the first such node not yet given
out, and its serial is written into that node's entry (``serial_number: 0x...``) so that
the master knows it by its identity from then on. A device the file does not know gets a
free node-ID the file does not use. The file is edited as text (one line added per node,
comments and layout kept) and replaced atomically.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from cobus._yaml import LineMap, read_yaml
from cobus.device.storage import atomic_write
from cobus.errors import CobusError
from cobus.master.config import load_network
from cobus.proto.lss import LssIdentity

__all__ = ["NetworkPlan", "NetworkWriteError", "Planned"]


class NetworkWriteError(CobusError):
    """The serial numbers cannot be written into the network file (the message says why)."""


@dataclass(frozen=True)
class Planned:
    """The node-ID a device found gets; ``name`` the file's node (None: not in the file);
    ``write`` whether its serial is to be written into that node's entry."""

    node_id: int
    name: str | None
    write: bool


@dataclass(frozen=True)
class _Node:
    name: str
    node_id: int
    vendor: int
    product: int
    revision: int
    serial: int


class NetworkPlan:
    """The nodes of a network file, for the devices an LSS scan finds."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        cfg = load_network(self.path)  # NetworkConfigError: every problem, with its line
        self.nodes = [
            _Node(
                n.name,
                n.node_id,
                n.vendor_id,
                n.product_code,
                n.revision_number,
                n.serial_number,
            )
            for n in cfg.nodes.values()
            if n.enabled
        ]
        #: Every node-ID the file gives a node (a device it does not know gets none of them).
        self.used = {n.node_id for n in cfg.nodes.values()}
        vendors = {n.vendor for n in self.nodes if n.vendor}
        #: The one vendor the file's nodes give, if they give one: fastscan confirms it
        #: instead of scanning it (and scans whole when a device of another one remains).
        self.vendor = vendors.pop() if len(vendors) == 1 else None
        self._given: set[str] = set()

    def choose(self, identity: LssIdentity, heard: set[int]) -> Planned | None:
        """The file's node for ``identity``; None when the file does not know it. A node
        whose ID is heard on the bus is there already and is not given again."""
        for node in self.nodes:
            if node.name in self._given or not node.serial or node.node_id in heard:
                continue
            if (node.vendor, node.product, node.serial) != (
                identity.vendor,
                identity.product,
                identity.serial,
            ):
                continue
            if not node.revision or node.revision == identity.revision:
                self._given.add(node.name)
                return Planned(node.node_id, node.name, False)
        for node in self.nodes:
            if node.name in self._given or node.serial or node.node_id in heard:
                continue
            if not node.vendor or not node.product:
                continue  # (a node known by nothing would match any device)
            if (node.vendor, node.product) != (identity.vendor, identity.product):
                continue
            if node.revision and node.revision != identity.revision:
                continue
            self._given.add(node.name)
            return Planned(node.node_id, node.name, True)
        return None

    def write_back(self, serials: dict[str, int]) -> None:
        """Write ``serial_number`` into the entries of the nodes named (name -> serial)."""
        if not serials:
            return
        try:
            text = self.path.read_text(encoding="utf-8")
        except OSError as exc:
            raise NetworkWriteError(f"{self.path}: cannot read it again: {exc.strerror}") from None
        data, problems = read_yaml(text)
        nodes = data.get("nodes") if isinstance(data, dict) and not problems else None
        if not isinstance(nodes, LineMap):
            raise NetworkWriteError(f"{self.path}: changed while the scan ran; read it again")
        lines = text.splitlines(keepends=True)
        inserts: list[tuple[int, str]] = []
        for name, serial in serials.items():
            entry = nodes.get(name)
            at = entry.lines.get("node_id") if isinstance(entry, LineMap) else None
            if at is None or not 1 <= at <= len(lines):
                raise NetworkWriteError(
                    f"{self.path}: node {name!r} has no node_id line to write its serial beside"
                )
            line = lines[at - 1]
            indent = re.match(r"[ \t]*", line)
            assert indent is not None
            if not re.match(r"[ \t]*node_id\s*:", line):
                raise NetworkWriteError(
                    f"{self.path}:{at}: node {name!r} is written on one line; add "
                    f"'serial_number: 0x{serial:08X}' to it yourself"
                )
            end = "" if line.endswith("\n") else "\n"
            inserts.append(
                (
                    at,
                    f"{end}{indent.group(0)}serial_number: 0x{serial:08X}"
                    "   # by cobus lss assign-all\n",
                )
            )
        for at, added in sorted(inserts, reverse=True):
            lines.insert(at, added)
        try:
            atomic_write(self.path, "".join(lines).encode("utf-8"))
        except OSError as exc:
            raise NetworkWriteError(
                f"{self.path}: cannot write the serial numbers ({exc}); the file is unchanged"
            ) from None
