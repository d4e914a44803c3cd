"""The mock controller's own kinematic model: UR10 nominal DH plus a factory calibration, for actual_TCP_pose and
the primary interface's KINEMATICS_INFO.

Nominal DH: Universal Robots' published UR10 parameters (the same as configs/robots/ur10.yaml): d1 = 0.1273,
a2 = -0.612, a3 = -0.5723, d4 = 0.163941, d5 = 0.1157, d6 = 0.0922 m, alpha = pi/2, 0, 0, pi/2, -pi/2, 0; link i is
Rz(theta_i + q_i) Tz(d_i) Tx(a_i) Rx(alpha_i) (standard DH). A real UR carries in calibration.conf and sends in
KINEMATICS_INFO the calibrated DH of its arm (ur_client_library primary/robot_state/kinematics_info.cpp parses
checksum, dh_theta, dh_a, dh_d, dh_alpha, calibration_status; ur_calibration builds the chain as theta offset
dh_theta and full a, d, alpha). The mock's factory calibration is a small seeded deviation from the nominal
(theta and alpha 1e-4 rad, a and d 0.2 mm standard deviations): the order of magnitude of the residual errors a
factory calibration corrects, not UR's redundant parameterisation (real files move d2/d3 and theta2..4 by large
compensating amounts), which a consumer handles the same way.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass

NOMINAL_A = (0.0, -0.612, -0.5723, 0.0, 0.0, 0.0)
NOMINAL_D = (0.1273, 0.0, 0.0, 0.163941, 0.1157, 0.0922)
NOMINAL_ALPHA = (math.pi / 2, 0.0, 0.0, math.pi / 2, -math.pi / 2, 0.0)
NOMINAL_THETA = (0.0,) * 6


@dataclass(frozen=True)
class Calibration:
    """Calibrated DH of one arm, as KINEMATICS_INFO carries it (metres, radians)."""

    checksum: tuple[int, ...]
    dh_theta: tuple[float, ...]
    dh_a: tuple[float, ...]
    dh_d: tuple[float, ...]
    dh_alpha: tuple[float, ...]
    calibration_status: int = 0  # the mock reports 0; UR does not document the values publicly


def factory_calibration(seed: int) -> Calibration:
    rng = random.Random(f"ur-factory-calibration/{seed}")
    theta = tuple(t + rng.gauss(0.0, 1e-4) for t in NOMINAL_THETA)
    a = tuple(v + rng.gauss(0.0, 2e-4) for v in NOMINAL_A)
    d = tuple(v + rng.gauss(0.0, 2e-4) for v in NOMINAL_D)
    alpha = tuple(v + rng.gauss(0.0, 1e-4) for v in NOMINAL_ALPHA)
    checksum = tuple(rng.getrandbits(32) for _ in range(6))
    return Calibration(checksum, theta, a, d, alpha)


def _matmul(m, n):
    return [[sum(m[i][k] * n[k][j] for k in range(4)) for j in range(4)] for i in range(4)]


def flange(q, cal: Calibration):
    """4x4 pose of the tool flange in the base frame (lists of floats)."""
    t = [[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]]
    for i in range(6):
        th = q[i] + cal.dh_theta[i]
        ct, st = math.cos(th), math.sin(th)
        ca, sa = math.cos(cal.dh_alpha[i]), math.sin(cal.dh_alpha[i])
        a, d = cal.dh_a[i], cal.dh_d[i]
        link = [[ct, -st * ca, st * sa, a * ct], [st, ct * ca, -ct * sa, a * st], [0.0, sa, ca, d], [0, 0, 0, 1.0]]
        t = _matmul(t, link)
    return t


def rotation_vector(r) -> tuple[float, float, float]:
    """Axis-angle vector of a rotation matrix (UR's pose convention: p[x, y, z, rx, ry, rz])."""
    c = max(-1.0, min(1.0, (r[0][0] + r[1][1] + r[2][2] - 1.0) / 2.0))
    angle = math.acos(c)
    if angle < 1e-12:
        return (0.0, 0.0, 0.0)
    if math.pi - angle < 1e-6:  # near pi: axis from the diagonal
        x = math.sqrt(max(0.0, (r[0][0] + 1) / 2))
        y = math.copysign(math.sqrt(max(0.0, (r[1][1] + 1) / 2)), r[0][1] if x > 1e-9 else 1.0)
        z = math.copysign(math.sqrt(max(0.0, (r[2][2] + 1) / 2)), r[0][2] if x > 1e-9 else r[1][2])
        return (x * angle, y * angle, z * angle)
    k = angle / (2 * math.sin(angle))
    return (k * (r[2][1] - r[1][2]), k * (r[0][2] - r[2][0]), k * (r[1][0] - r[0][1]))


def tcp_pose(q, cal: Calibration, tcp=(0.0, 0.0, 0.0)) -> tuple[float, ...]:
    """p[x, y, z, rx, ry, rz] of the TCP (a translation `tcp` in the flange frame) in the base frame."""
    t = flange(q, cal)
    pos = [t[i][3] + sum(t[i][k] * tcp[k] for k in range(3)) for i in range(3)]
    rot = [row[:3] for row in t[:3]]
    return (*pos, *rotation_vector(rot))


def tcp_speed(q, qd, cal: Calibration, tcp=(0.0, 0.0, 0.0), dt: float = 0.002) -> tuple[float, ...]:
    """[vx, vy, vz, wx, wy, wz] of the TCP in the base frame (RTDE actual_TCP_speed: linear and angular velocity),
    by a backward difference over dt."""
    before = [a - b * dt for a, b in zip(q, qd, strict=True)]
    t1, t0 = flange(q, cal), flange(before, cal)
    p1 = [t1[i][3] + sum(t1[i][k] * tcp[k] for k in range(3)) for i in range(3)]
    p0 = [t0[i][3] + sum(t0[i][k] * tcp[k] for k in range(3)) for i in range(3)]
    # R1 R0^T = exp([w] dt)
    rel = [[sum(t1[i][k] * t0[j][k] for k in range(3)) for j in range(3)] for i in range(3)]
    w = rotation_vector(rel)
    return (*((a - b) / dt for a, b in zip(p1, p0, strict=True)), *(x / dt for x in w))
