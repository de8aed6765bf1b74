"""Checks across the nodes of a network file, once each node reads well on its own: two TPDOs
on one COB-ID, two RPDOs on one, an RPDO fed by another node's TPDO (PDO linking), a PDO on
the master's TIME identifier.
"""

from __future__ import annotations

from dataclasses import replace

from cobus.master.config.model import NetworkConfig
from cobus.master.config.values import Report

__all__ = ["cross_checks"]


def cross_checks(network: NetworkConfig, report: Report) -> None:
    """Report what collides across nodes; an RPDO another node's TPDO feeds is marked
    linked (the master does not send it)."""
    producers: dict[int, str] = {}
    for node in network.nodes.values():
        for layout in node.tpdos:
            other = producers.get(layout.cob_id)
            here = f"{node.name} TPDO {layout.number}"
            if other is not None:
                report.error(
                    node.name,
                    f"tpdo{layout.number}",
                    f"COB-ID 0x{layout.cob_id:X} is also sent by {other}: two producers collide",
                    None,
                )
            producers.setdefault(layout.cob_id, here)
    consumers: dict[int, str] = {}
    for node in network.nodes.values():
        for i, layout in enumerate(node.rpdos):
            here = f"{node.name} RPDO {layout.number}"
            other = consumers.get(layout.cob_id)
            if other is not None:
                report.error(
                    node.name,
                    f"rpdo{layout.number}",
                    f"COB-ID 0x{layout.cob_id:X} is also {other}'s; give each RPDO its own",
                    None,
                )
            consumers.setdefault(layout.cob_id, here)
            source = producers.get(layout.cob_id)
            if source is not None:
                report.warning(
                    node.name,
                    f"rpdo{layout.number}",
                    f"COB-ID 0x{layout.cob_id:X} is fed by {source} (PDO linking): the master "
                    "does not send it",
                    None,
                )
                node.rpdos[i] = replace(
                    layout, positions=tuple(None for _ in layout.positions), linked=True
                )
    # two enabled LSS nodes with one address (a revision left out matches any revision)
    addresses: dict[tuple[int, int, int], list[tuple[int, str]]] = {}
    for node in network.nodes.values():
        if not node.lss or not node.enabled:
            continue
        key = (node.vendor_id, node.product_code, node.serial_number)
        seen = addresses.setdefault(key, [])
        rev = node.revision_number
        other = next((name for r, name in seen if not r or not rev or r == rev), None)
        if other is not None:
            report.error(
                node.name,
                "lss",
                f"node {other!r} has the same LSS address (vendor, product, serial; a "
                "revision_number left out matches any): LSS cannot tell the two devices apart",
                None,
            )
        seen.append((rev, node.name))
    master = network.master
    if master.time_period:
        for node in network.nodes.values():
            for layout in (*node.tpdos, *node.rpdos):
                if layout.cob_id == master.time_cob_id:
                    report.error(
                        node.name,
                        f"{layout.direction}{layout.number}",
                        f"COB-ID 0x{layout.cob_id:X} is the master's TIME identifier",
                        None,
                    )
