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


# A joint whose values in a table spread less than this never moved: ten steps of the controller's 4 decimals of a
# degree (KR C2 EKI/RSI; calib.model.cell.CONTROLLER_STEP_DEG), so a joint that only jitters by rounding counts.
STILL_SPREAD_DEG = 1e-3
MAX_RANK_POSES = 200  # distinct poses enough to see a rank; more only cost time


def still_joints(q_deg: np.ndarray) -> list[int]:
    """The joints (0-based) that never move in a table's joint values q_deg (N, n)."""
    q_deg = np.atleast_2d(q_deg)
    return [j for j in range(q_deg.shape[1]) if np.ptp(q_deg[:, j]) < STILL_SPREAD_DEG]


def unidentifiable_params(
    chain: Chain, params: list[Param], q: np.ndarray, tool: np.ndarray, still: list[int]
) -> list[Param]:
    """The parameters a table whose joints `still` never move cannot identify, taken from those joints' offsets and
    the links on either side (a joint that never moves makes its two links one rigid body: its offset and part of
    their parameters describe the same thing). Greedy: dq_j first, then link j, then link j-1, each dropped while the
    identification Jacobian at the table's poses q (M, n) rad, with station and tool-point columns, does not have
    full column rank."""
    if not still:
        return []
    q = np.unique(np.atleast_2d(q), axis=0)[:MAX_RANK_POSES]
    order = []
    for j in still:
        order += [p for p in params if p.kind == "dq" and p.joint == j]
        order += [p for p in params if p.kind != "dq" and p.joint == j]
        order += [p for p in params if p.kind != "dq" and p.joint == j - 1]
    kept = list(params)
    dropped: list[Param] = []

    def full(ps: list[Param]) -> bool:
        j = identification_jacobian(chain, ps, q, tool)
        return numerical_rank(j) == numerical_rank(identification_jacobian(chain, [], q, tool)) + len(ps)

    for p in dict.fromkeys(order):
        if full(kept):
            break
        without = [x for x in kept if x != p]
        if numerical_rank(identification_jacobian(chain, without, q, tool)) == numerical_rank(
            identification_jacobian(chain, kept, q, tool)
        ):
            kept, dropped = without, dropped + [p]
    return dropped
