"""Device profiles run from the master side: the drives and I/O a user commands.

- :mod:`cobus.profiles.cia402` — CiA 402 sans I/O: power states from the statusword, the
  controlword commands, modes of operation, error code texts.
- :mod:`cobus.profiles.drive402` — :class:`AsyncDrive402` / :class:`Drive402`: enable, move,
  home, run at a velocity or a torque, follow a trajectory every SYNC, with typed errors.
- :mod:`cobus.profiles.axes` — several drives enabled or quick-stopped together.
- :mod:`cobus.profiles.trajectory` — motion profiles for the cyclic modes (:class:`Trapezoid`,
  jerk-limited :class:`SCurve`).
- :mod:`cobus.profiles.zapi` — the ZAPI ACE2 inverter of the thesis, its handshake kept.
- :mod:`cobus.profiles.stober` — the STÖBER MDS 5000: parameters by name, E82 events.
- :mod:`cobus.profiles.ecmotor` — the EC motor of seed 002: its own SDO dialect as a client.
- :mod:`cobus.profiles.io401` — CiA 401 I/O modules: named channels, scaling, change callbacks.
"""

from cobus.profiles.cia402 import Command, OperationMode, PowerState, Statusword, error_text
from cobus.profiles.drive402 import (
    AsyncDrive402,
    Drive402,
    DriveError,
    DriveFault,
    DriveStateError,
    DriveTimeoutError,
    HomingError,
    Quirks,
)
from cobus.profiles.trajectory import SCurve, Trajectory, Trapezoid

__all__ = [
    "AsyncDrive402",
    "Command",
    "Drive402",
    "DriveError",
    "DriveFault",
    "DriveStateError",
    "DriveTimeoutError",
    "HomingError",
    "OperationMode",
    "PowerState",
    "Quirks",
    "SCurve",
    "Statusword",
    "Trajectory",
    "Trapezoid",
    "error_text",
]
