"""Simulated devices for the bench: faithful models of the documents' devices, with faults.

See :mod:`cobus.sim.base` for what all of them share, :mod:`cobus.sim.generic` for what the
simulated CANopen devices share, :mod:`cobus.sim.faults` for the bus faults and
:mod:`cobus.sim.rig` for rig files (``cobus sim RIG``).

- :class:`Drive402` (kind ``cia402_drive``): a CiA 402 servo drive with a motor model.
- :class:`Io401` (kind ``cia401_io``): a CiA 401 I/O module with a speed potentiometer.
- :class:`EdsDevice` (kind ``eds``): the device of any EDS/DCF file.
- :func:`start_rig` runs a rig from blocking code (``start_rig(net, "thesis")``).
"""

from cobus.sim.base import SimulatedDevice, SimulationError, UnknownFaultError, UnknownQuirkError
from cobus.sim.blocking import BlockingRig, BlockingSimulatedDevice, start_rig
from cobus.sim.drive402 import Drive402, DriveState
from cobus.sim.ecmotor import EcMotor
from cobus.sim.faults import Babbler, FaultConfigError, FaultyBus, fault_catalogue
from cobus.sim.generic import (
    CanopenSimDevice,
    DeviceOffError,
    EdsDevice,
    EdsDeviceError,
    FaultParameterError,
)
from cobus.sim.io401 import ChannelError, Io401
from cobus.sim.rig import KINDS, KindUnavailableError, Rig, RigError, ready_rig, resolve_kind
from cobus.sim.stober import StoberMds5000
from cobus.sim.zapi import ZapiAce2

__all__ = [
    "KINDS",
    "Babbler",
    "BlockingRig",
    "BlockingSimulatedDevice",
    "CanopenSimDevice",
    "ChannelError",
    "DeviceOffError",
    "Drive402",
    "DriveState",
    "EcMotor",
    "EdsDevice",
    "EdsDeviceError",
    "FaultConfigError",
    "FaultParameterError",
    "FaultyBus",
    "Io401",
    "KindUnavailableError",
    "Rig",
    "RigError",
    "SimulatedDevice",
    "SimulationError",
    "StoberMds5000",
    "UnknownFaultError",
    "UnknownQuirkError",
    "ZapiAce2",
    "fault_catalogue",
    "ready_rig",
    "resolve_kind",
    "start_rig",
]
