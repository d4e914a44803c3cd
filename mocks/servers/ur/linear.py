"""URScript movel for the mock UR controller: the TCP on a straight line to the target pose, its orientation turning
about one fixed axis, the path parameter on the trapezoid of motion.Profile at the tool's speed and acceleration.

URScript movel(pose, a, v): "Move to position (linear in tool-space)", "a: tool acceleration [m/s^2], v: tool speed
[m/s]" (UR Script Manual, movel). The line's length L sets the profile (s per second: v / L, a / L); a move that only
turns the tool (L = 0) takes v and a as rad/s and rad/s^2 of its angle (the manual does not say: the mock's
choice). A joint cannot exceed its rated speed: the path speed is lowered until none does (motion.Path caps movej the
same way). The joints come from inverse kinematics of the controller's own model (kinematics.flange, Newton's method
on the geometric Jacobian from where the arm stands) at WAYPOINT_S of the profile's time apart, linear in between: a
TCP off the line by a few micrometres at most at 0.25 m/s (an arc of the arm's reach between waypoints 5 mm
apart: 5^2 / (8 x 1000) mm), 0.1 um measured at 0.05 m/s. A target
the arm cannot reach on the line is refused before it moves (ValueError: the controller ends the program with a
runtime error, as a real one ends a movel it cannot solve).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from trackcal.mocks.servers.ur.kinematics import Calibration, rotation_vector
from trackcal.mocks.servers.ur.motion import Profile

WAYPOINT_S = 0.02  # inverse kinematics every 10 controller ticks of the profile
IK_TOLERANCE = 1e-10  # m and rad
IK_ITERATIONS = 30


def _rotation(rv: Sequence[float]) -> np.ndarray:
    """Rodrigues: the rotation matrix of a rotation vector (UR's pose convention)."""
    w = np.asarray(rv, dtype=float)
    angle = float(np.linalg.norm(w))
    if angle < 1e-15:
        return np.eye(3)
    k = w / angle
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(angle) * kx + (1 - math.cos(angle)) * kx @ kx


def _rotvec(r: np.ndarray) -> np.ndarray:
    return np.array(rotation_vector(r.tolist()))


def _tcp(q: Sequence[float], cal: Calibration, tcp: Sequence[float]):
    """(TCP position, rotation, geometric Jacobian 6 x 6) of joints q: kinematics.flange's chain (standard DH)."""
    t = np.eye(4)
    axes, origins = [], []
    for i in range(6):
        axes.append(t[:3, 2].copy())
        origins.append(t[:3, 3].copy())
        th = q[i] + cal.dh_theta[i]
        ct, st = math.cos(th), math.sin(th)
        ca, sa = math.cos(cal.dh_alpha[i]), math.sin(cal.dh_alpha[i])
        a, d = cal.dh_a[i], cal.dh_d[i]
        t = t @ np.array(
            [[ct, -st * ca, st * sa, a * ct], [st, ct * ca, -ct * sa, a * st], [0.0, sa, ca, d], [0.0, 0.0, 0.0, 1.0]]
        )
    p = t[:3, 3] + t[:3, :3] @ np.asarray(tcp, dtype=float)
    z = np.array(axes)
    return p, t[:3, :3], np.vstack([np.cross(z, p - np.array(origins)).T, z.T])


def solve(q: Sequence[float], p: np.ndarray, r: np.ndarray, cal: Calibration, tcp: Sequence[float]) -> np.ndarray:
    """Joints placing the TCP at (p, r), by Newton's method from q; ValueError when it does not converge."""
    x = np.asarray(q, dtype=float).copy()
    for _ in range(IK_ITERATIONS):
        pos, rot, jac = _tcp(x, cal, tcp)
        err = np.concatenate([p - pos, _rotvec(r @ rot.T)])
        if float(np.max(np.abs(err))) < IK_TOLERANCE:
            return x
        try:
            x += np.linalg.solve(jac, err)
        except np.linalg.LinAlgError:  # singular: a singularity on the line
            break
    raise ValueError("inverse kinematics failed: the pose is out of reach on the line, or a singularity is on it")


class LinearPath(Profile):
    def __init__(
        self,
        q0: Sequence[float],
        pose: Sequence[float],
        speed: float,
        acc: float,
        cal: Calibration,
        tcp: Sequence[float],
        vmax: Sequence[float],
        limits: Sequence[tuple[float, float]] | None = None,
    ) -> None:
        if not (speed > 0 and acc > 0):
            raise ValueError("movel needs a positive speed and acceleration")
        if len(pose) != 6 or not all(math.isfinite(v) for v in pose):
            raise ValueError("movel needs a pose p[x, y, z, rx, ry, rz]")
        self.q0 = tuple(float(v) for v in q0)
        p0, r0, _ = _tcp(self.q0, cal, tcp)
        p1, r1 = np.asarray(pose[:3], dtype=float), _rotation(pose[3:])
        turn = _rotvec(r0.T @ r1)  # in the start's tool frame
        length, angle = float(np.linalg.norm(p1 - p0)), float(np.linalg.norm(turn))
        self.lead = length if length > 1e-9 else angle
        self.waypoints = [np.asarray(self.q0)]
        if self.lead == 0.0:
            self.q1 = self.q0
            return
        self._shape(speed / self.lead, acc / self.lead)
        n = max(2, math.ceil(self.total / WAYPOINT_S))
        for k in range(1, n + 1):
            s = k / n
            self.waypoints.append(solve(self.waypoints[-1], p0 + s * (p1 - p0), r0 @ _rotation(s * turn), cal, tcp))
        self.q1 = tuple(float(v) for v in self.waypoints[-1])
        self.n = n
        qs = np.array(self.waypoints)
        for j, (lo, hi) in enumerate(limits or ()):
            if qs[:, j].min() < lo or qs[:, j].max() > hi:
                raise ValueError("the line leaves the joint limits")
        steps = np.abs(np.diff(np.array(self.waypoints), axis=0)).max(axis=0) * n  # max |dq/ds| per joint
        sv = speed / self.lead
        for rate, vj in zip(steps, vmax, strict=True):
            if rate > 0:
                sv = min(sv, vj / rate)
        self._shape(sv, acc / self.lead)

    def _segment(self, s: float) -> tuple[int, float]:
        k = min(int(s * self.n), self.n - 1)
        return k, s * self.n - k

    def at(self, s: float) -> tuple[float, ...]:
        if s >= 1.0:
            return self.q1
        k, u = self._segment(max(s, 0.0))
        a, b = self.waypoints[k], self.waypoints[k + 1]
        return tuple(float(v) for v in a + u * (b - a))

    def rate(self, s: float) -> tuple[float, ...]:
        k, _ = self._segment(min(max(s, 0.0), 1.0))
        return tuple(float(v) for v in (self.waypoints[k + 1] - self.waypoints[k]) * self.n)
