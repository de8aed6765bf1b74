"""The EDS of a device (CiA 306), written by the dictionary's own writer.

The export describes the running device, not only its dictionary; the dictionary itself is
not changed. What a dictionary built in code leaves open is filled in (file information,
product and vendor from 1008h/1018h, all standard bit rates), and the capabilities are those
this device implements: simple boot-up slave, no LSS, no dynamic SDO channels, the PDO counts
of the dictionary and dummy mapping of every basic type 0001h..0007h.
"""

from __future__ import annotations

import datetime as _dt
from dataclasses import replace

from cobus.device.pdo import count_pdos
from cobus.od import ObjectDictionary

__all__ = ["export_eds"]

_BIT_RATES = {10, 20, 50, 125, 250, 500, 800, 1000}


def export_eds(od: ObjectDictionary, *, description: str | None = None) -> str:
    """The EDS text of ``od`` with complete [FileInfo] and [DeviceInfo] sections."""
    file_info = replace(od.file_info, extra=dict(od.file_info.extra))
    info = replace(
        od.device_info, baud_rates=set(od.device_info.baud_rates), extra=dict(od.device_info.extra)
    )
    name_var = od.get_variable(0x1008, 0)
    product = name_var.value if name_var is not None and name_var.value else None
    now = _dt.datetime.now()
    if file_info.file_name is None:
        file_info.file_name = "device.eds"
    if file_info.file_version is None:
        file_info.file_version = "1"
    if file_info.file_revision is None:
        file_info.file_revision = "0"
    if file_info.eds_version is None:
        file_info.eds_version = "4.0"
    if description is not None:
        file_info.description = description
    elif file_info.description is None:
        file_info.description = product or "cobus device"
    if file_info.creation_date is None:
        file_info.creation_date = f"{now:%m-%d-%Y}"
        file_info.creation_time = now.strftime("%I:%M%p")
    if file_info.created_by is None:
        file_info.created_by = "cobus"
    identity = {
        sub: var.value
        for sub in (1, 2, 3)
        if (var := od.get_variable(0x1018, sub)) is not None and isinstance(var.value, int)
    }
    if info.vendor_number is None and 1 in identity:
        info.vendor_number = identity[1]
    if info.product_number is None and 2 in identity:
        info.product_number = identity[2]
    if info.revision_number is None and 3 in identity:
        info.revision_number = identity[3]
    if info.product_name is None:
        info.product_name = product or "cobus device"
    if info.vendor_name is None:
        info.vendor_name = "cobus"
    if not info.baud_rates:
        info.baud_rates = set(_BIT_RATES)
    # what this device implements, whatever the dictionary's file said
    info.simple_boot_up_master = False
    info.simple_boot_up_slave = True
    if not info.granularity:
        info.granularity = 8
    info.dynamic_channels_supported = 0
    info.group_messaging = False
    info.nr_of_rx_pdo, info.nr_of_tx_pdo = count_pdos(od)
    info.lss_supported = False
    dummies = dict(od.dummy_usage)
    dummies.update(dict.fromkeys(range(1, 8), True))  # the device maps a dummy of 0001h..0007h
    return od.to_eds(file_info=file_info, device_info=info, dummy_usage=dummies)
