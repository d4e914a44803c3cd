"""Joint angles that put tool points where they are wanted: Gauss-Newton on rigidly attached points.

Three non-collinear points of the tool fix position and orientation (9 equations for n joints). The joint Jacobian
of `calib.model.kinematics` is analytic, so the iteration converges quadratically near a solution; `pinv` with a
small rcond takes the least-squares step where the chain has fewer than 6 joints or is near a singularity. Used by
compensation (the identified model reaching the nominal pose) and by the ISO 9283 plan (the nominal model reaching
the cube's poses).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from trackcal.calib.model.kinematics import Kinematics

# (q (N, n)) -> (q_true (N, n), dq_true/dq (N, n, n)): the joints the chain turns to when commanded q (an extension's
# joint errors); None for a purely geometric model
TrueJoints = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]


def reach_points(
    kin: Kinematics,
    tools: np.ndarray,
    target: np.ndarray,
    q_start: np.ndarray,
    dev: np.ndarray | None = None,
    true_joints: TrueJoints | None = None,
    tol_mm: float = 1e-10,
    max_iter: int = 20,
    skip: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Commanded joints (N, n) rad with which the model puts the k tool points `tools` (k, 3; last joint frame) at
    `target` (N, k, 3), from `q_start` (N, n). Returns (q, iterations (N,), converged (N,) bool); a row that did not
    converge or diverged to non-finite angles keeps q_start. Rows in `skip` are not iterated (converged False)."""
    q0 = np.atleast_2d(np.asarray(q_start, dtype=float))
    n_rows, n = q0.shape
    k = len(tools)
    q = q0.copy()
    iterations = np.zeros(n_rows, dtype=int)
    converged = np.zeros(n_rows, dtype=bool)
    done = np.zeros(n_rows, dtype=bool) if skip is None else np.asarray(skip, dtype=bool).copy()
    for it in range(max_iter + 1):
        active = np.flatnonzero(~done)
        if len(active) == 0:
            break
        if true_joints is None:
            qt, dqt = q[active], np.broadcast_to(np.eye(n), (len(active), n, n))
        else:
            qt, dqt = true_joints(q[active])
        jac = kin.jacobian(np.repeat(qt, k, axis=0), np.tile(tools, (len(active), 1)), dev)
        err = target[active] - jac.p.reshape(len(active), k, 3)
        ok = np.linalg.norm(err, axis=2).max(axis=1) <= tol_mm
        done[active[ok]] = converged[active[ok]] = True
        iterations[active[ok]] = it
        if ok.all() or it == max_iter:
            break
        keep = ~ok
        jq = np.einsum("nij,njk->nik", jac.d_q.reshape(len(active), 3 * k, n), dqt)[keep]
        step = np.einsum("nji,ni->nj", np.linalg.pinv(jq, rcond=1e-12), err[keep].reshape(-1, 3 * k))
        q[active[keep]] += step
        gone = active[keep][~np.all(np.isfinite(q[active[keep]]), axis=1)]
        q[gone], done[gone] = q0[gone], True
    q[~converged] = q0[~converged]
    return q, iterations, converged
