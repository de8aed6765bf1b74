"""The pre-defined connection set of CiA 301: the default COB-IDs of a node's services.

Every identifier of the set is a function code (the top four of the 11 bits) plus the
node-ID (1..127), except the broadcast ones (NMT 000h, SYNC 080h, TIME 100h) and LSS
(7E4h/7E5h, CiA 305). This module is the one place cobus spells them; the services'
modules name theirs from here (``SYNC_COB_ID``, ``EMCY_BASE``...).

    >>> sdo_cob_ids(10)
    (1546, 1418)
    >>> hex(emcy_cob_id(10)), hex(error_control_cob_id(10)), hex(tpdo_cob_id(2, 10))
    ('0x8a', '0x70a', '0x28a')
    >>> service_of(0x58A)
    ('sdo_tx', 10)
"""

from __future__ import annotations

__all__ = [
    "EMCY_BASE",
    "ERROR_CONTROL_BASE",
    "LSS_MASTER_COB_ID",
    "LSS_SLAVE_COB_ID",
    "MAX_NODE_ID",
    "NMT_COB_ID",
    "RPDO_BASE",
    "SDO_RX_BASE",
    "SDO_TX_BASE",
    "SYNC_COB_ID",
    "TIME_COB_ID",
    "TPDO_BASE",
    "emcy_cob_id",
    "error_control_cob_id",
    "rpdo_cob_id",
    "sdo_cob_ids",
    "service_of",
    "tpdo_cob_id",
]

NMT_COB_ID = 0x000
SYNC_COB_ID = 0x080
#: EMCY: 080h + node-ID (080h itself is SYNC).
EMCY_BASE = 0x080
TIME_COB_ID = 0x100
#: TPDO 1..4: 180h, 280h, 380h, 480h + node-ID (the step between them: PDO_STEP).
TPDO_BASE = 0x180
#: RPDO 1..4: 200h, 300h, 400h, 500h + node-ID.
RPDO_BASE = 0x200
PDO_STEP = 0x100
#: SDO server to client (the server's answers): 580h + node-ID.
SDO_TX_BASE = 0x580
#: SDO client to server (the requests): 600h + node-ID.
SDO_RX_BASE = 0x600
#: Error control (heartbeat, boot-up, node guarding): 700h + node-ID.
ERROR_CONTROL_BASE = 0x700
#: LSS (CiA 305): the slaves answer on 7E4h, the master asks on 7E5h.
LSS_SLAVE_COB_ID = 0x7E4
LSS_MASTER_COB_ID = 0x7E5
#: The highest node-ID: a base + node-ID stays below base + 80h.
MAX_NODE_ID = 0x7F

_FUNCTIONS = {
    EMCY_BASE: "emcy",
    TPDO_BASE: "tpdo1",
    RPDO_BASE: "rpdo1",
    TPDO_BASE + PDO_STEP: "tpdo2",
    RPDO_BASE + PDO_STEP: "rpdo2",
    TPDO_BASE + 2 * PDO_STEP: "tpdo3",
    RPDO_BASE + 2 * PDO_STEP: "rpdo3",
    TPDO_BASE + 3 * PDO_STEP: "tpdo4",
    RPDO_BASE + 3 * PDO_STEP: "rpdo4",
    SDO_TX_BASE: "sdo_tx",
    SDO_RX_BASE: "sdo_rx",
    ERROR_CONTROL_BASE: "error_control",
}


def _node(node_id: int) -> int:
    if isinstance(node_id, bool) or not isinstance(node_id, int) or not 1 <= node_id <= 127:
        raise ValueError(f"node-ID {node_id!r}: the pre-defined connection set covers 1..127")
    return node_id


def sdo_cob_ids(node_id: int) -> tuple[int, int]:
    """The default SDO channel of a node: (client to server 600h + id, server to client
    580h + id)."""
    node = _node(node_id)
    return SDO_RX_BASE + node, SDO_TX_BASE + node


def emcy_cob_id(node_id: int) -> int:
    """080h + node-ID."""
    return EMCY_BASE + _node(node_id)


def error_control_cob_id(node_id: int) -> int:
    """700h + node-ID: heartbeat, boot-up and node guarding."""
    return ERROR_CONTROL_BASE + _node(node_id)


def _pdo(base: int, number: int, node_id: int) -> int:
    if isinstance(number, bool) or not isinstance(number, int) or not 1 <= number <= 4:
        raise ValueError(f"the pre-defined connection set covers PDO 1..4, not {number!r}")
    return base + PDO_STEP * (number - 1) + _node(node_id)


def tpdo_cob_id(number: int, node_id: int) -> int:
    """TPDO ``number`` (1..4): 180h/280h/380h/480h + node-ID."""
    return _pdo(TPDO_BASE, number, node_id)


def rpdo_cob_id(number: int, node_id: int) -> int:
    """RPDO ``number`` (1..4): 200h/300h/400h/500h + node-ID."""
    return _pdo(RPDO_BASE, number, node_id)


def service_of(cob_id: int) -> tuple[str, int | None]:
    """Which service of the set an 11-bit identifier is, and for which node: ("nmt", None),
    ("sync", None), ("time", None), ("lss_master" / "lss_slave", None), ("emcy", 10),
    ("tpdo1".."tpdo4" / "rpdo1".."rpdo4", 10), ("sdo_tx" / "sdo_rx", 10),
    ("error_control", 10); ("other", None) for one outside the set."""
    if cob_id == NMT_COB_ID:
        return "nmt", None
    if cob_id == SYNC_COB_ID:
        return "sync", None
    if cob_id == TIME_COB_ID:
        return "time", None
    if cob_id == LSS_MASTER_COB_ID:
        return "lss_master", None
    if cob_id == LSS_SLAVE_COB_ID:
        return "lss_slave", None
    node = cob_id & 0x7F
    name = _FUNCTIONS.get(cob_id & 0x780)
    if name is None or node == 0 or not 0 <= cob_id <= 0x7FF:
        return "other", None
    return name, node
