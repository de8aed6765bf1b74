"""The operator panel: a local web HMI for a running cobus network (issue 40).

    panel = Panel(port=8047)             # 127.0.0.1 unless told otherwise
    serve_master(panel, master)          # the Network page: nodes, LEDs, NMT buttons, bus load
    serve_alarms(panel, alarm_handler)   # the Alarms page and the rotating current-alarm line
    await panel.start()                  # aiohttp in this loop: no thread, no signal handlers
    print(panel.url)

``cobus run NETWORK.yml --panel`` does the same from the command line. The pages are static
files (package data, no build step; uPlot vendored) talking to the server over one WebSocket:
:mod:`cobus.apps.panel.server` tells the protocol, :mod:`cobus.apps.panel.hub` the queues.
"""

from cobus._moved import renamed_names
from cobus.apps.panel.alarms import AlarmView, serve_alarms
from cobus.apps.panel.drives import DriveView, serve_drive, serve_zapi
from cobus.apps.panel.hub import Client, Hub
from cobus.apps.panel.network import MasterView, serve_master
from cobus.apps.panel.parameters import ParameterView, serve_parameters
from cobus.apps.panel.server import CommandError, Panel, PanelCommand, PanelError
from cobus.apps.panel.trace import TraceView, serve_trace

__all__ = [
    "AlarmView",
    "Client",
    "CommandError",
    "DriveView",
    "Hub",
    "MasterView",
    "Panel",
    "PanelCommand",
    "PanelError",
    "ParameterView",
    "TraceView",
    "serve_alarms",
    "serve_drive",
    "serve_master",
    "serve_parameters",
    "serve_trace",
    "serve_zapi",
]

# (renamed: cobus.profiles.Command is the CiA 402 controlword command)
__getattr__ = renamed_names(__name__, {"Command": ("PanelCommand", PanelCommand)})
