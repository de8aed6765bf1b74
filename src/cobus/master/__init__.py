"""The CANopen master: the network description (YAML) it boots a network from.

- :func:`load_network` reads a network description (YAML, in the spirit of ROS 2 canopen's
  ``bus.yml``) into a :class:`NetworkConfig`; ``cobus config check FILE`` lists its problems.
"""

from cobus.master.config import (
    MasterConfig,
    NetworkConfig,
    NodeConfig,
    PdoLayout,
    SdoEntry,
    Signal,
    check_network,
    load_network,
    loads_network,
    parse_network,
)
from cobus.master.errors import (
    ConfigProblem,
    NetworkConfigError,
    Severity,
)

__all__ = [
    "ConfigProblem",
    "MasterConfig",
    "NetworkConfig",
    "NetworkConfigError",
    "NodeConfig",
    "PdoLayout",
    "SdoEntry",
    "Severity",
    "Signal",
    "check_network",
    "load_network",
    "loads_network",
    "parse_network",
]
