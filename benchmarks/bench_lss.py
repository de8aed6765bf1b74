"""How long a fastscan takes to find one unconfigured device: cobus's ``net.lss.fastscan()``
beside python-canopen's ``network.lss.fast_scan()``, on the same cobus device (an LSS slave
that starts without a node-ID) on python-can's virtual bus, in real time.

python-canopen waits its full response timeout (0.5 s by default) for every bit that is 1
and sleeps 10 ms after every probe; cobus's window adapts to the round trip it measures
(floor 10 ms, ceiling 0.5 s) and skips the fields it is told. Rows: each as a user gets it,
then python-canopen with its timeout cut to 50 ms, and cobus told the vendor and product.
The identity has 27 one-bits in its 128, so the figures scale with that.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable

import canopen

from benchmarks.common import header, row
from cobus.device import UNCONFIGURED, add_device, minimal_od
from cobus.proto.lss import LssIdentity, LssState
from cobus.runtime import Network

IDENTITY = LssIdentity(0x360, 0x1234, 0x0001_0002, 0x8BAD_F00D)


def _timed(scan: Callable[[], object], reset: Callable[[], None]) -> tuple[float, object]:
    t0 = time.perf_counter()
    found = scan()
    elapsed = time.perf_counter() - t0
    reset()  # the device found is in configuration state: back to waiting for the next scan
    return elapsed * 1000, found


def main() -> None:
    channel = f"bench-lss-{os.getpid()}"
    v, p, r, s = IDENTITY.fields
    od = minimal_od(vendor_id=v, product_code=p, revision=r, serial=s)
    with (
        Network(interface="virtual", channel=channel) as device_net,
        Network(interface="virtual", channel=channel) as net,
    ):
        add_device(device_net, UNCONFIGURED, od)
        cnet = canopen.Network()
        cnet.connect(interface="virtual", channel=channel)
        try:

            def waiting() -> None:
                net.lss.switch_global(LssState.WAITING)
                net.sleep(0.05)

            def canopen_scan(timeout: float) -> Callable[[], object]:
                def scan() -> object:
                    cnet.lss.RESPONSE_TIMEOUT = timeout
                    found, fields = cnet.lss.fast_scan()
                    assert found and fields == list(IDENTITY.fields), fields
                    return fields

                return scan

            def cobus_scan(known: dict[str, int] | None) -> Callable[[], object]:
                def scan() -> object:
                    found = net.lss.fastscan(known)
                    assert found == IDENTITY, found
                    return found

                return scan

            cobus_default, _ = _timed(cobus_scan(None), waiting)
            cobus_known, _ = _timed(cobus_scan({"vendor": v, "product": p}), waiting)
            canopen_default, _ = _timed(canopen_scan(0.5), waiting)
            canopen_fast, _ = _timed(canopen_scan(0.05), waiting)
        finally:
            cnet.disconnect()
    print(header("LSS fastscan of one unconfigured device, real time (ms; lower is better)"))
    print(
        row(
            "fastscan, as each comes (canopen: 0.5 s timeout)",
            cobus_default,
            canopen_default,
            "ms",
            False,
        )
    )
    print(row("fastscan, canopen's timeout cut to 50 ms", cobus_default, canopen_fast, "ms", False))
    print(row("fastscan, vendor and product known (cobus)", cobus_known, None, "ms", False))


if __name__ == "__main__":
    main()
