"""Looking at a bus: :class:`~cobus.trace.decoder.Decoder` turns frames into CANopen records
(NMT, heartbeat, guarding, SYNC, TIME, EMCY, LSS, whole SDO transfers, PDOs by name)."""

from cobus._moved import renamed_names
from cobus.trace.decoder import (
    Bootup,
    Decoder,
    EmergencyRecord,
    GuardRequest,
    GuardResponse,
    Heartbeat,
    LssFrame,
    LssSession,
    NmtCommandRecord,
    NodeStats,
    PdoRecord,
    SdoBlockFrame,
    SdoTransfer,
    SyncRecord,
    TimeRecord,
    TraceRecord,
    Unknown,
    frame_kind,
)

__all__ = [
    "Bootup",
    "Decoder",
    "EmergencyRecord",
    "GuardRequest",
    "GuardResponse",
    "Heartbeat",
    "LssFrame",
    "LssSession",
    "NmtCommandRecord",
    "NodeStats",
    "PdoRecord",
    "SdoBlockFrame",
    "SdoTransfer",
    "SyncRecord",
    "TimeRecord",
    "TraceRecord",
    "Unknown",
    "frame_kind",
]

__getattr__ = renamed_names(
    __name__,
    {
        "Record": ("TraceRecord", TraceRecord),
        "NmtCommand": ("NmtCommandRecord", NmtCommandRecord),
        "Emergency": ("EmergencyRecord", EmergencyRecord),
    },
)
