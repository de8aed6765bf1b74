"""Object dictionary: the CiA 301 data types and the CiA 306 EDS/DCF files.

- :class:`DataType`, :func:`encode`, :func:`decode` — exact little-endian codecs of every
  basic data type (hot paths: one dict lookup and a precompiled ``struct``).
- :class:`ObjectDictionary` of :class:`Variable`, :class:`Record` and :class:`Array` objects,
  addressed by number (``od[0x1018][1]``) or by name (``od["Identity object"]["Vendor-ID"]``).
- :func:`load` / :func:`loads` read EDS and DCF files, tolerant by default: what deviates from
  CiA 306 is listed in ``od.findings``; ``strict=True`` raises :class:`EdsError` instead.
- ``od.to_eds()`` / ``od.to_dcf(node_id)`` / ``od.save(path)`` write them back.
- :func:`resolve` finds an object as people name it (name with case and separators ignored,
  ``"Record.Sub"``, ``0x1018``, ``(0x1018, 1)``, ``"0x1018:01"``), "did you mean" when nothing
  matches: the one name resolver every part of cobus uses.
- :class:`CommandObjects` / :func:`process_data_of` — which objects are commands (controlwords,
  modes, set-points, outputs) or process data rather than parameters.
"""

from cobus.od._checks import mapping_entries, validate
from cobus.od._eds import load, loads
from cobus.od._errors import (
    DataLengthError,
    DataTypeError,
    EdsError,
    Finding,
    Severity,
    ValueRangeError,
)
from cobus.od._lookup import (
    NameLookupError,
    did_you_mean,
    match_key,
    match_name,
    normalize_name,
    parse_address,
    resolve,
    resolve_object,
    suggestions,
)
from cobus.od._model import (
    Access,
    Array,
    Commissioning,
    DeviceInfo,
    FileInfo,
    NodeRelative,
    Object,
    ObjectDictionary,
    ObjectDictionaryError,
    ObjectType,
    Record,
    Variable,
)
from cobus.od._roles import CommandObjects, process_data_of
from cobus.od._types import (
    DataType,
    TimeDifference,
    TimeOfDay,
    Value,
    codec,
    data_type_named,
    decode,
    encode,
    struct_unpacker,
)

__all__ = [
    "Access",
    "Array",
    "CommandObjects",
    "Commissioning",
    "DataLengthError",
    "DataType",
    "DataTypeError",
    "DeviceInfo",
    "EdsError",
    "FileInfo",
    "Finding",
    "NameLookupError",
    "NodeRelative",
    "Object",
    "ObjectDictionary",
    "ObjectDictionaryError",
    "ObjectType",
    "Record",
    "Severity",
    "TimeDifference",
    "TimeOfDay",
    "Value",
    "ValueRangeError",
    "Variable",
    "codec",
    "data_type_named",
    "decode",
    "did_you_mean",
    "encode",
    "load",
    "loads",
    "mapping_entries",
    "match_key",
    "match_name",
    "normalize_name",
    "parse_address",
    "process_data_of",
    "resolve",
    "resolve_object",
    "struct_unpacker",
    "suggestions",
    "validate",
]
