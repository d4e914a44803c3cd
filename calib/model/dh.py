"""Standard Denavit-Hartenberg tables as trackcal chains.

Link i of a standard DH table is Rz(theta_i + q_i) Tz(d_i) Tx(a_i) Rx(alpha_i) (Denavit and Hartenberg 1955; the
convention of Universal Robots' published tables and of the calibrated DH a UR controller keeps). A chain joint turns
about z of its frame by q_i, then its link translation and fixed rotation lead to the next joint's frame
(calib.model.chain), so the fixed part of link i is Rz(theta_i) Tz(d_i) Tx(a_i) Rx(alpha_i): translation
Rz(theta_i) (a_i, 0, d_i), rotation Rz(theta_i) Rx(alpha_i). The frame after the last link is the flange.

Nominal tables (alpha and theta offsets in whole quarter turns) give axis-aligned chains, which the parameter
generation of calib.model.params requires; a calibrated table (small theta and alpha deviations) gives a chain with
tilted axes, exact for forward kinematics (predict, compare) but refused there.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from trackcal.calib.model.chain import Chain, ChainError, Joint
from trackcal.calib.model.rigid import rot_axis


def dh_chain(theta_rad: Sequence[float], a_mm: Sequence[float], d_mm: Sequence[float], alpha_rad: Sequence[float],
             name: str = "dh", template: Chain | None = None) -> Chain:  # fmt: skip
    """The chain of a standard DH table (mm, rad). `template`: a chain of the same number of joints whose joint
    names, limits and masses are kept (its centres of mass are taken as given in the frames after the rotations)."""
    rows = [np.asarray(v, dtype=float) for v in (theta_rad, a_mm, d_mm, alpha_rad)]
    n = len(rows[0])
    if n == 0 or any(r.shape != (n,) for r in rows) or not all(np.all(np.isfinite(r)) for r in rows):
        raise ChainError(f"{name}: a DH table needs theta, a, d and alpha of the same length, finite numbers")
    if template is not None and template.dof != n:
        raise ChainError(f"{name}: the DH table has {n} joints, the template {template.name} {template.dof}")
    joints = []
    for i, (th, a, d, al) in enumerate(zip(*rows, strict=True)):
        rz = rot_axis(2, th)
        base = template.joints[i] if template is not None else None
        joints.append(Joint(name=base.name if base else f"J{i + 1}", axis=2, sign=1.0,
                            translation=rz @ np.array([a, 0.0, d]), rotation=rz @ rot_axis(0, al),
                            limits=base.limits if base else None, mass_kg=base.mass_kg if base else 0.0,
                            com=base.com if base else np.zeros(3)))  # fmt: skip
    base_tf = template.base if template is not None else np.eye(4)
    return Chain(name=name, base=base_tf, joints=tuple(joints))
