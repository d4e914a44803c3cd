"""A chain back to the YAML schema of configs/robots (for model.json and URDF sources)."""

from __future__ import annotations

import numpy as np

from .chain import Chain
from .rigid import AXIS_NAME


def _rpy_deg(r: np.ndarray) -> list[float]:
    """URDF rpy (R = Rz(y) Ry(p) Rx(r)) of a rotation matrix, deg."""
    pitch = np.arcsin(np.clip(-r[2, 0], -1.0, 1.0))
    if abs(np.cos(pitch)) > 1e-9:
        roll, yaw = np.arctan2(r[2, 1], r[2, 2]), np.arctan2(r[1, 0], r[0, 0])
    else:
        roll, yaw = np.arctan2(-r[1, 2], r[1, 1]), 0.0
    return [float(np.degrees(v)) for v in (roll, pitch, yaw)]


def chain_to_dict(chain: Chain) -> dict:
    joints = []
    for jt in chain.joints:
        jd = {
            "name": jt.name,
            "axis": ("-" if jt.sign < 0 else "") + AXIS_NAME[jt.axis],
            "link_mm": [float(v) for v in jt.translation],
        }
        if not np.allclose(jt.rotation, np.eye(3)):
            jd["link_rpy_deg"] = _rpy_deg(jt.rotation)
        if jt.limits is not None:
            jd["limits_deg"] = [float(np.degrees(v)) for v in jt.limits]
        if jt.mass_kg:
            jd["mass_kg"] = jt.mass_kg
            jd["com_mm"] = [float(v) for v in jt.com]
        joints.append(jd)
    return {
        "name": chain.name,
        "base": {"translation_mm": [float(v) for v in chain.base[:3, 3]], "rpy_deg": _rpy_deg(chain.base[:3, :3])},
        "joints": joints,
    }
