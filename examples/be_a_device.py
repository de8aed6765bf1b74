"""Be a CANopen device: a valve block with a set-point (written by the master, by SDO or
RPDO) and a pressure it reports by TPDO, its settings kept across resets by 1010h "save".

    python examples/be_a_device.py --simulated      # and a master on the same network
    python examples/be_a_device.py -i socketcan -c can0 -b 500000 --node 5 --duration 0

On a real bus it runs until Ctrl-C (``--duration 0``) or for ``--duration`` seconds; a master
(cobus, python-canopen, a PLC) reads its EDS from 1021h. With ``--simulated`` a cobus
master on the same simulated network writes the set-point and reads the pressure.
"""

from __future__ import annotations

import argparse
import math
import sys

from _bench import add_bus_arguments, open_network
from cobus.device import DictionaryBuilder, add_device
from cobus.od import DataType, loads


def valve_block() -> DictionaryBuilder:
    b = DictionaryBuilder(device_name="valve block", vendor_id=0x0000_0C0B, product_code=0x5)
    b.variable(0x2000, "Setpoint", DataType.INTEGER16, access="rww", mappable=True)
    b.variable(0x2001, "Pressure", DataType.INTEGER16, access="ro", mappable=True)
    b.tpdo(1, [(0x2001, 0)], transmission_type=255, event_timer_ms=100)
    b.rpdo(1, [(0x2000, 0)])
    return b


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_bus_arguments(parser)
    parser.add_argument("--node", type=int, default=5, help="the device's node-ID (default 5)")
    parser.add_argument("--storage", default="valve.json", help="where 1010h 'save' writes")
    args = parser.parse_args(argv)
    with open_network(args) as net:
        dev = add_device(net, args.node, valve_block().build(), storage=args.storage)
        dev.on_write(0x2000, 0, lambda value: print(f"set-point written: {value}"))
        print(f"valve block on node {args.node}, {dev.state}")
        master = None
        if args.simulated:
            master = net.add_remote(args.node, loads(dev.to_eds(), node_id=args.node))
            master.nmt.start()
            master.tpdo.read()
            master.sdo.write("Setpoint", 300)
        t, step = 0.0, 0.1
        while args.duration <= 0 or t < args.duration:
            # the pressure follows the set-point like a first-order system, with some ripple
            setpoint = dev.get(0x2000)
            pressure = dev.get(0x2001)
            ripple = 3 * math.sin(2 * math.pi * t)
            dev.set(0x2001, 0, round(pressure + (setpoint - pressure) * 0.2 + ripple))
            net.sleep(step)
            t += step
        if master is not None:
            print(f"the master reads pressure {master.tpdo[1]['Pressure']} (set-point 300)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
