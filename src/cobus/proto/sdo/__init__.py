"""SDO (CiA 301): client and server machines, abort codes, errors and the block CRC.

- :class:`SdoClient` reads and writes objects of a server: expedited, segmented and block
  transfers; completion events :class:`UploadDone`, :class:`DownloadDone`,
  :class:`TransferFailed`.
- :class:`SdoServer` serves an :class:`SdoServerBackend` (:class:`DictBackend` for simple uses);
  events :class:`ServerDownloaded`, :class:`ServerUploaded`, :class:`ServerAborted`.
- :class:`SdoAbortCode` and :func:`describe` give every abort code its CiA 301 text.
"""

from cobus.proto.sdo._wire import check_timeout
from cobus.proto.sdo.abort import BECKHOFF_ABORT_TEXTS, SdoAbortCode, as_code, describe
from cobus.proto.sdo.client import DownloadDone, SdoClient, TransferFailed, UploadDone
from cobus.proto.sdo.crc import crc16
from cobus.proto.sdo.errors import (
    SdoAbort,
    SdoAbortedError,
    SdoBusyError,
    SdoError,
    SdoParameterError,
    SdoProtocolError,
    SdoTimeoutError,
)
from cobus.proto.sdo.server import (
    DictBackend,
    SdoServer,
    SdoServerBackend,
    ServerAborted,
    ServerDownloaded,
    ServerUploaded,
)

__all__ = [
    "BECKHOFF_ABORT_TEXTS",
    "DictBackend",
    "DownloadDone",
    "SdoAbort",
    "SdoAbortCode",
    "SdoAbortedError",
    "SdoBusyError",
    "SdoClient",
    "SdoError",
    "SdoParameterError",
    "SdoProtocolError",
    "SdoServer",
    "SdoServerBackend",
    "SdoTimeoutError",
    "ServerAborted",
    "ServerDownloaded",
    "ServerUploaded",
    "TransferFailed",
    "UploadDone",
    "as_code",
    "check_timeout",
    "crc16",
    "describe",
]
