"""Motion profiles a master computes and feeds to a drive cycle by cycle (cyclic synchronous
position): ``Trapezoid(start, end, velocity, acceleration)`` gives the position at any time.

A trajectory is any object with ``duration`` (seconds), ``start``/``end`` (positions) and
``position(t)`` — a user may write their own (a cam table, a spline).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Protocol

__all__ = ["Trajectory", "Trapezoid"]


class Trajectory(Protocol):
    """What :meth:`~cobus.profiles.AsyncDrive402.follow` needs of a trajectory."""

    @property
    def duration(self) -> float:
        """Seconds from the start to the end."""

    @property
    def start(self) -> float:
        """The position at t = 0."""

    @property
    def end(self) -> float:
        """The position at t >= duration."""

    def position(self, t: float) -> float:
        """The position ``t`` seconds after the start (``start`` before 0, ``end`` after
        the duration)."""


def _positive(what: str, value: float) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise TypeError(f"{what} must be a finite number, not {value!r}")
    if value <= 0:
        raise ValueError(f"{what} must be above 0, not {value!r}")
    return float(value)


@dataclass(frozen=True)
class Trapezoid:
    """A move from ``start`` to ``end``: accelerate at ``acceleration`` up to ``velocity``,
    cruise, decelerate at ``deceleration`` (default: the acceleration) to stand at ``end``;
    a triangle when the distance is too short to reach the velocity. Units are the caller's
    (increments, or user units, per second)."""

    start: float
    end: float
    velocity: float
    acceleration: float
    deceleration: float | None = None
    #: Seconds of the three phases and the peak velocity reached (computed).
    t_acc: float = field(init=False)
    t_cruise: float = field(init=False)
    t_dec: float = field(init=False)
    peak: float = field(init=False)

    def __post_init__(self) -> None:
        for what in ("start", "end"):
            value = getattr(self, what)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise TypeError(f"{what} must be a number, not {value!r}")
            if not math.isfinite(value):
                raise ValueError(f"{what} must be finite, not {value!r}")
        v = _positive("velocity", self.velocity)
        a = _positive("acceleration", self.acceleration)
        d = _positive("deceleration", a if self.deceleration is None else self.deceleration)
        distance = abs(self.end - self.start)
        if distance <= v * v / (2 * a) + v * v / (2 * d):
            v = math.sqrt(2 * distance * a * d / (a + d))
        t_acc, t_dec = v / a, v / d
        cruise = (distance - v * t_acc / 2 - v * t_dec / 2) / v if v > 0 else 0.0
        object.__setattr__(self, "peak", v)
        object.__setattr__(self, "t_acc", t_acc)
        object.__setattr__(self, "t_dec", t_dec)
        object.__setattr__(self, "t_cruise", max(cruise, 0.0))

    @property
    def duration(self) -> float:
        """Seconds from the start to the end."""
        return self.t_acc + self.t_cruise + self.t_dec

    def position(self, t: float) -> float:
        """The position ``t`` seconds after the start."""
        sign = 1.0 if self.end >= self.start else -1.0
        v = self.peak
        if t <= 0:
            return self.start
        if t >= self.duration:
            return self.end
        if t < self.t_acc:
            s = v / self.t_acc * t * t / 2
        elif t < self.t_acc + self.t_cruise:
            s = v * self.t_acc / 2 + v * (t - self.t_acc)
        else:
            left = self.duration - t
            s = abs(self.end - self.start) - v / self.t_dec * left * left / 2
        return self.start + sign * s

    def velocity_at(self, t: float) -> float:
        """The velocity ``t`` seconds after the start (signed)."""
        sign = 1.0 if self.end >= self.start else -1.0
        if t <= 0 or t >= self.duration:
            return 0.0
        if t < self.t_acc:
            return sign * self.peak * t / self.t_acc
        if t < self.t_acc + self.t_cruise:
            return sign * self.peak
        return sign * self.peak * (self.duration - t) / self.t_dec
