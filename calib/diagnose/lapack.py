"""The LAPACK routines the diagnosis solves its folds with, called without holding the GIL.

scipy.linalg.lapack's f2py wrappers of these routines hold the GIL for the whole call (f2py's `threadsafe` is not
declared on them: scipy/scipy#12436), so the folds of a cross-validation solved in threads ran one after the other
wherever they reduced, factored or solved: the tridiagonal reduction of 650 columns ran at 0.93x on 2 threads
(issue 41). These are the same routines of the same library, scipy's (its Cython API, `scipy.linalg.cython_lapack`,
whose capsules hold their C addresses: numba's `get_cython_function_address` reads them so), called through
ctypes, which releases the GIL for the call of a foreign function (Python's ctypes documentation); 1.95x on 2
threads.

Each function here is the call the f2py wrapper made, argument for argument: its arrays copied to Fortran order as the
wrapper copied them, the same triangle and the same workspace, so the results are the wrapper's bit for bit (tests:
tests/calib/diagnose/test_lapack.py). An illegal argument (info < 0) raises numpy.linalg.LinAlgError.
"""

from __future__ import annotations

import ctypes

import numpy as np
import scipy.linalg.cython_lapack as _cython_lapack

_api = ctypes.pythonapi
_api.PyCapsule_GetName.restype = ctypes.c_char_p
_api.PyCapsule_GetName.argtypes = [ctypes.py_object]
_api.PyCapsule_GetPointer.restype = ctypes.c_void_p
_api.PyCapsule_GetPointer.argtypes = [ctypes.py_object, ctypes.c_char_p]
_P, _C = ctypes.c_void_p, ctypes.c_char_p


def _routine(name: str, *args) -> ctypes._CFuncPtr:
    """The routine `name` of scipy.linalg.cython_lapack as a ctypes function of argument types `args` (every
    argument by address, as LAPACK takes them; a routine returns nothing)."""
    capsule = _cython_lapack.__pyx_capi__[name]
    return ctypes.CFUNCTYPE(None, *args)(_api.PyCapsule_GetPointer(capsule, _api.PyCapsule_GetName(capsule)))


_dsytrd = _routine("dsytrd", _C, _P, _P, _P, _P, _P, _P, _P, _P, _P)
_dormqr = _routine("dormqr", _C, _C, _P, _P, _P, _P, _P, _P, _P, _P, _P, _P, _P)
_dgtsv = _routine("dgtsv", _P, _P, _P, _P, _P, _P, _P, _P)
_dpotrf = _routine("dpotrf", _C, _P, _P, _P, _P)
_dpotrs = _routine("dpotrs", _C, _P, _P, _P, _P, _P, _P, _P)
_dpotri = _routine("dpotri", _C, _P, _P, _P, _P)
_dtrtrs = _routine("dtrtrs", _C, _C, _C, _P, _P, _P, _P, _P, _P, _P)


def _ref(v: int):
    """An int passed by address, as LAPACK takes its scalars."""
    return ctypes.byref(ctypes.c_int(int(v)))


def _at(a: np.ndarray) -> ctypes.c_void_p:
    """The address of a's data: `a` must stay referenced (a name bound to it) until the call returns."""
    return ctypes.c_void_p(a.ctypes.data)


def _checked(name: str, info: ctypes.c_int) -> int:
    if info.value < 0:
        raise np.linalg.LinAlgError(f"LAPACK reported an illegal value in {-info.value}-th argument on entry to {name}")
    return info.value


def _fortran(a) -> np.ndarray:
    """A Fortran-ordered float64 copy of `a` (as f2py copies an argument it overwrites), a vector as one column."""
    a = np.asarray(a, dtype=float)
    return np.array(a.reshape(len(a), -1), order="F")


def dsytrd_lower(s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]:
    """(a, d, e, tau, info) of dsytrd of the lower triangle of s (p, p), its optimal workspace queried first: what
    `lapack.dsytrd(s, lower=1, lwork=lapack.dsytrd_lwork(p, lower=1))` returned."""
    a = _fortran(s)
    p = len(a)
    d, e, tau = np.empty(p), np.empty(max(p - 1, 0)), np.empty(max(p - 1, 0))
    work, info = np.empty(1), ctypes.c_int(0)
    args = (b"L", _ref(p), _at(a), _ref(max(p, 1)), _at(d), _at(e), _at(tau))
    _dsytrd(*args, _at(work), _ref(-1), ctypes.byref(info))
    _checked("DSYTRD", info)
    work = np.empty(max(int(work[0]), 1))
    _dsytrd(*args, _at(work), _ref(len(work)), ctypes.byref(info))
    return a, d, e, tau, _checked("DSYTRD", info)


def dormqr_left(trans: str, a: np.ndarray, tau: np.ndarray, c: np.ndarray, lwork: int) -> np.ndarray:
    """Q c (trans "N") or Q^T c (trans "T") by dormqr from the left, Q the product of the elementary reflectors of
    a (m, k) and tau (k,): what `lapack.dormqr("L", trans, a, tau, c, lwork)` returned as its first value."""
    a, out, tau = _fortran(a), _fortran(c), np.ascontiguousarray(tau, dtype=float)
    m = _ref(max(len(a), 1))
    work, info = np.empty(max(lwork, 1)), ctypes.c_int(0)
    _dormqr(
        b"L",
        trans.encode(),
        _ref(len(a)),
        _ref(out.shape[1]),
        _ref(len(tau)),
        _at(a),
        m,
        _at(tau),
        _at(out),
        m,
        _at(work),
        _ref(len(work)),
        ctypes.byref(info),
    )
    _checked("DORMQR", info)
    return out


def dgtsv(dl: np.ndarray, d: np.ndarray, du: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, int]:
    """(x, info): the solution of the tridiagonal system (sub-diagonal dl, diagonal d, super-diagonal du) for b (p,)
    by dgtsv (none of the arguments is overwritten)."""
    dl, d, du, x = (np.array(v, dtype=float) for v in (dl, d, du, b))
    info = ctypes.c_int(0)
    _dgtsv(_ref(len(d)), _ref(1), _at(dl), _at(d), _at(du), _at(x), _ref(max(len(d), 1)), ctypes.byref(info))
    return x, _checked("DGTSV", info)


def _overwritten(a: np.ndarray, name: str) -> np.ndarray:
    if not a.flags.f_contiguous or a.dtype != np.float64 or a.ndim != 2:
        raise np.linalg.LinAlgError(
            f"{name}: the array must be a Fortran-ordered float64 matrix (it is overwritten in place)"
        )
    return a


def dpotrf_in_place(a: np.ndarray, lower: bool) -> int:
    """info of dpotrf of `a` (p, p, Fortran-ordered, overwritten by the factor in the triangle `lower` selects, the
    other left as it was: f2py's `clean=0`); info > 0 when a is not positive definite."""
    a, info = _overwritten(a, "dpotrf_in_place"), ctypes.c_int(0)
    _dpotrf(b"L" if lower else b"U", _ref(len(a)), _at(a), _ref(max(len(a), 1)), ctypes.byref(info))
    return _checked("DPOTRF", info)


def dpotrs(c: np.ndarray, b: np.ndarray, lower: bool) -> tuple[np.ndarray, int]:
    """(x, info): (c c^T)^-1 b (lower) or (c^T c)^-1 b by dpotrs from the Cholesky factor in c (p, p, Fortran-ordered),
    b (p,) or (p, k), x shaped as b."""
    x, c = _fortran(b), np.asfortranarray(c, dtype=float)  # c held: its address is passed
    ld, info = _ref(max(len(c), 1)), ctypes.c_int(0)
    _dpotrs(b"L" if lower else b"U", _ref(len(c)), _ref(x.shape[1]), _at(c), ld, _at(x), ld, ctypes.byref(info))
    return x.reshape(np.shape(b)), _checked("DPOTRS", info)


def dpotri_in_place(c: np.ndarray, lower: bool) -> int:
    """info of dpotri: the inverse from the Cholesky factor in c (p, p, Fortran-ordered), written over it (its
    triangle `lower` selects)."""
    c, info = _overwritten(c, "dpotri_in_place"), ctypes.c_int(0)
    _dpotri(b"L" if lower else b"U", _ref(len(c)), _at(c), _ref(max(len(c), 1)), ctypes.byref(info))
    return _checked("DPOTRI", info)


def dtrtrs_lower(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, int]:
    """(x, info): a^-1 b by dtrtrs, a (p, p, Fortran-ordered) lower triangular with a non-unit diagonal, b (p, k)."""
    x, a = _fortran(b), np.asfortranarray(a, dtype=float)  # a held: its address is passed
    ld, info = _ref(max(len(a), 1)), ctypes.c_int(0)
    _dtrtrs(b"L", b"N", b"N", _ref(len(a)), _ref(x.shape[1]), _at(a), ld, _at(x), ld, ctypes.byref(info))
    return x, _checked("DTRTRS", info)
