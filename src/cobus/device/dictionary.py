"""Object dictionaries for devices built in code: the CiA 301 communication profile and a
small builder for the application's objects and default PDO mappings.

:func:`minimal_od` gives a dictionary with every communication object a
:class:`~cobus.device.Device` serves (1000h..1029h, SDO server, PDOs). Values that follow the
node-ID (SDO COB-IDs, EMCY, the pre-defined PDO COB-IDs 1-4) are ``$NODEID`` expressions, as an
EDS writes them, so the device's EDS export keeps them relative. :class:`DictionaryBuilder`
adds application objects and default PDO mappings on top.
"""

from __future__ import annotations

import datetime as _dt
from collections.abc import Iterable, Sequence
from typing import Any

from cobus.device.errors import DeviceConfigError
from cobus.od import (
    Access,
    Array,
    DataType,
    ObjectDictionary,
    ObjectType,
    Record,
    Variable,
    loads,
    validate,
)

__all__ = ["DEFAULT_DEVICE_TYPE", "DictionaryBuilder", "minimal_od"]

#: 1000h of a device without a profile: CiA 401 (generic I/O) as the seeds' devices declare.
DEFAULT_DEVICE_TYPE = 0x191

_MAX_PDOS = 512
_MAX_MAP_ENTRIES = 64


def _var(
    out: list[str],
    section: str,
    name: str,
    dt: DataType,
    access: str,
    default: str | None,
    *,
    mappable: bool = False,
) -> None:
    out.append(f"[{section}]")
    out.append(f"ParameterName={name}")
    out.append("ObjectType=0x7")
    out.append(f"DataType=0x{int(dt):04X}")
    out.append(f"AccessType={access}")
    if default is not None:
        out.append(f"DefaultValue={default}")
    out.append(f"PDOMapping={int(mappable)}")
    out.append("")


def _composite(out: list[str], index: int, name: str, kind: ObjectType, subs: int) -> None:
    out.append(f"[{index:04X}]")
    out.append(f"ParameterName={name}")
    out.append(f"ObjectType=0x{int(kind):X}")
    out.append(f"SubNumber=0x{subs:X}")
    out.append("")


def _sub(index: int, sub: int) -> str:
    return f"{index:04X}sub{sub:X}"


def _check_count(what: str, value: int, low: int, high: int) -> int:
    if not isinstance(value, int) or isinstance(value, bool) or not low <= value <= high:
        raise DeviceConfigError(f"{what} {value!r} is out of range: use {low}..{high}")
    return value


def _text(value: str, what: str) -> str:
    if not isinstance(value, str) or not value.isascii() or not value.isprintable():
        raise DeviceConfigError(f"{what} {value!r} must be printable ASCII text")
    return value


def _profile_text(
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
) -> str:
    today = _dt.date.today()
    out = [
        "[FileInfo]",
        "FileName=cobus_device.eds",
        "FileVersion=1",
        "FileRevision=0",
        "EDSVersion=4.0",
        f"Description={device_name}",
        f"CreationDate={today:%m-%d-%Y}",
        "CreationTime=12:00PM",
        "CreatedBy=cobus",
        "",
        "[DeviceInfo]",
        f"VendorName={vendor_name}",
        f"VendorNumber=0x{identity[0]:08X}",
        f"ProductName={device_name}",
        f"ProductNumber=0x{identity[1]:08X}",
        f"RevisionNumber=0x{identity[2]:08X}",
        "OrderCode=",
        *(f"BaudRate_{rate}=1" for rate in (10, 20, 50, 125, 250, 500, 800, 1000)),
        "SimpleBootUpMaster=0",
        "SimpleBootUpSlave=1",
        "Granularity=8",
        "DynamicChannelsSupported=0",
        "GroupMessaging=0",
        f"NrOfRXPDO={rpdos}",
        f"NrOfTXPDO={tpdos}",
        "LSS_Supported=0",
        "",
        "[DummyUsage]",
        *(f"Dummy{code:04X}=1" for code in range(1, 8)),
        "",
    ]
    U8, U16, U32 = DataType.UNSIGNED8, DataType.UNSIGNED16, DataType.UNSIGNED32
    VS, DOM = DataType.VISIBLE_STRING, DataType.DOMAIN
    _var(out, "1000", "Device type", U32, "ro", f"0x{device_type:08X}")
    _var(out, "1001", "Error register", U8, "ro", "0", mappable=True)
    if error_history:
        _composite(out, 0x1003, "Pre-defined error field", ObjectType.ARRAY, error_history + 1)
        _var(out, _sub(0x1003, 0), "Number of errors", U8, "rw", "0")
        for n in range(1, error_history + 1):
            _var(out, _sub(0x1003, n), f"Standard error field {n}", U32, "ro", "0")
    _var(out, "1005", "COB-ID SYNC", U32, "rw", "0x00000080")
    _var(out, "1006", "Communication cycle period", U32, "rw", "0")
    _var(out, "1007", "Synchronous window length", U32, "rw", "0")
    _var(out, "1008", "Manufacturer device name", VS, "const", device_name)
    _var(out, "1009", "Manufacturer hardware version", VS, "const", hardware_version or None)
    _var(out, "100A", "Manufacturer software version", VS, "const", software_version or None)
    _var(out, "100C", "Guard time", U16, "rw", "0")
    _var(out, "100D", "Life time factor", U8, "rw", "0")
    for index, name, sub_name in (
        (0x1010, "Store parameters", "save"),
        (0x1011, "Restore default parameters", "restore"),
    ):
        _composite(out, index, name, ObjectType.ARRAY, 4)
        _var(out, _sub(index, 0), "Highest sub-index supported", U8, "ro", "3")
        for sub, what in ((1, "all"), (2, "communication"), (3, "application")):
            _var(
                out,
                _sub(index, sub),
                f"{sub_name.capitalize()} {what} parameters",
                U32,
                "rw",
                "0x00000001",
            )
    _var(out, "1012", "COB-ID time stamp", U32, "rw", "0x80000100")
    _var(out, "1014", "COB-ID EMCY", U32, "rw", "$NODEID+0x80")
    _var(out, "1015", "Inhibit time EMCY", U16, "rw", "0")
    _composite(out, 0x1016, "Consumer heartbeat time", ObjectType.ARRAY, heartbeat_consumers + 1)
    _var(out, _sub(0x1016, 0), "Highest sub-index supported", U8, "ro", str(heartbeat_consumers))
    for n in range(1, heartbeat_consumers + 1):
        _var(out, _sub(0x1016, n), f"Consumer heartbeat time {n}", U32, "rw", "0x00000000")
    _var(out, "1017", "Producer heartbeat time", U16, "rw", "0")
    _composite(out, 0x1018, "Identity object", ObjectType.RECORD, 5)
    _var(out, _sub(0x1018, 0), "Highest sub-index supported", U8, "ro", "4")
    for sub, name in enumerate(("Vendor-ID", "Product code", "Revision number", "Serial number")):
        _var(out, _sub(0x1018, sub + 1), name, U32, "ro", f"0x{identity[sub]:08X}")
    _var(out, "1019", "Synchronous counter overflow value", U8, "rw", "0")
    _var(out, "1021", "Store EDS", DOM, "ro", None)
    _var(out, "1022", "Store format", U16, "ro", "0")
    _composite(out, 0x1029, "Error behavior object", ObjectType.ARRAY, 2)
    _var(out, _sub(0x1029, 0), "Highest sub-index supported", U8, "ro", "1")
    _var(out, _sub(0x1029, 1), "Communication error", U8, "rw", "0")
    for n in range(sdo_servers):
        index = 0x1200 + n
        if n == 0:
            _composite(out, index, "SDO server parameter", ObjectType.RECORD, 3)
            _var(out, _sub(index, 0), "Highest sub-index supported", U8, "ro", "2")
            _var(out, _sub(index, 1), "COB-ID client to server", U32, "ro", "$NODEID+0x600")
            _var(out, _sub(index, 2), "COB-ID server to client", U32, "ro", "$NODEID+0x580")
            continue
        _composite(out, index, f"SDO server parameter {n + 1}", ObjectType.RECORD, 4)
        _var(out, _sub(index, 0), "Highest sub-index supported", U8, "ro", "3")
        _var(out, _sub(index, 1), "COB-ID client to server", U32, "rw", "0x80000000")
        _var(out, _sub(index, 2), "COB-ID server to client", U32, "rw", "0x80000000")
        _var(out, _sub(index, 3), "Node-ID of the SDO client", U8, "rw", "0")
    for kind, count, comm_base, map_base, id_base in (
        ("RPDO", rpdos, 0x1400, 0x1600, 0x200),
        ("TPDO", tpdos, 0x1800, 0x1A00, 0x180),
    ):
        tx = kind == "TPDO"
        for n in range(count):
            comm = comm_base + n
            cob = f"$NODEID+0x{id_base + 0x100 * n:X}" if n < 4 else "0x80000000"
            _composite(
                out,
                comm,
                f"{kind} communication parameter {n + 1}",
                ObjectType.RECORD,
                6 if tx else 5,
            )
            _var(out, _sub(comm, 0), "Highest sub-index supported", U8, "ro", "6" if tx else "5")
            _var(out, _sub(comm, 1), f"COB-ID used by {kind}", U32, "rw", cob)
            _var(out, _sub(comm, 2), "Transmission type", U8, "rw", "255")
            _var(out, _sub(comm, 3), "Inhibit time", U16, "rw", "0")
            _var(out, _sub(comm, 5), "Event timer", U16, "rw", "0")
            if tx:
                _var(out, _sub(comm, 6), "SYNC start value", U8, "rw", "0")
            mapping = map_base + n
            _composite(
                out,
                mapping,
                f"{kind} mapping parameter {n + 1}",
                ObjectType.RECORD,
                mapping_entries + 1,
            )
            _var(out, _sub(mapping, 0), "Number of mapped objects", U8, "rw", "0")
            for e in range(1, mapping_entries + 1):
                _var(out, _sub(mapping, e), f"Mapped object {e}", U32, "rw", "0x00000000")
    return "\n".join(out)


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
    text = _profile_text(
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
    od = loads(text, node_id, strict=True, path="<cobus minimal_od>")
    od.path = None
    return od


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
        comm = self._pdo(0x1800, 0x1A00, number, entries, transmission_type)
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
        comm = self._pdo(0x1400, 0x1600, number, entries, transmission_type)
        comm[5].default = event_timer_ms

    def _pdo(
        self,
        comm_base: int,
        map_base: int,
        number: int,
        entries: Iterable[tuple[int, int]],
        transmission_type: int,
    ) -> Record | Array:
        kind = "TPDO" if comm_base == 0x1800 else "RPDO"
        comm = self.od.get(comm_base + number - 1) if isinstance(number, int) else None
        mapping = self.od.get(map_base + number - 1) if isinstance(number, int) else None
        if not isinstance(comm, Record | Array) or not isinstance(mapping, Record | Array):
            raise DeviceConfigError(
                f"the dictionary has no {kind} {number}: ask minimal_od() for more PDOs"
            )
        values = []
        for index, sub in entries:
            var = self.od.get_variable(index, sub)
            if var is None:
                raise DeviceConfigError(
                    f"{kind} {number} maps 0x{index:04X}:{sub:02X}, which is not in the "
                    "dictionary yet: add the variable first"
                )
            if var.bit_length is None:
                raise DeviceConfigError(
                    f"{kind} {number} maps 0x{index:04X}:{sub:02X} ({var.data_type.name}), "
                    "which has no fixed bit length"
                )
            values.append(index << 16 | sub << 8 | var.bit_length)
        slots = len(mapping.subindices) - 1
        if len(values) > slots:
            raise DeviceConfigError(
                f"{kind} {number} maps {len(values)} objects but its mapping has {slots} "
                "entries: ask minimal_od(mapping_entries=...) for more"
            )
        for sub in range(1, slots + 1):
            mapping[sub].default = values[sub - 1] if sub <= len(values) else 0
        mapping[0].default = len(values)
        comm[2].default = transmission_type
        return comm

    def build(self) -> ObjectDictionary:
        """The dictionary; raises :class:`DeviceConfigError` listing what is inconsistent
        (PDO mappings of objects that are not mappable, too long, ...)."""
        problems = [str(f) for f in validate(self.od) if f.severity.value == "error"]
        if problems:
            raise DeviceConfigError("the dictionary is inconsistent:\n" + "\n".join(problems))
        return self.od
