"""Global diagnostics of the master: bus state and error counters, queue overflows, the SYNC
toggle bit and the bus load over a sliding window.

The bus load is what the frames seen take of the bit rate: each frame counts its bits on the
wire (start of frame to the end of the interframe space) with the worst-case number of stuff
bits CiA/ISO 11898 allow, averaged over the window (100-500 ms is usual).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

from cobus.master.errors import MasterValueError
from cobus.proto import Frame
from cobus.proto.frame import frame_bits  # (its home; kept importable from here)
from cobus.runtime.events import BusState

__all__ = ["BusLoadMeter", "MasterDiagnostics", "frame_bits"]


class BusLoadMeter:
    """Bus load in % of ``bitrate`` over the last ``window`` seconds."""

    __slots__ = ("_bits", "_frames", "bitrate", "window")

    def __init__(self, bitrate: int, window: float = 0.25) -> None:
        if bitrate <= 0 or window <= 0:
            raise MasterValueError(
                f"bit rate {bitrate} bit/s and window {window} s must both be positive"
            )
        self.bitrate = bitrate
        self.window = window
        self._frames: deque[tuple[float, int]] = deque()
        self._bits = 0

    def add(self, frame: Frame, now: float) -> None:
        """Count ``frame``, seen at ``now``, in the load of the window."""
        bits = frame_bits(frame)
        self._frames.append((now, bits))
        self._bits += bits
        self._expire(now)

    def _expire(self, now: float) -> None:
        frames = self._frames
        limit = now - self.window
        while frames and frames[0][0] <= limit:
            self._bits -= frames.popleft()[1]

    def load(self, now: float) -> float:
        """The bus load in % at ``now``."""
        self._expire(now)
        return 100.0 * self._bits / (self.bitrate * self.window)


@dataclass
class MasterDiagnostics:
    """What the master knows about the bus (the Beckhoff master's global diagnostics)."""

    bus_state: BusState = BusState.ACTIVE
    tx_errors: int | None = None
    rx_errors: int | None = None
    bus_off_count: int = 0
    rx_overflows: int = 0
    tx_queue_overflows: int = 0
    send_errors: int = 0
    sync_count: int = 0
    #: Toggles with every SYNC seen on the bus.
    sync_toggle: bool = False
    frames: int = 0
    #: Frames sent (RPDOs) and received (TPDOs) per PDO: ``(node_id, "tpdo"|"rpdo", n)``.
    pdo_counters: dict[tuple[int, str, int], int] = field(default_factory=dict)

    @property
    def bus_off(self) -> bool:
        """Whether the controller is bus-off."""
        return self.bus_state is BusState.BUS_OFF

    @property
    def warning(self) -> bool:
        """The controller reached the warning limit (or worse)."""
        return self.bus_state is not BusState.ACTIVE
