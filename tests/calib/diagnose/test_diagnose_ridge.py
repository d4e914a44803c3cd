"""calib.diagnose.ridge: every ridge of a path from one tridiagonal reduction equals the direct solve."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from trackcal.calib.diagnose import ridge
from trackcal.calib.diagnose.ridge import _eigen_path as eigen_path
from trackcal.calib.diagnose.ridge import ridge_path


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
