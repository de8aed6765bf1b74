"""The network description: a YAML file in the spirit of ROS 2 canopen's ``bus.yml``.

```yaml
master:
  node_id: 1               # optional: without it the master sends no heartbeat
  bitrate: 500000          # bit/s
  sync_period: 10          # ms (0: no SYNC); sync_cob_id: 0x80, sync_overflow: 0
  sync_by_interface: false # true: the CAN interface times SYNC (SocketCAN: the kernel;
                           # a simulated network's loop does)
  heartbeat_time: 100      # ms: the master's own heartbeat (needs node_id)
  reset: node              # node | broadcast (one 81h 00 for every node)
  start: node              # node | broadcast (one 01h 00 once every node is configured)
defaults:                  # keys every node takes unless it sets them itself
  heartbeat_time: 100
nodes:
  drive1:
    node_id: 2
    eds: drives/e35.eds    # EDS or DCF, relative to this file (key ``dcf`` works too)
    mandatory: true
    device_type: 0x20192
    tpdo1: {mapping: [statusword, position_actual_value], transmission_type: 1}
    rpdo1: {mapping: [controlword, "0x607A:00"], transmission_type: 255}
    signals:
      position: {object: position_actual_value, scale: 0.001, unit: mm}
```

Times are milliseconds, as plain numbers or as text with a unit (``"1.5 s"``, ``"500 us"``);
``inhibit_time`` is in 100 µs units, as in the dictionary. Objects are named as the node's
EDS names them (case, spaces and punctuation do not matter: ``"Position actual value"`` =
``position_actual_value``), as ``record.sub_name``, ``record[sub]``, or by address
``"0x6041:00"`` (sub-index in hex). :func:`load_network` reads and checks a file;
:func:`check_network` lists every problem with file, line, node and key.

The start-up SDO list of each node is derived from its dictionary: every writable object
whose configured value (DCF ParameterValue, or what this file sets) differs from the EDS
default, the PDOs as the mapping procedure of CiA 301 wants them (disable, clear, map, count,
enable), then the explicit ``sdo`` entries. :meth:`NodeConfig.to_dcf` writes the node's DCF
and :meth:`NodeConfig.concise_dcf` the CiA 302 concise DCF of what the master downloads.
A device whose mapping sub-index 0 is a read-only constant while its entries are writable
(direct mapping, e.g. the STÖBER MDS 5000 of seed 004) gets every entry written instead, 0 for
the unused ones; the master skips those when it reads the mapping.

Devices that are only "based on CANopen" (the EC motor of seed 002: an SDO dialect of its own,
no boot-up, no error control) take ``do_not_initialise: true`` with ``sdo_server: false``: the
master then sends the node no SDO at all (no 1000h/1018h check, no start-up list), counts it
present, and started once it sent the NMT start, and runs its PDOs. An RPDO given an empty
mapping (``rpdo1: {mapping: []}``) is sent with no data (DLC 0), a trigger such a device may
answer, e.g. the EC motor's status poll: a synchronous one with every SYNC, an event-driven
one at the start and with its event timer.

A node with ``lss: true`` and its identity (``vendor_id``, ``product_code``,
``serial_number``; ``revision_number`` too, or the master searches for it) is named by LSS
(CiA 305) at the master's start: the device with that identity takes the node's node-ID
before the node boots, whether it had none or another; ``lss_store: true`` has it store
the node-ID, so that it boots with it by itself at its next power-on.

The package, one idea per module: :mod:`~cobus.master.config.model` (what the master runs),
:mod:`~cobus.master.config.reader` (the file, with its report), :mod:`~cobus.master.config.nodes`
(one node entry), :mod:`~cobus.master.config.pdos` (PDO layouts and signals),
:mod:`~cobus.master.config.startup` (the start-up list), :mod:`~cobus.master.config.checks`
(checks across nodes), :mod:`~cobus.master.config.names` (objects by name) and
:mod:`~cobus.master.config.values` (the value parsers and the report of problems).
"""

from __future__ import annotations

from cobus.master.config.model import (
    BIT_RATES,
    MasterConfig,
    NetworkConfig,
    NodeConfig,
    PdoLayout,
    SdoEntry,
    Signal,
)
from cobus.master.config.names import ObjectIndex, normalise
from cobus.master.config.reader import check_network, load_network, loads_network, parse_network

__all__ = [
    "BIT_RATES",
    "MasterConfig",
    "NetworkConfig",
    "NodeConfig",
    "ObjectIndex",
    "PdoLayout",
    "SdoEntry",
    "Signal",
    "check_network",
    "load_network",
    "loads_network",
    "normalise",
    "parse_network",
]
