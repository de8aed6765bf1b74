"""Program blocks: the reusable parts a controller program is built from, on top of the
master, the drive profiles and any node with an SDO server.

- :mod:`cobus.blocks.parameters` — parameter sets from YAML, CSV or a DCF;
- :mod:`cobus.blocks.param_manager` — read, compare, write, save, read back and verify a
  node's parameters, by hand or by the master before it starts the node.
"""

from cobus.blocks.param_manager import (
    AsyncParameterManager,
    ParameterFailure,
    Parameterise,
    ParameterManager,
    ParameterReport,
    ParameterStep,
)
from cobus.blocks.parameters import (
    Parameter,
    ParameterFileError,
    ParameterProblem,
    ParameterSet,
    SaveCommand,
    load_parameters,
    loads_parameters,
)

__all__ = [
    "AsyncParameterManager",
    "Parameter",
    "ParameterFailure",
    "ParameterFileError",
    "ParameterManager",
    "ParameterProblem",
    "ParameterReport",
    "ParameterSet",
    "ParameterStep",
    "Parameterise",
    "SaveCommand",
    "load_parameters",
    "loads_parameters",
]
