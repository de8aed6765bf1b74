"""Looking at a bus: :class:`~cobus.trace.decoder.Decoder` turns frames into CANopen records
(NMT, heartbeat, guarding, SYNC, TIME, EMCY, LSS, whole SDO transfers, PDOs by name)."""

from cobus.trace.decoder import (
    Bootup,
    Decoder,
    Emergency,
    GuardRequest,
    GuardResponse,
    Heartbeat,
    LssFrame,
    LssSession,
    NmtCommand,
    NodeStats,
    PdoRecord,
    Record,
    SdoBlockFrame,
    SdoTransfer,
    SyncRecord,
    TimeRecord,
    Unknown,
    frame_kind,
)

__all__ = [
    "Bootup",
    "Decoder",
    "Emergency",
    "GuardRequest",
    "GuardResponse",
    "Heartbeat",
    "LssFrame",
    "LssSession",
    "NmtCommand",
    "NodeStats",
    "PdoRecord",
    "Record",
    "SdoBlockFrame",
    "SdoTransfer",
    "SyncRecord",
    "TimeRecord",
    "Unknown",
    "frame_kind",
]
