"""Motion profiles a master computes and feeds to a drive cycle by cycle (cyclic synchronous
position): ``Trapezoid(start, end, velocity, acceleration)`` gives the position at any time.

A trajectory is any object with ``duration`` (seconds), ``start``/``end`` (positions) and
``position(t)`` — a user may write their own (a cam table, a spline).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Protocol

__all__ = ["SCurve", "Trajectory", "Trapezoid"]


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


def _check_ends(start: float, end: float) -> None:
    for what, value in (("start", start), ("end", end)):
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise TypeError(f"{what} must be a number, not {value!r}")
        if not math.isfinite(value):
            raise ValueError(f"{what} must be finite, not {value!r}")


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
        _check_ends(self.start, self.end)
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


@dataclass(frozen=True)
class SCurve:
    """A jerk-limited move from ``start`` to ``end``: the acceleration ramps at ``jerk`` up
    to ``acceleration`` and back (seven phases: jerk, constant acceleration, jerk, cruise at
    ``velocity``, and the mirror image to stand at ``end``). When the distance is too short
    for the velocity, the highest velocity that fits is used; when the velocity is too low
    for the acceleration, the highest acceleration that fits. Gentler on the mechanics than
    :class:`Trapezoid`, for a little more time."""

    start: float
    end: float
    velocity: float
    acceleration: float
    jerk: float
    #: The peak velocity and acceleration reached, the jerk and constant-acceleration
    #: phase times, and the cruise time (computed).
    peak: float = field(init=False)
    peak_acceleration: float = field(init=False)
    t_jerk: float = field(init=False)
    t_const: float = field(init=False)
    t_cruise: float = field(init=False)

    def __post_init__(self) -> None:
        _check_ends(self.start, self.end)
        v_max = _positive("velocity", self.velocity)
        a_max = _positive("acceleration", self.acceleration)
        j = _positive("jerk", self.jerk)
        distance = abs(self.end - self.start)

        def ramp(v: float) -> tuple[float, float, float]:
            """(peak acceleration, jerk time, constant time) to reach ``v`` from rest."""
            a = min(a_max, math.sqrt(v * j))
            tj = a / j
            return a, tj, max(v / a - tj, 0.0) if a > 0 else 0.0

        def ramp_distance(v: float) -> float:
            _a, tj, tc = ramp(v)
            return v * (2 * tj + tc) / 2  # the ramp's mean velocity is v / 2 (symmetry)

        v = v_max
        if 2 * ramp_distance(v) > distance:  # too short: the highest velocity that fits
            low, high = 0.0, v_max
            for _ in range(80):
                mid = (low + high) / 2
                low, high = (mid, high) if 2 * ramp_distance(mid) <= distance else (low, mid)
            v = low
        a, tj, tc = ramp(v)
        cruise = (distance - 2 * ramp_distance(v)) / v if v > 0 else 0.0
        object.__setattr__(self, "peak", v)
        object.__setattr__(self, "peak_acceleration", a)
        object.__setattr__(self, "t_jerk", tj)
        object.__setattr__(self, "t_const", tc)
        object.__setattr__(self, "t_cruise", max(cruise, 0.0))

    @property
    def _ramp_time(self) -> float:
        return 2 * self.t_jerk + self.t_const

    @property
    def duration(self) -> float:
        """Seconds from the start to the end."""
        return 2 * self._ramp_time + self.t_cruise

    def _ramp(self, t: float) -> float:
        """The distance covered ``t`` seconds into the acceleration ramp."""
        j, tj, tc, a = self.jerk, self.t_jerk, self.t_const, self.peak_acceleration
        if t <= tj:
            return j * t**3 / 6
        s1, v1 = j * tj**3 / 6, j * tj**2 / 2
        if t <= tj + tc:
            u = t - tj
            return s1 + v1 * u + a * u * u / 2
        s2, v2 = s1 + v1 * tc + a * tc * tc / 2, v1 + a * tc
        u = min(t - tj - tc, tj)
        return s2 + v2 * u + a * u * u / 2 - j * u**3 / 6

    def position(self, t: float) -> float:
        """The position ``t`` seconds after the start."""
        if t <= 0:
            return self.start
        if t >= self.duration:
            return self.end
        sign = 1.0 if self.end >= self.start else -1.0
        distance = abs(self.end - self.start)
        ramp = self._ramp_time
        if t <= ramp:
            s = self._ramp(t)
        elif t <= ramp + self.t_cruise:
            s = self._ramp(ramp) + self.peak * (t - ramp)
        else:
            s = distance - self._ramp(self.duration - t)
        return self.start + sign * s

    def velocity_at(self, t: float) -> float:
        """The velocity ``t`` seconds after the start (signed)."""
        if t <= 0 or t >= self.duration:
            return 0.0
        h = min(1e-6, t / 2, (self.duration - t) / 2)
        return (self.position(t + h) - self.position(t - h)) / (2 * h)
