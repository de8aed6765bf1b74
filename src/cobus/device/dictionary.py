"""Object dictionaries for devices built in code: the CiA 301 communication profile and a
small builder for the application's objects and default PDO mappings.

:func:`minimal_od` gives a dictionary with every communication object a
:class:`~cobus.device.Device` serves (1000h..1029h, SDO server, PDOs). Values that follow the
node-ID (SDO COB-IDs, EMCY, the pre-defined PDO COB-IDs 1-4) are
:class:`~cobus.od.NodeRelative` defaults, so they follow ``od.node_id`` and the device's EDS
export writes them as ``$NODEID`` expressions. :class:`DictionaryBuilder` adds application
objects and default PDO mappings on top.

The dictionary is built as objects directly (an earlier version wrote EDS text and read it
back: the objects are the same, five times faster to make).
"""

from __future__ import annotations

import datetime as _dt
from collections.abc import Sequence
from typing import Any

from cobus.device import emcy, guarding, heartbeat, nmt, pdo, sdo_server, storage, sync, timestamp
from cobus.device._objects import CONST as _CONST
from cobus.device._objects import RO as _RO
from cobus.device._objects import U8 as _U8
from cobus.device._objects import U16 as _U16
from cobus.device._objects import U32 as _U32
from cobus.device._objects import var as _var
from cobus.device.errors import DeviceConfigError
from cobus.od import (
    Access,
    Array,
    DataType,
    DeviceInfo,
    FileInfo,
    ObjectDictionary,
    Record,
    Variable,
    validate,
)

__all__ = ["DEFAULT_DEVICE_TYPE", "DictionaryBuilder", "minimal_od"]

#: 1000h of a device without a profile: CiA 401 (generic I/O) as the seeds' devices declare.
DEFAULT_DEVICE_TYPE = 0x191

_MAX_PDOS = 512
_MAX_MAP_ENTRIES = 64


_BIT_RATES = {10, 20, 50, 125, 250, 500, 800, 1000}


def _check_count(what: str, value: int, low: int, high: int) -> int:
    if not isinstance(value, int) or isinstance(value, bool) or not low <= value <= high:
        raise DeviceConfigError(f"{what} {value!r} is out of range: use {low}..{high}")
    return value


def _text(value: str, what: str) -> str:
    if not isinstance(value, str) or not value.isascii() or not value.isprintable():
        raise DeviceConfigError(f"{what} {value!r} must be printable ASCII text")
    return value


def minimal_od(
    *,
    node_id: int | None = None,
    device_type: int = DEFAULT_DEVICE_TYPE,
    vendor_id: int = 0,
    product_code: int = 0,
    revision: int = 0,
    serial: int = 0,
    device_name: str = "cobus device",
    vendor_name: str = "cobus",
    hardware_version: str = "",
    software_version: str = "",
    rpdos: int = 4,
    tpdos: int = 4,
    mapping_entries: int = 8,
    heartbeat_consumers: int = 4,
    sdo_servers: int = 1,
    error_history: int = 8,
) -> ObjectDictionary:
    """A CiA 301 dictionary with every communication object a device serves.

    PDO 1-4 get the pre-defined COB-IDs (``$NODEID+0x180`` ...), the others are invalid until
    configured; every PDO starts with an empty mapping of ``mapping_entries`` entries and
    transmission type 255. ``node_id`` resolves the ``$NODEID`` values at once (the device
    does it anyway). Add the application's objects with ``od.add(...)`` or use
    :class:`DictionaryBuilder`.
    """
    for what, value in (
        ("device type", device_type),
        ("vendor-ID", vendor_id),
        ("product code", product_code),
        ("revision number", revision),
        ("serial number", serial),
    ):
        _check_count(what, value, 0, 0xFFFFFFFF)
    _check_count("number of RPDOs", rpdos, 0, _MAX_PDOS)
    _check_count("number of TPDOs", tpdos, 0, _MAX_PDOS)
    _check_count("mapping entries per PDO", mapping_entries, 1, _MAX_MAP_ENTRIES)
    _check_count("number of heartbeat consumers (1016h)", heartbeat_consumers, 1, 127)
    _check_count("number of SDO servers", sdo_servers, 1, 128)
    _check_count("error history depth (1003h)", error_history, 0, 254)
    if node_id is not None:
        _check_count("node-ID", node_id, 1, 127)
    od = ObjectDictionary()
    _profile(
        od,
        device_type=device_type,
        identity=(vendor_id, product_code, revision, serial),
        device_name=_text(device_name, "device name"),
        hardware_version=_text(hardware_version, "hardware version") if hardware_version else "",
        software_version=_text(software_version, "software version") if software_version else "",
        vendor_name=_text(vendor_name, "vendor name"),
        rpdos=rpdos,
        tpdos=tpdos,
        mapping_entries=mapping_entries,
        heartbeat_consumers=heartbeat_consumers,
        sdo_servers=sdo_servers,
        error_history=error_history,
    )
    if node_id is not None:
        od.node_id = node_id
    return od


def _profile(
    od: ObjectDictionary,
    *,
    device_type: int,
    identity: tuple[int, int, int, int],
    device_name: str,
    hardware_version: str,
    software_version: str,
    vendor_name: str,
    rpdos: int,
    tpdos: int,
    mapping_entries: int,
    heartbeat_consumers: int,
    sdo_servers: int,
    error_history: int,
) -> None:
    """Fill ``od`` with the file information and the communication objects."""
    od.file_info = FileInfo(
        file_name="cobus_device.eds",
        file_version="1",
        file_revision="0",
        eds_version="4.0",
        description=device_name,
        creation_time="12:00PM",
        creation_date=f"{_dt.date.today():%m-%d-%Y}",
        created_by="cobus",
    )
    od.device_info = DeviceInfo(
        vendor_name=vendor_name,
        vendor_number=identity[0],
        product_name=device_name,
        product_number=identity[1],
        revision_number=identity[2],
        order_code="",
        baud_rates=set(_BIT_RATES),
        simple_boot_up_master=False,
        simple_boot_up_slave=True,
        granularity=8,
        dynamic_channels_supported=0,
        group_messaging=False,
        nr_of_rx_pdo=rpdos,
        nr_of_tx_pdo=tpdos,
        lss_supported=False,
    )
    for code in range(1, 8):  # the device maps a dummy of every basic type 0001h..0007h
        od.set_dummy_usage(code)
    # the device's own objects; each service defines the objects it serves (CiA 301 order)
    add = od.add
    add(_var(0x1000, 0, "Device type", _U32, _RO, device_type))
    emcy.define_objects(od, history=error_history)
    sync.define_objects(od)
    vs = DataType.VISIBLE_STRING
    add(_var(0x1008, 0, "Manufacturer device name", vs, _CONST, device_name))
    add(_var(0x1009, 0, "Manufacturer hardware version", vs, _CONST, hardware_version or None))
    add(_var(0x100A, 0, "Manufacturer software version", vs, _CONST, software_version or None))
    guarding.define_objects(od)
    storage.define_objects(od)
    timestamp.define_objects(od)
    heartbeat.define_objects(od, consumers=heartbeat_consumers)
    identity_names = ("Vendor-ID", "Product code", "Revision number", "Serial number")
    identity_obj = Record(0x1018, "Identity object")
    identity_obj.add(_var(0x1018, 0, "Highest sub-index supported", _U8, _RO, 4))
    for sub, name in enumerate(identity_names, 1):
        identity_obj.add(_var(0x1018, sub, name, _U32, _RO, identity[sub - 1]))
    add(identity_obj)
    add(_var(0x1021, 0, "Store EDS", DataType.DOMAIN, _RO, None))
    add(_var(0x1022, 0, "Store format", _U16, _RO, 0))
    nmt.define_objects(od)
    sdo_server.define_objects(od, servers=sdo_servers)
    pdo.define_objects(od, rpdos=rpdos, tpdos=tpdos, entries=mapping_entries)


_ACCESS = {a.value: a for a in Access}


def _access(value: Access | str) -> Access:
    if isinstance(value, Access):
        return value
    try:
        return _ACCESS[value.lower()]
    except (KeyError, AttributeError):
        raise DeviceConfigError(
            f"access {value!r} is unknown: use one of {', '.join(_ACCESS)}"
        ) from None


class DictionaryBuilder:
    """Builds a device's dictionary: :func:`minimal_od` plus the application's objects and
    default PDO mappings.

    >>> b = DictionaryBuilder(device_name="valve block")
    >>> b.variable(0x2000, "Setpoint", DataType.INTEGER16, access="rww", mappable=True)
    >>> b.tpdo(1, [(0x2000, 0)], transmission_type=255, event_timer_ms=100)
    >>> od = b.build()

    The variables' access follows the seeds' convention for controller variables when left
    out: ``ro`` entries go to TPDOs, ``wo``/``rww`` to RPDOs, ``rw`` is SDO only.
    """

    def __init__(self, **profile: Any) -> None:
        self.od = minimal_od(**profile)

    def variable(
        self,
        index: int,
        name: str,
        data_type: DataType,
        *,
        subindex: int | None = None,
        access: Access | str = Access.RW,
        mappable: bool = False,
        default: Any = None,
        low: Any = None,
        high: Any = None,
        unit: str | None = None,
    ) -> Variable:
        """Add a VAR object (``subindex`` None) or a sub-object of a record made by
        :meth:`record`. The default, when given, must fit the type and the limits."""
        if not isinstance(index, int) or not 0x2000 <= index <= 0xFFFF:
            raise DeviceConfigError(
                f"application object 0x{index:04X} must lie in 2000h..FFFFh; the communication "
                "area 1000h-1FFFh comes from minimal_od()"
                if isinstance(index, int)
                else f"index {index!r} is not an int"
            )
        var = Variable(
            index,
            subindex or 0,
            name,
            data_type,
            _access(access),
            mappable,
            default=default,
            low_limit=low,
            high_limit=high,
            unit=unit,
        )
        if subindex is None:
            self.od.add(var)
            return var
        parent = self.od.get(index)
        if not isinstance(parent, Record | Array):
            raise DeviceConfigError(
                f"0x{index:04X} is not a record or array yet: call record() or array() first"
            )
        parent.add(var)
        self._count(parent)
        return var

    def record(self, index: int, name: str) -> Record:
        """Add an empty RECORD; fill it with ``variable(index, ..., subindex=n)``."""
        rec = Record(index, name)
        rec.add(
            Variable(
                index, 0, "Highest sub-index supported", DataType.UNSIGNED8, Access.RO, default=0
            )
        )
        self.od.add(rec)
        return rec

    def array(
        self,
        index: int,
        name: str,
        data_type: DataType,
        count: int,
        *,
        access: Access | str = Access.RW,
        mappable: bool = False,
        default: Any = None,
        low: Any = None,
        high: Any = None,
    ) -> Array:
        """Add an ARRAY of ``count`` entries of one type (sub 0 holds the count)."""
        _check_count(f"entries of 0x{index:04X}", count, 1, 254)
        arr = Array(index, name)
        arr.add(
            Variable(
                index,
                0,
                "Highest sub-index supported",
                DataType.UNSIGNED8,
                Access.RO,
                default=count,
            )
        )
        for n in range(1, count + 1):
            arr.add(
                Variable(
                    index,
                    n,
                    f"{name} {n}",
                    data_type,
                    _access(access),
                    mappable,
                    default=default,
                    low_limit=low,
                    high_limit=high,
                )
            )
        self.od.add(arr)
        return arr

    @staticmethod
    def _count(obj: Record | Array) -> None:
        sub0 = obj.subindices.get(0)
        if sub0 is not None:
            sub0.default = max(s for s in obj.subindices if s)

    def tpdo(
        self,
        number: int,
        entries: Sequence[tuple[int, int]],
        *,
        transmission_type: int = 255,
        inhibit_time_100us: int = 0,
        event_timer_ms: int = 0,
        sync_start_value: int = 0,
    ) -> None:
        """Set the default mapping and transmission of TPDO ``number`` (1-based)."""
        comm = pdo.define_default(self.od, "TPDO", number, entries, transmission_type)
        comm[3].default = inhibit_time_100us
        comm[5].default = event_timer_ms
        comm[6].default = sync_start_value

    def rpdo(
        self,
        number: int,
        entries: Sequence[tuple[int, int]],
        *,
        transmission_type: int = 255,
        event_timer_ms: int = 0,
    ) -> None:
        """Set the default mapping and transmission of RPDO ``number`` (1-based)."""
        comm = pdo.define_default(self.od, "RPDO", number, entries, transmission_type)
        comm[5].default = event_timer_ms

    def build(self) -> ObjectDictionary:
        """The dictionary; raises :class:`DeviceConfigError` listing what is inconsistent
        (PDO mappings of objects that are not mappable, too long, ...)."""
        problems = [str(f) for f in validate(self.od) if f.severity.value == "error"]
        if problems:
            raise DeviceConfigError("the dictionary is inconsistent:\n" + "\n".join(problems))
        return self.od
