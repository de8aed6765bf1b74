"""Motion profiles: each stays within its limits, is continuous, and ends where it should;
the drive follows a jerk-limited one at a 1 ms SYNC."""

from __future__ import annotations

import itertools

import pytest

from cobus.profiles import Drive402
from cobus.profiles.trajectory import SCurve, Trapezoid
from cobus.runtime import Network
from cobus.sim import Rig, start_rig

SERVO = """
bus: embedded
devices:
  - {node: 10, kind: cia402_drive, name: servo}
"""


def derivatives(move: SCurve | Trapezoid, dt: float = 1e-4) -> tuple[list[float], list[float]]:
    n = int(move.duration / dt) + 3
    p = [move.position(i * dt) for i in range(-1, n)]
    v = [(b - a) / dt for a, b in itertools.pairwise(p)]
    a = [(d - c) / dt for c, d in itertools.pairwise(v)]
    return v, a


@pytest.mark.parametrize(
    ("start", "end", "v", "a", "j"),
    [
        (0, 100_000, 40_000, 200_000, 2_000_000),  # all seven phases
        (0, 1000, 40_000, 200_000, 2_000_000),  # too short: neither v nor a is reached
        (500, -20_000, 10_000, 1e6, 1e6),  # backwards; the jerk limits the acceleration
    ],
)
def test_an_s_curve_keeps_its_limits_and_ends_at_rest(
    start: float, end: float, v: float, a: float, j: float
) -> None:
    move = SCurve(start, end, v, a, j)
    assert move.position(0) == start and move.position(move.duration) == end
    velocity, acceleration = derivatives(move)
    assert max(abs(x) for x in velocity) <= v * 1.0001
    assert max(abs(x) for x in acceleration) <= a * 1.001
    jerks = [(y - x) / 1e-4 for x, y in itertools.pairwise(acceleration)]
    assert max(abs(x) for x in jerks) <= j * 1.05  # the acceleration ramps, never jumps
    assert move.duration >= Trapezoid(start, end, v, a).duration  # gentler, not faster


def test_the_seven_phases_take_the_textbook_times() -> None:
    move = SCurve(0, 100_000, 40_000, 200_000, 2_000_000)
    # jerk 0.1 s to 200 000, constant 0.1 s, jerk 0.1 s: 0.3 s and 6 000 each way;
    # 88 000 left at 40 000 inc/s: 2.2 s
    assert (move.t_jerk, move.t_const, move.t_cruise) == pytest.approx((0.1, 0.1, 2.2))
    assert move.duration == pytest.approx(2.8)
    with pytest.raises(ValueError, match="jerk must be above 0"):
        SCurve(0, 1, 1, 1, 0)


def test_the_drive_follows_an_s_curve_at_1_ms_sync() -> None:
    with Network(simulated=True) as net:
        start_rig(net, Rig.loads(SERVO))
        node = net.add_remote(10)
        node.rpdo.read()
        node.nmt.start()
        net.sync.start(0.001)
        drive = Drive402(node)
        drive.enable()
        move = SCurve(0, 30_000, 40_000, 200_000, 2_000_000)
        began = net.time()
        drive.follow(move)
        assert net.time() - began == pytest.approx(move.duration, abs=0.005)
        assert abs(drive.read_position() - 30_000) <= 20
