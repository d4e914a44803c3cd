"""Rotations and rigid transforms (numpy, batched where it matters)."""

from __future__ import annotations

import numpy as np

from trackcal.calib.errors import CalibError

AXIS_INDEX = {"x": 0, "y": 1, "z": 2}
AXIS_NAME = "xyz"


class RigidError(CalibError):
    """Points that do not determine a rigid transform (too few, collinear)."""


def rot_axis(axis: int, angle: np.ndarray | float) -> np.ndarray:
    """Rotation matrices about coordinate axis `axis` (0, 1, 2) by `angle` (rad); shape angle.shape + (3, 3)."""
    angle = np.asarray(angle, dtype=float)
    c, s = np.cos(angle), np.sin(angle)
    out = np.zeros(angle.shape + (3, 3))
    i, j = (axis + 1) % 3, (axis + 2) % 3
    out[..., axis, axis] = 1.0
    out[..., i, i] = c
    out[..., j, j] = c
    out[..., j, i] = s
    out[..., i, j] = -s
    return out


def skew(v: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """Skew-symmetric matrices [v]x with [v]x w = v x w; v shape (..., 3); written into `out` if given."""
    v = np.asarray(v, dtype=float)
    if out is None:
        out = np.zeros(v.shape[:-1] + (3, 3))
    else:
        out[..., 0, 0] = out[..., 1, 1] = out[..., 2, 2] = 0.0
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def exp_so3(w: np.ndarray) -> np.ndarray:
    """Rodrigues: rotation matrix of the rotation vector w (rad)."""
    w = np.asarray(w, dtype=float)
    theta = float(np.linalg.norm(w))
    k = skew(w)
    if theta < 1e-12:
        return np.eye(3) + k + 0.5 * k @ k
    return np.eye(3) + np.sin(theta) / theta * k + (1.0 - np.cos(theta)) / theta**2 * k @ k


def rpy_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """URDF convention: R = Rz(yaw) Ry(pitch) Rx(roll) (rad)."""
    return rot_axis(2, yaw) @ rot_axis(1, pitch) @ rot_axis(0, roll)


def rpy_of(r: np.ndarray) -> np.ndarray:
    """URDF (roll, pitch, yaw) of a rotation matrix, rad, with rpy_matrix(*rpy_of(r)) = r; pitch from atan2, which
    stays accurate near +-90 deg (arcsin loses half the digits there)."""
    c = np.hypot(r[0, 0], r[1, 0])
    pitch = np.arctan2(-r[2, 0], c)
    if c > 1e-12:
        return np.array([np.arctan2(r[2, 1], r[2, 2]), pitch, np.arctan2(r[1, 0], r[0, 0])])
    return np.array([np.arctan2(-r[1, 2], r[1, 1]), pitch, 0.0])


def turning(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking unit vector a onto unit vector b (a half turn about an axis normal to a when
    b = -a)."""
    a, b = np.asarray(a, float) / np.linalg.norm(a), np.asarray(b, float) / np.linalg.norm(b)
    axis = np.cross(a, b)
    s, c = np.linalg.norm(axis), float(a @ b)
    if s < 1e-15:
        if c > 0:
            return np.eye(3)
        normal = np.cross(a, np.eye(3)[int(np.argmin(np.abs(a)))])
        return exp_so3(np.pi * normal / np.linalg.norm(normal))
    return exp_so3(axis / s * np.arctan2(s, c))


def homogeneous(r: np.ndarray, t: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = r
    out[:3, 3] = t
    return out


def kabsch(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares rigid transform with dst ~ R src + t (Kabsch/Horn, SVD form).

    src, dst: (k, 3), k >= 3 non-collinear. Raises RigidError on degenerate input.
    """
    src = np.asarray(src, dtype=float)
    dst = np.asarray(dst, dtype=float)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3 or src.shape[0] < 3:
        raise RigidError("need at least 3 corresponding 3-D points")
    cs, cd = src.mean(axis=0), dst.mean(axis=0)
    h = (src - cs).T @ (dst - cd)
    u, s, vt = np.linalg.svd(h)
    if s[1] <= 1e-9 * max(s[0], 1e-300):
        raise RigidError("points are collinear: the rigid transform is not determined")
    d = np.sign(np.linalg.det(vt.T @ u.T))
    r = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return r, cd - r @ cs
