"""Object dictionary: the CiA 301 data types and the CiA 306 EDS/DCF files.

- :class:`DataType`, :func:`encode`, :func:`decode` — exact little-endian codecs of every
  basic data type (hot paths: one dict lookup and a precompiled ``struct``).
"""

from cobus.od._errors import DataLengthError, DataTypeError, ValueRangeError
from cobus.od._types import DataType, TimeDifference, TimeOfDay, Value, decode, encode

__all__ = [
    "DataLengthError",
    "DataType",
    "DataTypeError",
    "TimeDifference",
    "TimeOfDay",
    "Value",
    "ValueRangeError",
    "decode",
    "encode",
]
