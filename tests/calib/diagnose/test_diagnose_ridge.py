"""calib.diagnose.ridge: every ridge of a path from one tridiagonal reduction equals the direct solve; one ridge's
solve and inverse by Cholesky equal LU's, and fall back to LU where the matrix is not positive definite."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from trackcal.calib.diagnose import ridge
from trackcal.calib.diagnose.ridge import _eigen_path as eigen_path
from trackcal.calib.diagnose.ridge import ridge_inverse, ridge_path, ridge_solve


def direct(s, b, lams):
    return np.stack([np.linalg.solve(s + lam * np.eye(len(s)), b) for lam in lams], axis=1)


@settings(deadline=None, max_examples=40)
@given(p=st.integers(1, 40), rank=st.floats(0.2, 1.0), seed=st.integers(0, 2**32 - 1))
def test_ridge_path_equals_one_solve_per_ridge(p, rank, seed):
    rng = np.random.default_rng(seed)
    x = rng.standard_normal((3 * p, p)) * np.geomspace(1.0, 1e3, p)  # columns of different scales, as Jacobians
    x[:, max(1, int(rank * p)) :] = 0.0  # and possibly rank deficient: the ridge alone holds those directions
    s, b = x.T @ x, x.T @ rng.standard_normal(3 * p)
    lams = np.geomspace(1e-3, 1e3, 7) * np.trace(s) / p
    ref = direct(s, b, lams)
    assert np.allclose(ridge_path(s, b, lams), ref, rtol=1e-9, atol=1e-11 * np.abs(ref).max())


def test_a_singular_system_falls_back_to_the_clipped_eigendecomposition(monkeypatch):
    # an eigenvalue of -lam (rounding below zero in a direction the data do not hold): T + lam I is exactly singular
    # (dgtsv refuses it), and the path is the eigendecomposition's with the eigenvalues clipped at 0, as before
    # issue 26
    calls = []
    monkeypatch.setattr(ridge, "_eigen_path", lambda *a: calls.append(1) or eigen_path(*a))
    path = ridge.ridge_path(np.diag([4.0, -1.0, 1.0]), np.array([4.0, 3.0, 1.0]), [1.0, 2.0])
    assert calls == [1]
    assert np.allclose(path, [[4 / 5, 4 / 6], [3 / 1, 3 / 2], [1 / 2, 1 / 3]])


def test_an_empty_path():
    assert ridge_path(np.zeros((0, 0)), np.zeros(0), [1.0, 2.0]).shape == (0, 2)


@pytest.mark.parametrize("p", [2, 64, 300])
def test_sizes_of_the_map_search(p):
    rng = np.random.default_rng(p)
    x = rng.standard_normal((2 * p, p))
    s, b, lams = x.T @ x, rng.standard_normal(p), np.geomspace(1e-2, 1e2, 17)
    ref = direct(s, b, lams)
    assert np.allclose(ridge_path(s, b, lams), ref, rtol=1e-10, atol=1e-12 * np.abs(ref).max())


@settings(deadline=None, max_examples=40)
@given(p=st.integers(1, 40), rank=st.floats(0.2, 1.0), per_column=st.booleans(), seed=st.integers(0, 2**32 - 1))
def test_one_ridge_by_cholesky_equals_lu(p, rank, per_column, seed):
    # the penalised normal equations of the map (`joint_map_fit`): a Gram matrix of columns of different scales,
    # possibly rank deficient, with a ridge on every column or on some (the map's) only, the others' block of full rank
    rng = np.random.default_rng(seed)
    x = rng.standard_normal((3 * p, p)) * np.geomspace(1.0, 1e3, p)
    k = max(1, int(rank * p))
    x[:, k:] = 0.0
    s, b = x.T @ x, x.T @ rng.standard_normal((3 * p, 2))
    lam = np.trace(s) / p * (np.where(np.arange(p) < k // 2, 0.0, 0.1) if per_column else 0.1)
    h = s + np.diag(np.broadcast_to(lam, p))
    ref, ref_inv = np.linalg.solve(h, b), np.linalg.inv(h)
    # the relative accuracy of either is cond(h) eps (Golub & Van Loan 3.3.2)
    tol = np.linalg.cond(h) * 1e-14
    assert np.allclose(ridge_solve(s, b, lam), ref, rtol=tol, atol=tol * np.abs(ref).max())
    assert np.allclose(ridge_solve(s, b[:, 0], lam), ref[:, 0], rtol=tol, atol=tol * np.abs(ref).max())
    inv = ridge_inverse(s, lam)
    assert np.array_equal(inv, inv.T)
    assert np.allclose(inv, ref_inv, rtol=tol, atol=tol * np.abs(ref_inv).max())


def test_one_ridge_not_positive_definite_is_solved_by_lu():
    # rounding below -lam in a direction the data do not hold: Cholesky refuses, LU solves it as before issue 41
    s, b = np.diag([4.0, -2.0, 1.0]), np.array([4.0, 3.0, 1.0])
    assert np.array_equal(ridge_solve(s, b, 1.0), np.linalg.solve(s + np.eye(3), b))
    assert np.array_equal(ridge_inverse(s, 1.0), np.linalg.inv(s + np.eye(3)))
    with pytest.raises(np.linalg.LinAlgError):  # singular: LU raises, as it did
        ridge_solve(np.diag([4.0, -1.0, 1.0]), b, 1.0)
    with pytest.raises(np.linalg.LinAlgError):
        ridge_inverse(np.diag([4.0, -1.0, 1.0]), 1.0)


def test_one_ridge_of_an_empty_system():
    assert ridge_solve(np.zeros((0, 0)), np.zeros(0), 1.0).shape == (0,)
