"""Joint motion of the mock UR controller: URScript movej (all joints synchronised on one trapezoidal velocity
profile, the leading joint at the commanded speed and acceleration) and stopj (a synchronised deceleration).

Everything is a function of integer controller ticks (2 ms: the e-Series controller runs at 500 Hz, RTDE guide), so
the same commands at the same ticks give the same joints bit for bit. URScript movej(q, a, v): "a: joint acceleration
of leading axis [rad/s^2], v: joint speed of leading axis [rad/s]" (UR Script Manual, movej); a joint cannot exceed
its rated speed (`vmax`), so v is capped per joint and the slowest joint sets the common duration.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Sequence

TICK_S = 0.002  # e-Series controller period (RTDE guide: 500 Hz on e-Series)
# UR10e datasheet (Universal Robots, "UR10e technical specifications"): joint ranges +-360 deg; maximum speed base
# and shoulder 120 deg/s, elbow and wrists 180 deg/s. The UR10 (CB3) datasheet gives the same figures.
UR10_VMAX_RAD_S = tuple(math.radians(v) for v in (120.0, 120.0, 180.0, 180.0, 180.0, 180.0))
UR10_LIMITS_RAD = tuple((-2 * math.pi, 2 * math.pi) for _ in range(6))


class Profile(ABC):
    """The path parameter s in [0, 1] over time: a trapezoid of path speed sv and acceleration sa (s units per
    second), a triangle when the path is too short to reach sv."""

    lead = 0.0  # the path's length in the units its speed and acceleration are given in (stop's deceleration too)
    sv = sa = 1.0
    ta = tc = total = 0.0

    def _shape(self, sv: float, sa: float) -> None:
        if sv * sv / sa >= 1.0:  # triangle: never reaches sv
            self.ta, self.tc = math.sqrt(1.0 / sa), 0.0
            sv = sa * self.ta
        else:
            self.ta = sv / sa
            self.tc = (1.0 - sv * self.ta) / sv
        self.sv, self.sa = sv, sa
        self.total = 2 * self.ta + self.tc

    def s(self, t: float) -> tuple[float, float]:
        """(s, ds/dt) at time t after the start."""
        if t >= self.total:
            return 1.0, 0.0
        if t <= 0:
            return 0.0, 0.0
        if t < self.ta:
            return 0.5 * self.sa * t * t, self.sa * t
        if t < self.ta + self.tc:
            return 0.5 * self.sa * self.ta**2 + self.sv * (t - self.ta), self.sv
        r = self.total - t
        return 1.0 - 0.5 * self.sa * r * r, self.sa * r

    @abstractmethod
    def at(self, s: float) -> tuple[float, ...]:
        """The joints at s."""

    @abstractmethod
    def rate(self, s: float) -> tuple[float, ...]:
        """dq/ds at s."""


class Path(Profile):
    """q(s) = q0 + (q1 - q0) s, s in [0, 1]; the scalar s follows a trapezoidal profile or a braking ramp."""

    def __init__(
        self, q0: Sequence[float], q1: Sequence[float], speed: float, acc: float, vmax: Sequence[float]
    ) -> None:
        if not (speed > 0 and acc > 0):
            raise ValueError("movej needs a positive speed and acceleration")
        self.q0 = tuple(float(v) for v in q0)
        self.q1 = tuple(float(v) for v in q1)
        self.d = tuple(b - a for a, b in zip(self.q0, self.q1, strict=True))
        lead = max(abs(x) for x in self.d)
        self.lead = lead
        if lead == 0.0:
            return
        # path speed / acceleration (units of s per second): the leading joint at (speed, acc), every joint under
        # its rated speed
        sv = speed / lead
        for dj, vj in zip(self.d, vmax, strict=True):
            if dj != 0.0:
                sv = min(sv, vj / abs(dj))
        self._shape(sv, acc / lead)

    def at(self, s: float) -> tuple[float, ...]:
        if s >= 1.0:
            return self.q1
        return tuple(a + dj * s for a, dj in zip(self.q0, self.d, strict=True))

    def rate(self, s: float) -> tuple[float, ...]:
        return self.d


class Motion:
    """The arm: joints, joint speeds, the running move and its braking, stepped one controller tick at a time."""

    def __init__(self, q: Sequence[float], vmax: Sequence[float] = UR10_VMAX_RAD_S) -> None:
        self.q = tuple(float(v) for v in q)
        self.qd = tuple(0.0 for _ in self.q)
        self.vmax = tuple(float(v) for v in vmax)
        self.path: Profile | None = None
        self._tick = 0  # ticks since the path started
        # braking: (s at the start, ds/dt at the start, deceleration in s units, ticks since the start)
        self._brake: tuple[float, float, float] | None = None
        self._brake_tick = 0

    @property
    def moving(self) -> bool:
        return self.path is not None

    def move(self, target: Sequence[float], speed: float, acc: float) -> None:
        self.follow(Path(self.q, target, speed, acc, self.vmax))

    def follow(self, path: Profile) -> None:
        """Start a path from where the arm stands (movej's Path, movel's linear.LinearPath)."""
        self.path = path
        self._tick, self._brake = 0, None
        if self.path.total == 0.0:
            self.path = None

    def stop(self, decel: float) -> None:
        """Decelerate the running move (leading joint at `decel` rad/s^2) along its path until it stands."""
        if self.path is None or self._brake is not None or decel <= 0:
            return
        s, sd = self.path.s(self._tick * TICK_S)
        self._brake = (s, sd, decel / self.path.lead)
        self._brake_tick = 0

    def step(self) -> None:
        path = self.path
        if path is None:
            return
        if self._brake is None:
            self._tick += 1
            t = self._tick * TICK_S
            s, sd = path.s(t)
            done = t >= path.total
        else:
            s0, sd0, dec = self._brake
            self._brake_tick += 1
            t_stop = sd0 / dec
            tau = min(self._brake_tick * TICK_S, t_stop)
            s, sd = s0 + sd0 * tau - 0.5 * dec * tau * tau, sd0 - dec * tau
            # braked once the brake's time has run (never on sd reaching exactly 0: sd0 - dec * (sd0 / dec) may round
            # to a residue above zero, and the move would never end); a gentle stop may reach the target first
            done = tau >= t_stop or sd <= 0.0 or s >= 1.0
            sd = 0.0 if done else sd
        self.q = path.at(s)
        self.qd = tuple(dj * sd for dj in path.rate(s))
        if done:
            self.path, self._brake = None, None
            self.qd = tuple(0.0 for _ in self.q)
