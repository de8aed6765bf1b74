"""cobus: a CANopen stack and toolkit on python-can.

Layers (see ``ARCHITECTURE.md`` in the shared folder):

- :mod:`cobus.od` — object dictionary, CiA 301 data types, CiA 306 EDS/DCF.
- :mod:`cobus.proto` — sans-I/O protocol machines (SDO, NMT, heartbeat, ...).
- :mod:`cobus.runtime` — the network: a bus, a clock, dispatch.

``docs/architecture.md`` gives, for each CiA service, the file that holds it in each layer.

One naming rule, for every public name:

- an event (what a machine or a service reports) is a past-tense fact: ``BootupReceived``,
  ``EmergencySent``, ``TransferFailed``;
- an exception ends in ``Error``: ``SdoTimeoutError``, ``NameLookupError``;
- ``AsyncX`` is the asyncio class and ``X`` its blocking twin (``AsyncNetwork`` /
  ``Network``, ``AsyncDrive402`` / ``Drive402``, ``AsyncRemoteNode`` / ``RemoteNode``); where
  the asyncio class has long had the plain name (``Master``, ``Device``, ``Rig``,
  ``Simulation``, ``SimulatedDevice``, ``NmtMaster``, ``SdoChannel``, ``NetworkSync``) its
  twin is ``BlockingX``, since turning those names into other classes would break every
  program that uses them;
- one idea has one name, and no two classes of cobus share one (a simulated device is
  ``SimulatedX``, a decoded trace record ``XRecord``); one field has one name wherever the
  idea travels (an emergency's bytes are ``manufacturer_data`` in the record and its events);
  ``tests/test_layout.py`` checks both rules;
- a renamed public name keeps working for one release and warns with the new one
  (:class:`cobus._moved.Renamed`); a moved one says where it went.
"""

__version__ = "0.1.0"
