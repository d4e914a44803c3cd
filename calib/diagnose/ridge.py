"""Ridge paths: (S + lam I)^-1 b for every lam of a list, S symmetric positive semi-definite, for about the cost of one
factorisation of S.

S = Q T Q^T with T tridiagonal (LAPACK dsytrd, Householder reflectors Q), so that

    (S + lam I)^-1 b = Q (T + lam I)^-1 Q^T b,

and each lam costs one tridiagonal solve (dgtsv, O(p)) between two applications of the reflectors (dormqr, O(p^2)).
The eigendecomposition S = V diag(mu) V^T gives the same, but its eigenvectors cost about twice the reduction to
T (measured on 640 columns: 30 ms against 69 ms for the whole path of 17 ridges; issue 26). Golub & Van Loan,
Matrix Computations (4th ed.), 8.3.1 (Householder tridiagonalisation); LAPACK's dormtr applies the reflectors of a
lower-stored reduction as dormqr on A(2:p, 1:p-1) and C(2:p, :), which is what `_apply_q` does.

Should T + lam I be singular for some lam (S singular and lam = 0, or rounding below -lam in a direction of S
with no information), the path falls back to the eigendecomposition with S's eigenvalues clipped at 0, as before.

One ridge (a scalar, or one per column: `ridge_solve`, `ridge_inverse`): S + diag(lam) is positive definite by
construction, and a Cholesky factor costs half the flops of LU (issue 41: the single-ridge solves of ~650 columns
of the map's held-out test, 6 ms each by LU); LU, as before, when rounding leaves it not positive definite.
"""

from __future__ import annotations

import numpy as np

from trackcal.calib.diagnose.lapack import dgtsv, dormqr_left, dpotrf_in_place, dpotri_in_place, dpotrs, dsytrd_lower


def _apply_q(a: np.ndarray, tau: np.ndarray, c: np.ndarray, trans: str) -> np.ndarray:
    """Q c (trans "N") or Q^T c (trans "T"), Q from dsytrd(lower=1)'s a and tau; c (p, k)."""
    out = c.copy()
    if len(c) > 1:
        out[1:] = dormqr_left(trans, a[1:, :-1], tau, c[1:], 64 * max(c.shape[1], 1))
    return out


def _ridged(s: np.ndarray, lam) -> np.ndarray:
    """A copy of s with lam (a scalar or (p,)) added to its diagonal."""
    h = s.copy()
    h.flat[:: len(h) + 1] += lam
    return h


def _factor(h: np.ndarray) -> tuple[np.ndarray, int]:
    """(the upper Cholesky factor of h^T, h (p, p) C-ordered and overwritten: h^T is its Fortran-ordered view, LAPACK
    factors it in place; info > 0 when h is not positive definite)."""
    return h.T, dpotrf_in_place(h.T, lower=False)


def ridge_solve(s: np.ndarray, b: np.ndarray, lam) -> np.ndarray:
    """(s + diag(lam))^-1 b: s (p, p) symmetric positive semi-definite (a Gram matrix or a Schur complement of one),
    lam >= 0 a scalar or (p,), b (p,) or (p, k). By Cholesky; by LU (`np.linalg.solve`, raising LinAlgError when
    singular) when s + diag(lam) is not positive definite."""
    if len(s) == 0:
        return np.zeros(np.shape(b))
    c, info = _factor(_ridged(s, lam))
    if info != 0:
        return np.linalg.solve(_ridged(s, lam), b)
    return dpotrs(c, b, lower=False)[0]


def ridge_inverse(s: np.ndarray, lam) -> np.ndarray:
    """(s + diag(lam))^-1, symmetric: s and lam as `ridge_solve`'s. By Cholesky (dpotrf and dpotri: half the flops of
    LU's inverse); by `np.linalg.inv` when s + diag(lam) is not positive definite."""
    c, info = _factor(_ridged(s, lam))
    if info == 0:
        info = dpotri_in_place(c, lower=False)
    if info != 0:
        return np.linalg.inv(_ridged(s, lam))
    return np.triu(c) + np.triu(c, 1).T  # dpotri leaves the upper triangle


def _eigen_path(s: np.ndarray, b: np.ndarray, lams: np.ndarray) -> np.ndarray:
    mu, v = np.linalg.eigh(0.5 * (s + s.T))
    return v @ ((v.T @ b)[:, None] / (np.maximum(mu, 0.0)[:, None] + lams[None]))


def ridge_path(s: np.ndarray, b: np.ndarray, lams) -> np.ndarray:
    """(p, len(lams)): column i is (s + lams[i] I)^-1 b; s (p, p) symmetric (its lower triangle is read), b (p,)."""
    lams = np.asarray(lams, dtype=float)
    p = len(s)
    if p == 0:
        return np.zeros((0, len(lams)))
    a, d, e, tau, info = dsytrd_lower(s)
    if info != 0:
        return _eigen_path(s, b, lams)
    y = _apply_q(a, tau, np.asarray(b, dtype=float)[:, None], "T")[:, 0]
    if p == 1:  # T is its diagonal (dgtsv wants a sub-diagonal)
        with np.errstate(divide="ignore"):
            return y[:, None] / (np.maximum(d[:, None], 0.0) + lams[None])
    x = np.empty((p, len(lams)))
    for i, lam in enumerate(lams):
        xi, info = dgtsv(e, d + lam, e, y)
        if info != 0:
            return _eigen_path(s, b, lams)
        x[:, i] = xi
    return _apply_q(a, tau, x, "N")
