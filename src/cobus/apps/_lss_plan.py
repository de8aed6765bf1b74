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

import hashlib
import re
from dataclasses import dataclass
from pathlib import Path

from cobus._files import replace_file
from cobus._yaml import LineMap, read_yaml
from cobus.errors import CobusError
from cobus.master.config import load_network, loads_network
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
        try:
            self._digest = hashlib.sha256(self.path.read_bytes()).digest()
        except OSError:
            self._digest = b""  # (load_network says why it cannot be read)
        cfg = load_network(self.path)  # NetworkConfigError: every problem, with its line
        self._all = [
            _Node(
                n.name,
                n.node_id,
                n.vendor_id,
                n.product_code,
                n.revision_number,
                n.serial_number,
            )
            for n in cfg.nodes.values()
        ]
        enabled = {n.name for n in cfg.nodes.values() if n.enabled}
        self.nodes = [n for n in self._all if n.name in enabled]
        #: Every node-ID the file gives a node or the master (a device the file does not know
        #: gets none of them).
        self.used = {n.node_id for n in cfg.nodes.values()}
        if cfg.master.node_id is not None:
            self.used.add(cfg.master.node_id)
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
        """Write ``serial_number`` into the entries of the nodes named (name -> serial). The
        new text must read as the same network with just those serials added, else nothing
        is written and the message says what to add by hand."""
        if not serials:
            return
        by_hand = "; ".join(f"{n}: serial_number: 0x{v:08X}" for n, v in serials.items())
        target = self.path.resolve()  # (a link: the file it names gets the lines)
        try:
            raw = target.read_bytes()
        except OSError as exc:
            raise NetworkWriteError(
                f"{self.path}: cannot read it again ({exc.strerror}); add by hand: {by_hand}"
            ) from None
        if hashlib.sha256(raw).digest() != self._digest:
            raise NetworkWriteError(
                f"{self.path}: changed while the scan ran, so it is left alone; add by hand: "
                f"{by_hand}"
            )
        text = raw.decode("utf-8")
        data, problems = read_yaml(text)
        nodes = data.get("nodes") if isinstance(data, dict) and not problems else None
        lines = text.splitlines(keepends=True)
        edits: list[tuple[int, bool, str]] = []  # (line index, replace?, text)
        for name, serial in serials.items():
            entry = nodes.get(name) if isinstance(nodes, LineMap) else None
            edit = _edit(lines, entry, serial) if isinstance(entry, LineMap) else None
            if edit is None:
                raise NetworkWriteError(
                    f"{self.path}: node {name!r} is not written one key per line, so the file "
                    f"is left alone; add by hand: {by_hand}"
                )
            edits.append(edit)
        for at, replace, added in sorted(edits, reverse=True):
            if replace:
                lines[at] = added
            else:
                lines.insert(at, added)
        new_text = "".join(lines)
        self._check(new_text, serials, by_hand)
        try:
            replace_file(target, new_text.encode("utf-8"))
        except OSError as exc:
            raise NetworkWriteError(
                f"{self.path}: cannot write the serial numbers ({exc}); the file is unchanged; "
                f"add by hand: {by_hand}"
            ) from None

    def _check(self, text: str, serials: dict[str, int], by_hand: str) -> None:
        """``text`` reads as the network read at the start with just ``serials`` added."""
        try:
            after = loads_network(text, base_dir=self.path.parent, path=str(self.path))
        except CobusError:
            after = None
        expected = {n.name: n.serial for n in self._all}
        expected.update(serials)
        got = None if after is None else {n.name: n.serial_number for n in after.nodes.values()}
        ids = None if after is None else {n.name: n.node_id for n in after.nodes.values()}
        if got != expected or ids != {n.name: n.node_id for n in self._all}:
            raise NetworkWriteError(
                f"{self.path}: the serials could not be added without changing what else the "
                f"file says, so it is left alone; add by hand: {by_hand}"
            )


_KEY = r"""[ \t]*["']?{}["']?[ \t]*:"""


def _edit(lines: list[str], entry: LineMap, serial: int) -> tuple[int, bool, str] | None:
    """The line to change for ``entry``'s serial: its ``serial_number`` line given a new
    value (a placeholder such as 0), or one added after its ``node_id`` line, indented
    alike and with the same line end; None when the entry is not one key per line."""
    value = f"0x{serial:08X}"
    at = entry.lines.get("serial_number")
    if at is not None and 1 <= at <= len(lines):
        line = lines[at - 1]
        match = re.match(
            rf"({_KEY.format('serial_number')}[ \t]*)[^#\r\n]*?([ \t]*(#[^\r\n]*)?\r?\n?)$",
            line,
        )
        if match is None:
            return None
        return at - 1, True, f"{match.group(1)}{value}{match.group(2)}"
    at = entry.lines.get("node_id")
    if at is None or not 1 <= at <= len(lines):
        return None
    line = lines[at - 1]
    if not re.match(_KEY.format("node_id") + r"[ \t]*[^\s#]", line):
        return None  # (flow style, or its value on the next line)
    indent = re.match(r"[ \t]*", line)
    assert indent is not None
    end = "\r\n" if line.endswith("\r\n") else "\n"
    before = "" if line.endswith("\n") else end
    return (
        at,
        False,
        f"{before}{indent.group(0)}serial_number: {value}   # by cobus lss assign-all{end}",
    )
