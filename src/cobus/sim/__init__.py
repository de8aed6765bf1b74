"""Simulated devices for the bench: faithful models of the documents' devices, with faults.

See :mod:`cobus.sim.base` for what all of them share.
"""

from cobus.sim.base import SimulatedDevice, SimulationError, UnknownFaultError, UnknownQuirkError

__all__ = ["SimulatedDevice", "SimulationError", "UnknownFaultError", "UnknownQuirkError"]
