"""The object dictionary model: variables, records, arrays and the dictionary itself."""

from __future__ import annotations

import enum
import operator
import os
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeAlias

from cobus._enum import NamedIntEnum
from cobus.errors import CobusError
from cobus.od._errors import DataTypeError, Finding, Severity, ValueRangeError
from cobus.od._types import DECODERS, ENCODERS, INT_INFO, DataType, same_value
from cobus.od._values import TextError, format_value, parse_value

__all__ = [
    "Access",
    "Array",
    "Commissioning",
    "DeviceInfo",
    "FileInfo",
    "NodeRelative",
    "Object",
    "ObjectDictionary",
    "ObjectDictionaryError",
    "ObjectType",
    "Record",
    "Variable",
]


class ObjectDictionaryError(CobusError, KeyError):
    """A lookup or change the dictionary cannot do (unknown or ambiguous key, duplicate)."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""


class Access(enum.Enum):
    """CiA 301/306 access types; RWR/RWW are read-write, preferably mapped to TPDO/RPDO."""

    RO = "ro"
    WO = "wo"
    RW = "rw"
    RWR = "rwr"
    RWW = "rww"
    CONST = "const"

    @property
    def readable(self) -> bool:
        return self is not _WO

    @property
    def writable(self) -> bool:
        return self is not _RO and self is not _CONST

    def __str__(self) -> str:
        return self.value


# Members as module names for the checks asked on every SDO request: in Python 3.11 an Enum
# class's attribute costs ~0.5 us (its metaclass defines __getattr__), a global a tenth of it.
_RO, _WO, _CONST = Access.RO, Access.WO, Access.CONST


class ObjectType(NamedIntEnum):
    """CiA 301 object codes."""

    NULL = 0
    DOMAIN = 2
    DEFTYPE = 5
    DEFSTRUCT = 6
    VAR = 7
    ARRAY = 8
    RECORD = 9


# Bits of Variable._rel: which values are $NODEID expressions.
REL_DEFAULT = 1
REL_PARAM = 2
REL_LOW = 4
REL_HIGH = 8


@dataclass(frozen=True)
class NodeRelative:
    """``$NODEID+offset``: an integer value that follows the node-ID, as EDS files write the
    COB-IDs of a device (CiA 306). Give it to a variable built in code as its default (or
    parameter value or limit): ``Variable(..., default=NodeRelative(0x180))``.

    The variable's value is then ``node_id + offset`` for the node-ID of the dictionary it is
    in: resolved when it is added to one, and again at every change of ``od.node_id``; None
    while it is in no dictionary or the dictionary has no node-ID. ``relative`` is True, and
    ``to_eds()`` writes ``$NODEID+0x180``, which loading reads back as the same variable.
    """

    offset: int

    def __post_init__(self) -> None:
        offset = self.offset
        if not isinstance(offset, int) or isinstance(offset, bool) or offset < 0:
            raise ValueRangeError(
                f"NodeRelative offset {offset!r} must be an int >= 0 (the value is $NODEID+offset)"
            )

    def __str__(self) -> str:
        return format_value(DataType.UNSIGNED32, None, self.offset)


def _set_access(var: Variable, access: Access | str) -> None:
    try:  # "ro" and the like become the member: a device tests access by identity
        var._access = Access(access)
    except ValueError:
        known = ", ".join(a.value for a in Access)
        raise ObjectDictionaryError(
            f"0x{var.index:04X}:{var.subindex:02X} {var.name!r}: access {access!r} is none of "
            f"{known}"
        ) from None


class Variable:
    """One value of the dictionary: a VAR object, or a sub-object of a record or array.

    ``default`` and ``parameter_value`` are decoded Python values; a ``$NODEID`` expression is
    resolved with the dictionary's node id (None while the node id is unknown; ``relative``
    tells it is one). ``value`` is the configured ParameterValue if there is one, else the
    default. The ``*_raw`` texts are what the file said, written back unchanged unless the
    value is changed through the properties.
    """

    __slots__ = (
        "_access",
        "_default",
        "_default_raw",
        "_high",
        "_high_raw",
        "_home",
        "_low",
        "_low_raw",
        "_param",
        "_param_raw",
        "_rel",
        "data_type",
        "declared_type",
        "denotation",
        "description",
        "extra",
        "factor",
        "index",
        "line",
        "name",
        "obj_flags",
        "object_type",
        "parent",
        "pdo_mappable",
        "subindex",
        "unit",
    )

    _default: Any
    _default_raw: str | None
    _high: Any
    _high_raw: str | None
    _home: ObjectDictionary | None  # the dictionary a VAR object is in
    _low: Any
    _low_raw: str | None
    _param: Any
    _param_raw: str | None
    _rel: int
    _access: Access
    index: int
    subindex: int
    name: str
    data_type: DataType
    pdo_mappable: bool
    object_type: ObjectType
    #: The DataType number the file gave when it is not a basic type (then ``data_type`` is
    #: DOMAIN: the value is handled as opaque bytes); None normally.
    declared_type: int | None
    unit: str | None
    factor: float | None
    denotation: str | None
    description: str | None
    obj_flags: int | None
    #: Keys of the file this model does not interpret, kept to be written back.
    extra: dict[str, str] | None
    #: Line of the section in the file it was read from (None if built in code).
    line: int | None
    #: The record or array this is a sub-object of (None for a VAR object).
    parent: Record | Array | None

    def __init__(
        self,
        index: int,
        subindex: int,
        name: str,
        data_type: DataType,
        access: Access = Access.RW,
        pdo_mappable: bool = False,
        *,
        default: Any = None,
        low_limit: Any = None,
        high_limit: Any = None,
        parameter_value: Any = None,
        unit: str | None = None,
        factor: float | None = None,
        object_type: ObjectType = ObjectType.VAR,
    ) -> None:
        self.index = index
        self.subindex = subindex
        self.name = name
        self.data_type = data_type
        self.access = access
        self.pdo_mappable = pdo_mappable
        self.object_type = object_type
        self.declared_type = None
        self._low = self._low_raw = self._high = self._high_raw = None
        self._default = self._default_raw = self._param = self._param_raw = None
        self._rel = 0
        self._home = None
        self.unit = unit
        self.factor = factor
        self.denotation = self.description = None
        self.obj_flags = None
        self.extra = None
        self.line = None
        self.parent = None
        if low_limit is not None:
            self.low_limit = low_limit
        if high_limit is not None:
            self.high_limit = high_limit
        if default is not None:
            self.default = default
        if parameter_value is not None:
            self.parameter_value = parameter_value

    # --- values -----------------------------------------------------------------------------

    @property
    def default(self) -> Any:
        """The DefaultValue. Set it to a value of the type within the limits, to None, or to
        a :class:`NodeRelative` (so are ``parameter_value`` and the limits)."""
        return self._default

    @default.setter
    def default(self, value: Any) -> None:
        if isinstance(value, NodeRelative):
            self._default_raw, self._default = self._relative(value, REL_DEFAULT)
            return
        if value is not None:
            self.check(value)
        self._default = value
        self._default_raw = None
        self._rel &= ~REL_DEFAULT

    @property
    def parameter_value(self) -> Any:
        """The configured value (DCF ParameterValue), or None."""
        return self._param

    @parameter_value.setter
    def parameter_value(self, value: Any) -> None:
        if isinstance(value, NodeRelative):
            self._param_raw, self._param = self._relative(value, REL_PARAM)
            return
        if value is not None:
            self.check(value)
        self._param = value
        self._param_raw = None
        self._rel &= ~REL_PARAM

    @property
    def value(self) -> Any:
        """ParameterValue if given, else the default."""
        return self._default if self._param is None else self._param

    @value.setter
    def value(self, value: Any) -> None:
        self.parameter_value = value

    @property
    def low_limit(self) -> Any:
        return self._low

    @low_limit.setter
    def low_limit(self, value: Any) -> None:
        if isinstance(value, NodeRelative):
            self._low_raw, self._low = self._relative(value, REL_LOW)
            return
        if value is not None:
            ENCODERS[self.data_type](value)
        self._low = value
        self._low_raw = None
        self._rel &= ~REL_LOW

    @property
    def high_limit(self) -> Any:
        return self._high

    @high_limit.setter
    def high_limit(self, value: Any) -> None:
        if isinstance(value, NodeRelative):
            self._high_raw, self._high = self._relative(value, REL_HIGH)
            return
        if value is not None:
            ENCODERS[self.data_type](value)
        self._high = value
        self._high_raw = None
        self._rel &= ~REL_HIGH

    @property
    def default_raw(self) -> str | None:
        """DefaultValue as the file wrote it (e.g. ``$NODEID+0x180``); None if not from a file."""
        return self._default_raw

    @property
    def parameter_value_raw(self) -> str | None:
        return self._param_raw

    @property
    def relative(self) -> bool:
        """True when DefaultValue is a ``$NODEID`` expression."""
        return bool(self._rel & REL_DEFAULT)

    @property
    def bit_length(self) -> int | None:
        return self.data_type.bit_length

    if TYPE_CHECKING:

        @property
        def access(self) -> Access:
            """Who may read and write the value."""

        @access.setter
        def access(self, value: Access | str) -> None: ...

    else:  # read by a device for every SDO request: a getter in C, no Python frame
        access = property(
            operator.attrgetter("_access"),
            _set_access,
            doc="""Who may read and write the value: an :class:`Access`. Set to a member or
            its value (``"ro"``), which becomes the member; anything else raises
            :class:`ObjectDictionaryError`.""",
        )

    @property
    def readable(self) -> bool:
        return self.access.readable

    @property
    def writable(self) -> bool:
        return self.access.writable

    @property
    def qualname(self) -> str:
        """``0x1018sub1`` style address, as EDS sections name sub-objects."""
        if self.parent is None:
            return f"0x{self.index:04X}"
        return f"0x{self.index:04X}sub{self.subindex:X}"

    # --- codec with limits ------------------------------------------------------------------

    def check(self, value: Any) -> None:
        """Raise :class:`ValueRangeError` unless ``value`` fits the type and the limits."""
        ENCODERS[self.data_type](value)
        if self._low is not None or self._high is not None:
            self._check_limits(value)

    def _check_limits(self, value: Any) -> None:
        low, high = self._low, self._high
        try:
            if low is not None and value < low:
                raise ValueRangeError(
                    f"{value!r} is below the LowLimit {low!r} of {self.name!r} ({self.qualname})"
                )
            if high is not None and value > high:
                raise ValueRangeError(
                    f"{value!r} is above the HighLimit {high!r} of {self.name!r} ({self.qualname})"
                )
        except TypeError:
            raise ValueRangeError(
                f"{value!r} cannot be compared with the limits of {self.name!r}"
            ) from None

    def encode(self, value: Any) -> bytes:
        """Encode a value of this variable; the type's range and the limits are checked."""
        data = ENCODERS[self.data_type](value)
        if self._low is not None or self._high is not None:
            self._check_limits(value)
        return data

    def decode(self, data: bytes | bytearray | memoryview) -> Any:
        """Decode bytes of this variable; the decoded value must lie within the limits."""
        value = DECODERS[self.data_type](data)
        if self._low is not None or self._high is not None:
            self._check_limits(value)
        return value

    # --- node id ----------------------------------------------------------------------------

    def _relative(self, rel: NodeRelative, bit: int) -> tuple[str, int | None]:
        """The text and the value now of ``rel`` as one of this variable's values."""
        info = INT_INFO.get(self.data_type)
        if info is None:
            raise ValueRangeError(
                f"{self.name!r} ({self.qualname}) is {self.data_type.name}: only integer values "
                "can follow the node-ID ($NODEID+offset)"
            )
        low, high = info[0], info[1]
        if not low <= rel.offset + 1 or rel.offset + 127 > high:
            raise ValueRangeError(
                f"{rel} does not fit {self.data_type.name} ({low}..{high}) for every node-ID "
                f"1..127 of {self.name!r} ({self.qualname})"
            )
        self._rel |= bit
        home = self._home if self.parent is None else self.parent._home
        node_id = home._node_id if home is not None else None
        return str(rel), None if node_id is None else node_id + rel.offset

    def _resolve(self, node_id: int | None) -> None:
        """Re-evaluate the ``$NODEID`` expressions for another node id."""
        rel = self._rel
        dt = self.data_type
        for bit, raw_slot, slot in (
            (REL_DEFAULT, "_default_raw", "_default"),
            (REL_PARAM, "_param_raw", "_param"),
            (REL_LOW, "_low_raw", "_low"),
            (REL_HIGH, "_high_raw", "_high"),
        ):
            if rel & bit:
                try:
                    value = parse_value(dt, getattr(self, raw_slot), node_id)[0]
                except TextError:
                    value = None
                setattr(self, slot, value)

    def __repr__(self) -> str:
        return f"<Variable {self.name!r} {self.qualname} {self.data_type.name} {self.access}>"


def dummy_variable(code: int, data_type: DataType) -> Variable:
    """The DEFTYPE object a PDO dummy mapping of ``data_type`` refers to ([DummyUsage])."""
    var = Variable(code, 0, f"Dummy{code:04X}", data_type, Access.CONST, True)
    var.object_type = ObjectType.DEFTYPE
    return var


def _diff_var(a: Variable, b: Variable, where: str) -> list[str]:
    out: list[str] = []
    for attr in (
        "index",
        "subindex",
        "name",
        "object_type",
        "data_type",
        "declared_type",
        "access",
        "pdo_mappable",
        "unit",
        "factor",
        "denotation",
        "description",
        "obj_flags",
        "_rel",
    ):
        va, vb = getattr(a, attr), getattr(b, attr)
        if va != vb:
            out.append(f"{where}: {attr.lstrip('_')} {va!r} != {vb!r}")
    for attr, raw in (
        ("_default", "_default_raw"),
        ("_param", "_param_raw"),
        ("_low", "_low_raw"),
        ("_high", "_high_raw"),
    ):
        va, vb = getattr(a, attr), getattr(b, attr)
        if not same_value(va, vb) or type(va) is not type(vb):
            out.append(f"{where}: {attr.lstrip('_')} {va!r} != {vb!r}")
        elif va is None:
            ra, rb = getattr(a, raw), getattr(b, raw)
            # An unreadable or unresolved text is the value; an empty text equals no text.
            if (ra or "").strip() != (rb or "").strip():
                out.append(f"{where}: {raw.lstrip('_')} {ra!r} != {rb!r}")
    if (a.extra or {}) != (b.extra or {}):
        out.append(f"{where}: extra keys {a.extra!r} != {b.extra!r}")
    return out


class _Composite:
    """What records and arrays share: sub-objects by sub-index and by name."""

    __slots__ = (
        "_dup_names",
        "_home",
        "_names",
        "compact",
        "denotation",
        "description",
        "extra",
        "index",
        "line",
        "name",
        "obj_flags",
        "object_type",
        "subindices",
    )

    index: int
    name: str
    object_type: ObjectType
    #: Sub-objects by sub-index (insertion order; iterate the object for sub-index order).
    subindices: dict[int, Variable]
    #: CompactSubObj count when the file described the sub-objects compactly, else None.
    compact: int | None
    denotation: str | None
    description: str | None
    obj_flags: int | None
    extra: dict[str, str] | None
    line: int | None

    def __init__(self, index: int, name: str, object_type: ObjectType) -> None:
        self.index = index
        self.name = name
        self.object_type = object_type
        self.subindices = {}
        self._names: dict[str, Variable] = {}
        self._dup_names: dict[str, list[int]] | None = None
        self._home: ObjectDictionary | None = None  # the dictionary it is in
        self.compact = None
        self.denotation = self.description = None
        self.obj_flags = None
        self.extra = None
        self.line = None

    def add(self, var: Variable) -> None:
        """Add a sub-object; its sub-index must be new."""
        if var.index != self.index:
            raise ObjectDictionaryError(
                f"sub-object {var.name!r} has index 0x{var.index:04X}, not 0x{self.index:04X}"
            )
        if var.subindex in self.subindices:
            raise ObjectDictionaryError(f"0x{self.index:04X} already has sub-index {var.subindex}")
        self.subindices[var.subindex] = var
        var.parent = self  # type: ignore[assignment]
        if var._rel and self._home is not None:
            var._resolve(self._home._node_id)
        name = var.name
        if name in self._names:
            if self._dup_names is None:
                self._dup_names = {}
            self._dup_names.setdefault(name, [self._names[name].subindex]).append(var.subindex)
        else:
            self._names[name] = var

    def __getitem__(self, key: int | str) -> Variable:
        var = self.subindices.get(key) if isinstance(key, int) else self._names.get(key)
        if var is None:
            raise ObjectDictionaryError(
                f"0x{self.index:04X} ({self.name!r}) has no sub-object {key!r}"
            )
        if isinstance(key, str) and self._dup_names and key in self._dup_names:
            subs = ", ".join(str(s) for s in self._dup_names[key])
            raise ObjectDictionaryError(
                f"0x{self.index:04X}: the name {key!r} is used by sub-indices {subs}; "
                "use the sub-index"
            )
        return var

    def get(self, subindex: int) -> Variable | None:
        return self.subindices.get(subindex)

    def __contains__(self, key: object) -> bool:
        return key in self.subindices or key in self._names

    def __iter__(self) -> Iterator[Variable]:
        subs = self.subindices
        return iter([subs[k] for k in sorted(subs)])

    def __len__(self) -> int:
        return len(self.subindices)

    def __repr__(self) -> str:
        kind = type(self).__name__
        return f"<{kind} {self.name!r} 0x{self.index:04X} with {len(self.subindices)} sub-objects>"


class Record(_Composite):
    """A RECORD (or DEFSTRUCT): sub-objects of possibly different types."""

    __slots__ = ()

    def __init__(self, index: int, name: str, object_type: ObjectType = ObjectType.RECORD) -> None:
        super().__init__(index, name, object_type)


class Array(_Composite):
    """An ARRAY: sub-index 0 counts the entries, sub-indices 1..n share one type."""

    __slots__ = ()

    def __init__(self, index: int, name: str, object_type: ObjectType = ObjectType.ARRAY) -> None:
        super().__init__(index, name, object_type)


Object: TypeAlias = Variable | Record | Array


def _layout(
    comments: dict[str, list[tuple[str | None, str]]],
) -> dict[str, dict[str | None, list[str]]]:
    """Where the comments go when written: by section, by the key they follow (in lower case),
    in order. The order of comments that follow different keys does not matter."""
    out: dict[str, dict[str | None, list[str]]] = {}
    for section, lines in comments.items():
        if lines:
            by_key = out.setdefault(section, {})
            for after, text in lines:
                by_key.setdefault(None if after is None else after.lower(), []).append(text)
    return out


def _object_section(key: str, prefix: str) -> bool:
    """Whether the section ``key`` (upper case) describes the object ``prefix`` (4 digits)."""
    if not key.startswith(prefix):
        return False
    rest = key[4:]
    return not rest or rest.startswith("SUB") or rest in ("NAME", "VALUE", "DENOTATION")


def _diff_obj(a: Object, b: Object) -> list[str]:
    where = f"0x{a.index:04X}"
    if type(a) is not type(b):
        return [f"{where}: {type(a).__name__} != {type(b).__name__}"]
    if isinstance(a, Variable):
        assert isinstance(b, Variable)
        return _diff_var(a, b, where)
    assert isinstance(b, _Composite)
    out = []
    for attr in ("name", "object_type", "denotation", "description", "obj_flags"):
        va, vb = getattr(a, attr), getattr(b, attr)
        if va != vb:
            out.append(f"{where}: {attr} {va!r} != {vb!r}")
    if (a.extra or {}) != (b.extra or {}):
        out.append(f"{where}: extra keys {a.extra!r} != {b.extra!r}")
    subs_a, subs_b = set(a.subindices), set(b.subindices)
    if subs_a != subs_b:
        out.append(f"{where}: sub-indices {sorted(subs_a ^ subs_b)} are only in one of them")
    for sub in sorted(subs_a & subs_b):
        out.extend(_diff_var(a.subindices[sub], b.subindices[sub], f"{where}sub{sub:X}"))
    return out


@dataclass
class FileInfo:
    """[FileInfo]: about the file itself. Texts as written (dates mm-dd-yyyy, times hh:mmAM)."""

    file_name: str | None = None
    file_version: str | None = None
    file_revision: str | None = None
    eds_version: str | None = None
    description: str | None = None
    creation_time: str | None = None
    creation_date: str | None = None
    created_by: str | None = None
    modification_time: str | None = None
    modification_date: str | None = None
    modified_by: str | None = None
    last_eds: str | None = None
    extra: dict[str, str] = field(default_factory=dict)


#: The bit rates (kbit/s) [DeviceInfo] declares with BaudRate_<n>.
STANDARD_BAUD_RATES = (10, 20, 50, 125, 250, 500, 800, 1000)


@dataclass
class DeviceInfo:
    """[DeviceInfo]: identity and communication capabilities of the device."""

    vendor_name: str | None = None
    vendor_number: int | None = None
    product_name: str | None = None
    product_number: int | None = None
    revision_number: int | None = None
    order_code: str | None = None
    #: Supported bit rates in kbit/s.
    baud_rates: set[int] = field(default_factory=set)
    simple_boot_up_master: bool | None = None
    simple_boot_up_slave: bool | None = None
    granularity: int | None = None
    dynamic_channels_supported: int | None = None
    group_messaging: bool | None = None
    nr_of_rx_pdo: int | None = None
    nr_of_tx_pdo: int | None = None
    lss_supported: bool | None = None
    compact_pdo: int | None = None
    extra: dict[str, str] = field(default_factory=dict)


@dataclass
class Commissioning:
    """[DeviceComissioning] of a DCF: how this node is configured on its network."""

    node_id: int | None = None
    node_name: str | None = None
    #: kbit/s, as CiA 306 writes it.
    baudrate: int | None = None
    net_number: int | None = None
    network_name: str | None = None
    canopen_manager: bool | None = None
    lss_serial_number: int | None = None
    extra: dict[str, str] = field(default_factory=dict)
    #: The section name as spelled in the file (CiA 306 itself spells "DeviceComissioning").
    section: str = "DeviceComissioning"

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Commissioning):
            return NotImplemented
        return all(
            getattr(self, f) == getattr(other, f)
            for f in (
                "node_id",
                "node_name",
                "baudrate",
                "net_number",
                "network_name",
                "canopen_manager",
                "lss_serial_number",
                "extra",
            )
        )

    __hash__ = None  # type: ignore[assignment]


class ObjectDictionary:
    """Objects by index (and by name), with what the EDS/DCF said about the device.

    ``od[index]`` / ``od[name]`` give a :class:`Variable`, :class:`Record` or :class:`Array`;
    ``od[index][sub]`` / ``od[index][name]`` a sub-object. Iteration yields the objects in
    index order. Two dictionaries compare equal when everything they describe is equal;
    :meth:`diff` lists the differences.
    """

    def __init__(self) -> None:
        self._objects: dict[int, Object] = {}
        self._sorted: list[int] | None = []
        self._names: dict[str, Object] = {}
        self._dup_names: dict[str, list[int]] = {}
        self._node_id: int | None = None
        self._name_tables: Any = None  # cobus.od.resolve's, built when first needed
        self._version = 0  # objects added or removed (the name tables follow it)
        #: Bit rate in bit/s from [DeviceComissioning] (None if not given or 0).
        self.bitrate: int | None = None
        self.file_info = FileInfo()
        self.device_info = DeviceInfo()
        self.commissioning: Commissioning | None = None
        #: [Comments] lines.
        self.comments: list[str] = []
        #: [Comments] keys other than Lines and LineN, as written (kept to be written back).
        self.comments_extra: dict[str, str] = {}
        #: [DummyUsage]: data type number -> may be mapped as a PDO dummy entry.
        self.dummy_usage: dict[int, bool] = {}
        #: [DummyUsage] keys that are not DummyNNNN (or have no number), as written.
        self.dummy_usage_extra: dict[str, str] = {}
        #: Whole-line ``;`` and ``#`` comments of the file, kept to be written back: by the
        #: section they are in (its name in upper case as it is written: ``"1018SUB1"``,
        #: ``"DEVICEINFO"``; ``""`` for the lines before the first section), in file order,
        #: each as (the key it follows, None when it comes before any key; the line).
        self.file_comments: dict[str, list[tuple[str | None, str]]] = {}
        #: Sections the model does not interpret, in file order: (name, [(key, value)]).
        self.extra_sections: list[tuple[str, list[tuple[str, str]]]] = []
        #: What loading (and :meth:`validate`) found, in line order.
        self.findings: list[Finding] = []
        #: The file this was loaded from, if any.
        self.path: str | None = None
        # Dummy-mapping objects created from [DummyUsage] (not written as sections).
        self._dummies: set[int] = set()

    # --- mapping protocol -------------------------------------------------------------------

    def __getitem__(self, key: int | str) -> Object:
        if isinstance(key, int):
            obj = self._objects.get(key)
            if obj is None:
                raise ObjectDictionaryError(f"no object 0x{key:04X} in the dictionary")
            return obj
        obj = self._names.get(key)
        if obj is None:
            raise ObjectDictionaryError(f"no object named {key!r} in the dictionary")
        if key in self._dup_names:
            where = ", ".join(f"0x{i:04X}" for i in self._dup_names[key])
            raise ObjectDictionaryError(f"the name {key!r} is used by {where}; use the index")
        return obj

    def get(self, key: int | str) -> Object | None:
        try:
            return self[key]
        except ObjectDictionaryError:
            return None

    def get_variable(self, index: int, subindex: int = 0) -> Variable | None:
        """The variable at index/sub-index, or None (a plain VAR object is sub-index 0)."""
        obj = self._objects.get(index)
        if obj is None:
            return None
        if isinstance(obj, Variable):
            return obj if subindex == 0 else None
        return obj.subindices.get(subindex)

    def __contains__(self, key: object) -> bool:
        return key in self._objects or key in self._names

    def __iter__(self) -> Iterator[Object]:
        objs = self._objects
        if self._sorted is None:
            self._sorted = sorted(objs)
        return iter([objs[i] for i in self._sorted])

    def __len__(self) -> int:
        return len(self._objects)

    def variables(self) -> Iterator[Variable]:
        """Every variable: VAR objects and all sub-objects, in index/sub-index order."""
        for obj in self:
            if isinstance(obj, Variable):
                yield obj
            else:
                yield from obj

    def add(self, obj: Object) -> None:
        """Add an object; its index must be new. Its ``$NODEID`` values (read from a file, or
        :class:`NodeRelative` ones) resolve with this dictionary's node-ID."""
        self._add(obj)
        node_id = self._node_id
        if isinstance(obj, Variable):
            if obj._rel:
                obj._resolve(node_id)
            return
        for var in obj.subindices.values():
            if var._rel:
                var._resolve(node_id)

    def _add(self, obj: Object) -> None:
        """Add without resolving (the loader resolves as it reads)."""
        index = obj.index
        if index in self._objects:
            raise ObjectDictionaryError(f"the dictionary already has an object 0x{index:04X}")
        self._objects[index] = obj
        self._version += 1
        self._sorted = None
        obj._home = self
        name = obj.name
        if name in self._names:
            self._dup_names.setdefault(name, [self._names[name].index]).append(index)
        else:
            self._names[name] = obj

    def remove(self, index: int) -> Object:
        obj = self._objects.pop(index)
        self._version += 1
        obj._home = None
        self._sorted = None
        self._dummies.discard(index)
        if self.file_comments:  # the comments of its sections go with it
            prefix = f"{index:04X}"
            for key in [k for k in self.file_comments if _object_section(k, prefix)]:
                del self.file_comments[key]
        dups = self._dup_names.get(obj.name)
        if dups is not None:
            dups.remove(index)
            self._names[obj.name] = self._objects[dups[0]]
            if len(dups) == 1:
                del self._dup_names[obj.name]
        else:
            self._names.pop(obj.name, None)
        return obj

    def set_dummy_usage(self, code: int, enabled: bool = True) -> None:
        """[DummyUsage] ``DummyNNNN``: whether PDOs may map a dummy of the basic data type
        ``code`` (e.g. 0x0005 for UNSIGNED8). Enabled, the dictionary gets the DEFTYPE object
        ``code`` such mappings refer to (written as ``DummyNNNN=1``, not as an object section);
        disabled, that object goes again."""
        try:
            data_type = DataType(code)
        except ValueError:
            raise DataTypeError(
                f"dummy usage of 0x{code:04X}: only the basic data types 0x0001..0x001B can be "
                "mapped as PDO dummies"
            ) from None
        self.dummy_usage[code] = bool(enabled)
        if enabled:
            if code not in self._objects:
                self._add(dummy_variable(code, data_type))
                self._dummies.add(code)
        elif code in self._dummies:
            self.remove(code)

    # --- node id ----------------------------------------------------------------------------

    @property
    def node_id(self) -> int | None:
        """The node id ``$NODEID`` expressions resolve with (None: unresolved)."""
        return self._node_id

    @node_id.setter
    def node_id(self, node_id: int | None) -> None:
        if node_id is not None and not 1 <= node_id <= 127:
            raise ValueRangeError(f"node id {node_id} is outside 1..127")
        self._node_id = node_id
        for var in self.variables():
            if var._rel:
                var._resolve(node_id)

    # --- findings ---------------------------------------------------------------------------

    @property
    def errors(self) -> list[Finding]:
        return [f for f in self.findings if f.severity is Severity.ERROR]

    @property
    def warnings(self) -> list[Finding]:
        return [f for f in self.findings if f.severity is Severity.WARNING]

    # --- comparison -------------------------------------------------------------------------

    def diff(self, other: ObjectDictionary) -> list[str]:
        """Everything meaningful that differs from ``other``, one line each (empty: equal)."""
        out: list[str] = []
        for attr in (
            "node_id",
            "bitrate",
            "file_info",
            "device_info",
            "commissioning",
            "comments",
            "comments_extra",
            "dummy_usage",
            "dummy_usage_extra",
            "extra_sections",
        ):
            va, vb = getattr(self, attr), getattr(other, attr)
            if va != vb:
                out.append(f"{attr}: {va!r} != {vb!r}")
        mine_c, theirs_c = _layout(self.file_comments), _layout(other.file_comments)
        for section in sorted(mine_c.keys() | theirs_c.keys()):
            a, b = mine_c.get(section, {}), theirs_c.get(section, {})
            if a != b:
                out.append(f"comments of [{section}]: {a!r} != {b!r}")
        mine, theirs = set(self._objects), set(other._objects)
        for index in sorted(mine - theirs):
            out.append(f"0x{index:04X}: only in the first dictionary")
        for index in sorted(theirs - mine):
            out.append(f"0x{index:04X}: only in the second dictionary")
        for index in sorted(mine & theirs):
            out.extend(_diff_obj(self._objects[index], other._objects[index]))
        return out

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, ObjectDictionary):
            return NotImplemented
        return not self.diff(other)

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        name = self.device_info.product_name or self.path or "unnamed"
        return f"<ObjectDictionary {name!r} with {len(self._objects)} objects>"

    # --- writing (implemented in _write, bound here for a method-style API) -------------------

    def to_eds(
        self,
        *,
        file_info: FileInfo | None = None,
        device_info: DeviceInfo | None = None,
        dummy_usage: Mapping[int, bool] | None = None,
    ) -> str:
        """The dictionary as EDS text (CiA 306).

        ``file_info``, ``device_info`` and ``dummy_usage`` are written in place of the
        dictionary's own [FileInfo], [DeviceInfo] and [DummyUsage] (e.g. an export that fills
        in what a dictionary built in code leaves open); the dictionary is not changed.
        """
        from cobus.od._write import write

        return write(
            self,
            dcf=False,
            file_info=file_info,
            device_info=device_info,
            dummy_usage=dummy_usage,
        )

    def to_dcf(
        self,
        node_id: int | None = None,
        bitrate: int | None = None,
        *,
        file_info: FileInfo | None = None,
        device_info: DeviceInfo | None = None,
        dummy_usage: Mapping[int, bool] | None = None,
    ) -> str:
        """The dictionary as DCF text: [DeviceComissioning] with ``node_id`` (default: the
        dictionary's) and ``bitrate`` in bit/s (default: the dictionary's). The other
        arguments are those of :meth:`to_eds`."""
        from cobus.od._write import write

        return write(
            self,
            dcf=True,
            node_id=node_id,
            bitrate=bitrate,
            file_info=file_info,
            device_info=device_info,
            dummy_usage=dummy_usage,
        )

    def save(self, path: str | os.PathLike[str], node_id: int | None = None) -> None:
        """Write to ``path``: DCF if it ends in ``.dcf``, else EDS (CRLF line ends, CiA 306)."""
        target = Path(path)
        text = self.to_dcf(node_id) if target.suffix.lower() == ".dcf" else self.to_eds()
        with target.open("w", encoding="utf-8", newline="\r\n") as fh:
            fh.write(text)
