"""calib.diagnose.lapack: each routine called through scipy's Cython LAPACK API without the GIL gives what
scipy.linalg.lapack's f2py wrapper of the same routine gave, bit for bit (the same library, the same arguments), and
its calls release the GIL (ctypes' foreign functions, not its Python-API ones)."""

import ctypes

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.linalg import cho_factor, cho_solve, lapack, solve_triangular

from trackcal.calib.diagnose import lapack as nogil

SIZES = st.integers(1, 80)
SEEDS = st.integers(0, 2**32 - 1)


def gram(p: int, seed: int, rank: float = 1.0) -> np.ndarray:
    """A Gram matrix of columns of different scales (a Jacobian's), rank deficient below `rank`, as the map's."""
    x = np.random.default_rng(seed).standard_normal((3 * p, p)) * np.geomspace(1.0, 1e3, p)
    x[:, max(1, int(rank * p)) :] = 0.0
    return x.T @ x


def same(a, b) -> bool:
    # NaN where the wrapper gave NaN (a factor with a pivot near the smallest normal number): the same bits
    return all(np.array_equal(np.asarray(x), np.asarray(y), equal_nan=True) for x, y in zip(a, b, strict=True))


@settings(deadline=None, max_examples=40)
@given(p=SIZES, rank=st.floats(0.2, 1.0), seed=SEEDS)
def test_dsytrd_is_the_wrappers(p, rank, seed):
    s = gram(p, seed, rank)
    lwork = int(lapack.dsytrd_lwork(p, lower=1)[0])
    assert same(nogil.dsytrd_lower(s), lapack.dsytrd(s, lower=1, lwork=max(lwork, 1)))


@settings(deadline=None, max_examples=40)
@given(p=st.integers(2, 80), k=st.integers(1, 17), trans=st.sampled_from("NT"), seed=SEEDS)
def test_dormqr_of_the_reduction_is_the_wrappers(p, k, trans, seed):
    # as calib.diagnose.ridge applies the reflectors of the lower-stored reduction: A(2:p, 1:p-1), C(2:p, :)
    a, _, _, tau, _ = nogil.dsytrd_lower(gram(p, seed))
    c = np.random.default_rng(seed + 1).standard_normal((p, k))
    lwork = 64 * k
    want = lapack.dormqr("L", trans, a[1:, :-1], tau, c[1:], lwork)[0]
    assert np.array_equal(nogil.dormqr_left(trans, a[1:, :-1], tau, c[1:], lwork), want, equal_nan=True)


@settings(deadline=None, max_examples=40)
@given(p=st.integers(2, 80), lam=st.floats(0.0, 1e3), seed=SEEDS)
def test_dgtsv_is_the_wrappers_and_leaves_its_arguments(p, lam, seed):
    rng = np.random.default_rng(seed)
    d, e, y = rng.uniform(1.0, 5.0, p), rng.standard_normal(p - 1), rng.standard_normal(p)
    before = (d.copy(), e.copy(), y.copy())
    x, info = nogil.dgtsv(e, d + lam, e, y)
    *_, want, want_info = lapack.dgtsv(e, d + lam, e, y)
    assert info == want_info and np.array_equal(x, want, equal_nan=True)
    assert same((d, e, y), before)


@settings(deadline=None, max_examples=40)
@given(p=SIZES, rank=st.floats(0.2, 1.0), ridge=st.floats(0.0, 1.0), seed=SEEDS)
def test_cholesky_solve_and_inverse_are_the_wrappers(p, rank, ridge, seed):
    # ridge.py's use: the C-ordered h overwritten through its Fortran view h.T, the upper triangle; not positive
    # definite (a rank-deficient Gram matrix without a ridge) gives the same info > 0
    h = gram(p, seed, rank) + ridge * np.eye(p)
    b = np.random.default_rng(seed + 1).standard_normal(p)
    ours, theirs = h.copy(), h.copy()
    info = nogil.dpotrf_in_place(ours.T, lower=False)
    c, want_info = lapack.dpotrf(theirs.T, lower=0, overwrite_a=1, clean=0)
    assert info == want_info and np.array_equal(ours.T, c, equal_nan=True)
    if info:
        return
    x, info = nogil.dpotrs(ours.T, b, lower=False)
    assert same((x, info), lapack.dpotrs(c, b, lower=0))
    assert nogil.dpotri_in_place(ours.T, lower=False) == 0
    assert np.array_equal(ours.T, lapack.dpotri(c, lower=0, overwrite_c=1)[0], equal_nan=True)


@settings(deadline=None, max_examples=40)
@given(p=SIZES, k=st.integers(1, 5), seed=SEEDS)
def test_the_lower_factor_its_solve_and_triangular_inverse_are_scipys(p, k, seed):
    # joint_map_fit.MapEvidence's use, formerly scipy.linalg.cho_factor(lower=True), cho_solve and solve_triangular
    h = gram(p, seed) + np.eye(p)
    b = np.random.default_rng(seed + 1).standard_normal((p, k))
    factor = np.array(h, order="F")  # a copy (asfortranarray would return a 1 x 1 h itself)
    assert nogil.dpotrf_in_place(factor, lower=True) == 0
    want = cho_factor(h, lower=True, check_finite=False)
    assert np.array_equal(factor, want[0], equal_nan=True)
    assert np.array_equal(
        nogil.dpotrs(factor, b, lower=True)[0], cho_solve(want, b, check_finite=False), equal_nan=True
    )
    inv = solve_triangular(want[0], np.eye(p), lower=True, check_finite=False)
    assert np.array_equal(nogil.dtrtrs_lower(factor, np.eye(p))[0], inv, equal_nan=True)


def test_in_place_routines_refuse_an_array_they_cannot_overwrite():
    with pytest.raises(np.linalg.LinAlgError, match="Fortran-ordered"):
        nogil.dpotrf_in_place(np.eye(3), lower=True)  # C-ordered: its Fortran view is its transpose
    with pytest.raises(np.linalg.LinAlgError, match="Fortran-ordered"):
        nogil.dpotri_in_place(np.ones((3, 3), dtype=np.float32, order="F"), lower=False)


def test_an_illegal_argument_is_an_error_not_a_result():
    # LAPACK's info < 0: here a leading dimension below the order (DGTSV's 7th argument, ldb = 0 < n)
    d, e, b, info = np.ones(3), np.zeros(2), np.ones(3), ctypes.c_int(0)
    at, ref = nogil._at, nogil._ref
    nogil._dgtsv(ref(3), ref(1), at(e), at(d), at(e), at(b), ref(0), ctypes.byref(info))
    with pytest.raises(np.linalg.LinAlgError, match="7-th argument on entry to DGTSV"):
        nogil._checked("DGTSV", info)


@pytest.mark.parametrize("name", ["_dsytrd", "_dormqr", "_dgtsv", "_dpotrf", "_dpotrs", "_dpotri", "_dtrtrs"])
def test_the_calls_release_the_gil(name):
    # ctypes releases the GIL around a call of a CFUNCTYPE function, not of a PYFUNCTYPE one (which keeps it for
    # functions of the Python C API): the flag is what makes the folds' factorisations run at once in threads
    assert not getattr(nogil, name)._flags_ & ctypes._FUNCFLAG_PYTHONAPI
