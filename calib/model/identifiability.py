"""Numerical check of a parameter set: full column rank with free stations and free tool points.

The identification Jacobian [d p / d params | station (translation, rotation) | tool points] over random
poses must have full column rank (every parameter identifiable), and adding back any eliminated
parameter must lose rank (the set is irreducible).
"""

from __future__ import annotations

import numpy as np

from trackcal.calib.model.chain import Chain
from trackcal.calib.model.kinematics import Kinematics
from trackcal.calib.model.params import Param
from trackcal.calib.model.rigid import skew


def identification_jacobian(
    chain: Chain, params: list[Param], q: np.ndarray, tool: np.ndarray, free_base: bool = True
) -> np.ndarray:
    """Stacked Jacobian for every pose in q (m, n) rad and every point in tool (P, 3), one station at the base."""
    kin = Kinematics(chain, params)
    blocks = []
    n_pt = len(tool)
    for i, pt in enumerate(tool):
        jac = kin.jacobian(q, pt)
        parts = [jac.d_params]
        if free_base:
            parts += [np.broadcast_to(np.eye(3), (len(q), 3, 3)), -skew(jac.p)]
        pts = np.zeros((len(q), 3, 3 * n_pt))
        pts[:, :, 3 * i : 3 * i + 3] = jac.d_point
        parts.append(pts)
        blocks.append(np.concatenate(parts, axis=2).reshape(3 * len(q), -1))
    return np.vstack(blocks)


def numerical_rank(j: np.ndarray, rtol: float = 1e-9) -> int:
    scale = np.linalg.norm(j, axis=0)
    scale[scale == 0] = 1.0
    s = np.linalg.svd(j / scale, compute_uv=False)
    return int(np.sum(s > rtol * s[0]))


def random_configuration(chain: Chain, m: int, rng: np.random.Generator) -> np.ndarray:
    lim = chain.limits_array()
    lim = np.where(np.isfinite(lim), lim, np.array([-np.pi, np.pi]))
    return rng.uniform(lim[:, 0], lim[:, 1], size=(m, chain.dof))
