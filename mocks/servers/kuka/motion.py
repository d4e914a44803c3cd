"""The mock KR C2's motion model: joint state over interpolation cycles. Pure: no sockets, no threads, no clock.

Motion is a synchronous PTP (all axes start and stop together) with a quintic profile
s(u) = 10u^3 - 15u^4 + 6u^5, whose peak speed is 1.875x the mean and peak acceleration 10/sqrt(3) x span / T^2, so
the duration is the longer of T = 1.875 * max|dq| / v and T = sqrt(10/sqrt(3) * max|dq| / a), with the leading
axis's speed v = joint_speed_deg_s * speed% / 100 and acceleration a = joint_speed_deg_s / raise_time_s * speed% / 100
(a short move is acceleration-limited, a long one speed-limited). The acceleration is the KR C2's: "$RAISE_TIME +
$FILTER/2 is the time in ms in which the axis can be accelerated to its rated speed ($VEL_AXIS_MA)", and the command
acceleration is at most $ACC_ACT_MA/100 * rated speed / $RAISE_TIME (KUKA, KR C2 Machine Data, Maschinendaten
12.0400 en, 2.1.47 and 2.1.115); configs/krc2/trackcal_eki.src sets $VEL_AXIS[i] and $ACC_AXIS[i] both to the
request's speed %. After arrival a damped residual oscillation
overshoot * exp(-t / (settle_s / 5)) * cos(2 pi 1.5 Hz t) decays (e^-5 < 1 % of it is left after settle_s):
this is what trackcal's wait_settled must see through. The program's dwell is settle_s; then the move is done
(the controller reports $AXIS_ACT, 4 decimals). BRAKE (a Kind 2 stop of the running move): the axes decelerate
at brake_deg_s2 (all at the same rate relative to their speed, so they stop together, as a synchronous PTP).

Everything is computed from integer cycle counts (not accumulated float time) and the random.Random it is given
(one draw per move, for the overshoot's amplitude), so the same seed and the same commands give the same joints.
"""

from __future__ import annotations

import math
import random
from collections.abc import Sequence
from itertools import repeat

from trackcal.drivers.kuka.eki_codec import ERR_STOPPED, Command

_RESIDUAL_HZ = 1.5
# $RAISE_TIME + $DEF_FLT_PTP / 2 of the mock's axes (s): a KR 270's own value is in its $machine.dat, which KUKA does
# not publish (with KUKA robots the controller also adapts it to the load); half a second to the rated speed is the
# mock's choice, so a 2 deg move at 100 % takes 0.25 s instead of the 39 ms a speed-only profile gave it
RAISE_TIME_S = 0.5
QUINTIC_PEAK_ACCELERATION = 10.0 / math.sqrt(3.0)  # max of s''(u) = 60u - 180u^2 + 120u^3, at u = (3 - sqrt 3) / 6

Stop = tuple[tuple[float, ...], tuple[float, ...], tuple[float, ...]]  # joints, axis speeds, joints at standstill
_DECIMALS = repeat(4)  # what the controller reports: 4 decimals (map(round, values, _DECIMALS))


def quintic(u: float) -> float:
    return u * u * u * (10.0 - 15.0 * u + 6.0 * u * u)


def quintic_rate(u: float) -> float:
    return 30.0 * u * u * (1.0 - u) * (1.0 - u)


class Motion:
    """The arm of the mock controller, one interpolation cycle (cycle_s) per step().

    mode: idle, moving, braking, dwell. `command` is the move running (None when idle); `stops` records
    (joints, axis speeds, joints at standstill) for every braking.
    """

    def __init__(
        self,
        initial_joints_deg: Sequence[float],
        rng: random.Random,
        *,
        joint_speed_deg_s: float,
        settle_s: float,
        cycle_s: float,
        overshoot_deg: float,
        brake_deg_s2: float,
        raise_time_s: float = RAISE_TIME_S,
    ) -> None:
        q0 = tuple(float(v) for v in initial_joints_deg)
        self.joint_speed_deg_s = float(joint_speed_deg_s)
        self.raise_time_s = float(raise_time_s)  # 0: no acceleration limit (a speed-only profile)
        self.settle_s = float(settle_s)
        self.cycle_s = float(cycle_s)
        self.overshoot_deg = float(overshoot_deg)
        self.brake_deg_s2 = float(brake_deg_s2)
        self._rng = rng
        self.q = list(q0)  # actual joints (replaced, never changed in place: the rounded reports are kept per list)
        self.q_set = list(q0)  # set point (the same list as q while they are equal)
        self._reported: tuple[list[float], tuple[float, ...]] = (self.q, self._round(self.q))
        self._reported_set: tuple[list[float], tuple[float, ...]] = (self.q_set, self._round(self.q_set))
        self.mode = "idle"
        self.command: Command | None = None
        self._start: tuple[float, ...] = q0
        self._target: tuple[float, ...] = q0
        self._dirs = (0.0,) * len(q0)
        self._amp = 0.0
        self._k = 0  # cycles into the current motion phase
        self._n_move = 0
        self._n_dwell = max(1, math.ceil(self.settle_s / self.cycle_s - 1e-9))
        self._brake_from: tuple[float, ...] = q0
        self._brake_v: tuple[float, ...] = (0.0,) * len(q0)
        self._n_brake = 0
        self._since_arrival: int | None = None
        self.stops: list[Stop] = []

    @staticmethod
    def _round(values: list[float]) -> tuple[float, ...]:
        return tuple(map(round, values, _DECIMALS))

    @property
    def joints_deg(self) -> tuple[float, ...]:
        """$AXIS_ACT as the controller reports it: 4 decimals (rounded once per step: issue 41, the controller
        reads it several times a cycle)."""
        q, rounded = self._reported
        if q is not self.q:
            rounded = self._round(self.q)
            self._reported = (self.q, rounded)
        return rounded

    @property
    def set_deg(self) -> tuple[float, ...]:
        """The set point (ASPos) as the controller reports it: 4 decimals."""
        if self.q_set is self.q:
            return self.joints_deg
        q_set, rounded = self._reported_set
        if q_set is not self.q_set:
            rounded = self._round(self.q_set)
            self._reported_set = (self.q_set, rounded)
        return rounded

    @property
    def moving(self) -> bool:
        return self.mode in ("moving", "braking")

    @property
    def still(self) -> bool:
        """Idle and no residual oscillation left."""
        return self.mode == "idle" and self._since_arrival is None

    def begin(self, cmd: Command) -> None:
        """Start the PTP move `cmd` from where the arm is (the controller checked it)."""
        start = tuple(self.q)
        deltas = [b - a for a, b in zip(start, cmd.target_deg, strict=True)]
        span = max(abs(d) for d in deltas)
        speed = self.joint_speed_deg_s * cmd.speed_pct / 100.0
        duration = 1.875 * span / speed
        if self.raise_time_s > 0:  # the acceleration limit: $ACC_AXIS[i] = speed % of rated speed / $RAISE_TIME
            duration = max(duration, math.sqrt(QUINTIC_PEAK_ACCELERATION * span * self.raise_time_s / speed))
        self.command, self._start, self._target = cmd, start, tuple(cmd.target_deg)
        self._dirs = tuple(d / span for d in deltas) if span > 0 else (0.0,) * len(start)
        self._amp = self.overshoot_deg * (0.5 + 0.5 * self._rng.random()) if span > 0 else 0.0
        self._n_move = math.ceil(duration / self.cycle_s - 1e-9) if span > 0 else 0
        self._k = 0
        if self._n_move == 0:
            self.mode, self._since_arrival = "dwell", 0
        else:
            self.mode, self._since_arrival = "moving", None

    def brake(self) -> None:
        """BRAKE: every axis decelerates from its speed now, all at the rate that stops the fastest one at
        brake_deg_s2, so they stop together after v_max / brake_deg_s2 (braking distance v^2 / (2 a))."""
        duration = self._n_move * self.cycle_s
        rate = quintic_rate(self._k / self._n_move) / duration
        self._brake_v = tuple((b - a) * rate for a, b in zip(self._start, self._target, strict=True))
        self._brake_from = tuple(self.q)
        v_max = max(abs(v) for v in self._brake_v)
        self._n_brake = max(1, math.ceil(v_max / self.brake_deg_s2 / self.cycle_s - 1e-9))
        self.mode, self._k = "braking", 0

    def halt(self) -> Command | None:
        """Stand where the arm is now (a fault, a stop at rest); the move that was running, if any."""
        cmd = self.command
        self._target = self._start = tuple(self.q)
        self.q_set = list(self.q)
        self._amp, self._since_arrival, self.mode, self.command = 0.0, None, "idle", None
        return cmd

    def _residual(self, k: int) -> float:
        t = k * self.cycle_s
        tau = max(self.settle_s / 5.0, self.cycle_s)
        if t / tau > 40.0:
            return 0.0
        return self._amp * math.exp(-t / tau) * math.cos(2.0 * math.pi * _RESIDUAL_HZ * t)

    def step(self) -> tuple[Command, bool, int] | None:
        """One interpolation cycle; the move that ended in it, as (command, done, error), if one did: done after
        its dwell, or stopped (ERR_STOPPED) once braked to standstill."""
        if self.mode == "moving":
            self._k += 1
            u = min(1.0, self._k / self._n_move)
            p = quintic(u)
            self.q = [a + (b - a) * p for a, b in zip(self._start, self._target, strict=True)]
            self.q_set = self.q
            if self._k >= self._n_move:
                self.mode, self._k, self._since_arrival = "dwell", 0, 0
            return None
        if self.mode == "braking":
            self._k += 1
            t, t_stop = self._k * self.cycle_s, self._n_brake * self.cycle_s
            t = min(t, t_stop)
            travel = t - 0.5 * t * t / t_stop  # v(t) = v0 (1 - t / t_stop): constant deceleration
            self.q = [q0 + v * travel for q0, v in zip(self._brake_from, self._brake_v, strict=True)]
            self.q_set = self.q
            if self._k >= self._n_brake:
                self.stops.append((self._brake_from, self._brake_v, self.joints_deg))
                cmd = self.halt()
                return None if cmd is None else (cmd, False, ERR_STOPPED)
            return None
        if self._since_arrival is not None:  # the residual oscillation decays, dwelling or not
            self._since_arrival += 1
            r = self._residual(self._since_arrival)
            self.q = [t + d * r for t, d in zip(self._target, self._dirs, strict=True)]
            self.q_set = list(self._target)
            if r == 0.0:
                self._since_arrival = None
        if self.mode == "dwell":  # counted apart from the oscillation: without overshoot it still ends
            self._k += 1
            if self._k >= self._n_dwell:  # WAIT SEC 0 + dwell done: report $AXIS_ACT
                cmd = self.command
                assert cmd is not None
                self.mode, self.command = "idle", None
                return cmd, True, 0
        return None
