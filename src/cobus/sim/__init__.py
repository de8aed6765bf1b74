"""Simulated devices for the bench: faithful models of the documents' devices, with faults.

See :mod:`cobus.sim.base` for what all of them share, :mod:`cobus.sim.generic` for what the
simulated CANopen devices share, :mod:`cobus.sim.faults` for the bus faults and
:mod:`cobus.sim.rig` for rig files (``cobus sim RIG``).

- :class:`SimulatedDrive402` (kind ``cia402_drive``): a CiA 402 servo drive with a motor model.
- :class:`SimulatedIo401` (kind ``cia401_io``): a CiA 401 I/O module with a speed potentiometer.
- :class:`EdsDevice` (kind ``eds``): the device of any EDS/DCF file.
- :func:`start_rig` runs a rig from blocking code (``start_rig(net, "thesis")``).
"""

from cobus._moved import renamed_names
from cobus.sim.base import SimulatedDevice, SimulationError, UnknownFaultError, UnknownQuirkError
from cobus.sim.blocking import BlockingRig, BlockingSimulatedDevice, start_rig
from cobus.sim.drive402 import DriveState, SimulatedDrive402
from cobus.sim.ecmotor import EcMotor
from cobus.sim.faults import Babbler, FaultConfigError, FaultyBus, fault_catalogue
from cobus.sim.generic import (
    CanopenSimDevice,
    DeviceOffError,
    EdsDevice,
    EdsDeviceError,
    FaultParameterError,
)
from cobus.sim.io401 import ChannelError, SimulatedIo401
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
    "DriveState",
    "EcMotor",
    "EdsDevice",
    "EdsDeviceError",
    "FaultConfigError",
    "FaultParameterError",
    "FaultyBus",
    "KindUnavailableError",
    "Rig",
    "RigError",
    "SimulatedDevice",
    "SimulatedDrive402",
    "SimulatedIo401",
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

#: One name per idea: cobus.profiles.Drive402 and cobus.profiles.io401.Io401 drive real ones.
__getattr__ = renamed_names(
    __name__,
    {
        "Drive402": ("SimulatedDrive402", SimulatedDrive402),
        "Io401": ("SimulatedIo401", SimulatedIo401),
    },
)
