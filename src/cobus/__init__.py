"""cobus: a CANopen stack and toolkit on python-can.

Layers (see ``ARCHITECTURE.md`` in the shared folder):

- :mod:`cobus.od` — object dictionary, CiA 301 data types, CiA 306 EDS/DCF.
- :mod:`cobus.proto` — sans-I/O protocol machines (SDO, NMT, heartbeat, ...).
- :mod:`cobus.runtime` — the network: a bus, a clock, dispatch.
"""

__version__ = "0.1.0"
