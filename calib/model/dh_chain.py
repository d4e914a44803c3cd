"""Standard Denavit-Hartenberg tables as trackcal Chain objects and back (the robot YAML's `dh` block is read by
calib.model.dh; this module builds a Chain from the numbers a controller reports, such as its factory DH).

Link i of a standard DH table is Rz(theta_i + q_i) Tz(d_i) Tx(a_i) Rx(alpha_i) (Denavit and Hartenberg 1955; the
convention of robot makers' published tables and of the calibrated DH some controllers keep). A chain joint turns
about z of its frame by q_i, then its link translation and fixed rotation lead to the next joint's frame
(calib.model.chain), so the fixed part of link i is Rz(theta_i) Tz(d_i) Tx(a_i) Rx(alpha_i): translation
Rz(theta_i) (a_i, 0, d_i), rotation Rz(theta_i) Rx(alpha_i). The frame after the last link is the flange.

Nominal tables (alpha and theta offsets in whole quarter turns) give axis-aligned chains; a calibrated table (small
theta and alpha deviations) gives a chain with tilted axes, exact for forward kinematics, whose complete and
irreducible parameters calib.model.params generates too (any joint axes): the factory's calibration is the nominal
as it stands, nothing of it rounded away.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from trackcal.calib.model.chain import Chain, ChainError, Joint
from trackcal.calib.model.rigid import rot_axis


def dh_chain(
    theta_rad: Sequence[float],
    a_mm: Sequence[float],
    d_mm: Sequence[float],
    alpha_rad: Sequence[float],
    name: str = "dh",
    template: Chain | None = None,
) -> Chain:
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
        joints.append(
            Joint(
                name=base.name if base else f"J{i + 1}",
                axis=2,
                sign=1.0,
                translation=rz @ np.array([a, 0.0, d]),
                rotation=rz @ rot_axis(0, al),
                limits=base.limits if base else None,
                mass_kg=base.mass_kg if base else 0.0,
                com=base.com if base else np.zeros(3),
            )
        )
    base_tf = template.base if template is not None else np.eye(4)
    return Chain(name=name, base=base_tf, joints=tuple(joints))


def dh_of_chain(chain: Chain) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(theta, a_mm, d_mm, alpha) of a chain whose links are standard DH links with zero theta offsets (every joint
    about +z, link translation (a, 0, d), fixed rotation Rx(alpha)): the inverse of dh_chain for such chains.
    ChainError for a chain of another form."""
    a, d, alpha = [], [], []
    for j in chain.joints:
        t, r = j.translation, j.rotation
        al = float(np.arctan2(r[2, 1], r[1, 1]))
        if j.axis != 2 or j.sign < 0 or abs(t[1]) > 1e-9 or np.abs(r - rot_axis(0, al)).max() > 1e-12:
            raise ChainError(
                f"{chain.name}: joint {j.name} is not a standard DH link (z axis, translation (a, 0, d), "
                "rotation about x)"
            )
        a.append(float(t[0]))
        d.append(float(t[2]))
        alpha.append(al)
    return np.zeros(chain.dof), np.array(a), np.array(d), np.array(alpha)
