"""issue 41: diagnose's CPU on Series B within 10x one identify. Each change against the code it replaced, kept here
as a reference: the held-out comparison with the map and without it is one pass over the folds (each fold's Gram
downdate formed once), and a cross-validation without the map forms no Schur complement of its columns; the
candidates' fits carry their Gram matrix, warm-started fits form no Kabsch start, mid-ranks take one pass and a map's
coefficient names are parsed once."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.helpers import DenseRows, backlash_twin_case
from trackcal.calib.diagnose import crossval, fits
from trackcal.calib.diagnose.joint_map import Arc, harmonic_names, harmonics_by_joint, parse_name
from trackcal.calib.diagnose.joint_map_fit import FoldParts, _cv_scores
from trackcal.calib.diagnose.significance import _midranks
from trackcal.calib.identify import solver
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.identify.solver import IdentificationError, Problem, _init_stations, identify
from trackcal.calib.model.cell import load_cell
from trackcal.calib.model.kinematics import Kinematics

CELL = load_cell("kr270")


def drawn(seed: int, n_rows: int, n_free: int, n_pen: int):
    """A linearised problem (jm, r, Gram matrix, J^T r) of n_rows rows (3 coordinates each) and its folds: a partition
    of the rows into 4 and two edge folds (overlapping it), as held_out_errors receives them."""
    rng = np.random.default_rng(seed)
    jm = rng.standard_normal((3 * n_rows, n_free + n_pen)) * np.geomspace(1.0, 1e2, n_free + n_pen)
    r = rng.standard_normal(3 * n_rows)
    part = np.arange(n_rows) % 4
    groups = [np.flatnonzero(part[rng.permutation(n_rows)] == k) for k in range(4)]
    groups += [np.arange(n_rows // 5), np.arange(n_rows - n_rows // 5, n_rows)]
    return jm, r, jm.T @ jm, jm.T @ r, n_free + np.arange(n_pen), groups


def without_map_reference(jm, r, gram, rhs, pen, groups):
    """Before issue 41: every fold's held-out squared error of the model without the map's columns, the Schur
    complement of all of them formed (and not read) as _cv_scores did."""
    free = np.setdiff1d(np.arange(jm.shape[1]), pen)
    sq, count, n_rows = np.zeros(len(r) // 3), np.zeros(len(r) // 3, dtype=int), len(r) // 3
    total = 0.0
    for rows in groups:
        hold = np.zeros(n_rows, dtype=bool)
        hold[rows] = True
        hold = np.repeat(hold, 3)
        jk, rk = jm[hold], r[hold]
        g, b = gram - jk.T @ jk, rhs - jk.T @ rk
        gaa = g[np.ix_(free, free)]
        sa = np.sqrt(np.diag(gaa))
        sa[sa == 0] = 1.0
        gaa_inv = np.linalg.pinv(gaa / np.outer(sa, sa), rcond=1e-12) / np.outer(sa, sa)
        a = gaa_inv @ b[free][:, None]
        e = rk[:, None] - jk[:, free] @ a
        total += float(np.sum(e**2))
        np.add.at(sq, np.sort(rows), np.sum(e[:, 0].reshape(-1, 3) ** 2, axis=1))
        np.add.at(count, rows, 1)
    return total, sq, count


@settings(deadline=None, max_examples=25)
@given(seed=st.integers(0, 2**32 - 1), n_rows=st.integers(20, 60), n_free=st.integers(1, 8), n_pen=st.integers(1, 12))
def test_with_and_without_the_map_in_one_pass_give_the_same_errors(seed, n_rows, n_free, n_pen):
    jm, r, gram, rhs, pen, groups = drawn(seed, n_rows, n_free, n_pen)
    cols = pen[: max(1, n_pen // 2)]
    rows = DenseRows(jm, r, pen)
    free = np.setdiff1d(np.arange(jm.shape[1]), pen)
    args = (FoldParts(rows, free), n_rows, gram, rhs, None, pen, groups)
    *_, sq, count = _cv_scores(*args, [cols, pen[:0]], [0.5], rows, None, per_row=True)
    # with the map: its own pass (each fold's part formed again, or kept by the FoldParts of the pass above), bit for
    # bit
    for parts in (FoldParts(rows, free), args[0]):
        alone = _cv_scores(parts, *args[1:], [cols], [0.5], rows, None, per_row=True)
        assert np.array_equal(alone[2][:, 0], sq[:, 0]) and np.array_equal(alone[3], count)
    # without it: the reference, the Schur complement of the map's columns formed as before
    total, ref_sq, ref_count = without_map_reference(jm, r, gram, rhs, pen, groups)
    assert np.array_equal(sq[:, 1], ref_sq) and np.array_equal(count, ref_count)
    alone = _cv_scores(*args, [pen[:0]], [1.0], None, None)
    assert np.isclose(alone[0][0, 0], total, rtol=1e-12, atol=0)  # the folds summed in another order here


def midranks_reference(x: np.ndarray) -> np.ndarray:
    """Before issue 41: the ranks of the values equal to each distinct one averaged, one pass over x per value."""
    order = np.argsort(x, kind="stable")
    ranks = np.empty(len(x))
    ranks[order] = np.arange(1, len(x) + 1)
    for v in np.unique(x):
        at = x == v
        if np.count_nonzero(at) > 1:
            ranks[at] = ranks[at].mean()
    return ranks


@settings(deadline=None, max_examples=60)
@given(
    values=st.lists(st.integers(0, 12), min_size=1, max_size=80),
    scale=st.floats(1e-9, 1e3),
)
def test_midranks_equal_the_pass_per_distinct_value(values, scale):
    # few distinct values among many: runs of ties of every length, at the start, the end and between
    x = np.asarray(values, dtype=float) * scale
    assert np.array_equal(_midranks(x), midranks_reference(x))


@pytest.fixture(scope="module")
def twin_case():
    return backlash_twin_case(CELL)


def test_a_fit_carries_its_gram_matrix_and_cross_validates_as_before(twin_case):
    """The whole-table fit's J^T J is formed once (its identifiability check, from the normal equations summed over
    row chunks) and read by every cross-validation of it: J^T J of the whole Jacobian formed at the solution to
    rounding, and the held-out errors those of that Gram matrix formed again (before)."""
    table, params, geo = twin_case
    ctx = fits.context(CELL.chain, table, params, TrackerNoise(), geo, ("backlash",))
    fit = fits.whole_fit(ctx, ("backlash",))
    jm = fit.problem.residual_and_jacobian(fit.state)[1]
    dense = jm.T @ jm
    # sums of the same products in another order: rounding of float64 (eps 2.2e-16) times the terms' count, 3N
    assert np.abs(fit.gram - dense).max() <= 3 * len(table) * 2.2e-16 * np.abs(dense).max()
    folds = crossval.fold_rows(table, "pose", 5, 0) + crossval.edge_rows(table)
    now = crossval.cross_validate(ctx, ("backlash",), folds)
    fit.gram = dense  # formed again from the whole Jacobian, as cross_validate did
    before = crossval.cross_validate(ctx, ("backlash",), folds)
    # the Gram matrix's rounding (~1e-13) through a solve of a column-scaled condition number of thousands at most
    # (calib.identify.solver.solve's note)
    np.testing.assert_allclose(now.sq, before.sq, rtol=1e-9)
    assert np.array_equal(now.count, before.count)


def test_the_kabsch_start_is_formed_only_when_asked_for(twin_case, monkeypatch):
    """Problem.initial: the same start as before (the stations' Kabsch fits on the nominal robot) when asked for, and
    a caller that assigns its own start (a diagnosis's warm-started fits) never forms it."""
    table, params, geo = twin_case
    problem = Problem(CELL.chain, table, CELL.tool_points, params, TrackerNoise())
    first, row_pose = problem.rows.poses
    ref = _init_stations(
        Kinematics(CELL.chain, []),
        (problem.q[first], row_pose),
        problem.rows.points[problem.pt_idx],
        problem.xyz,
        problem.st_idx,
        problem.station_ids,
        table.source,
    )
    assert all(
        np.array_equal(a.rotation, b.rotation) and np.array_equal(a.translation, b.translation)
        for a, b in zip(problem.initial.stations, ref, strict=True)
    )
    ctx = fits.context(CELL.chain, table, params, TrackerNoise(), geo, ())
    calls = []
    monkeypatch.setattr(solver, "_init_stations", lambda *args: calls.append(args) or ref)
    fits._whole_fit(ctx, table, None, 100)
    assert calls == []
    assert Problem(CELL.chain, table, CELL.tool_points, params, TrackerNoise()).initial.stations == ref
    assert len(calls) == 1


def test_a_station_too_few_rows_to_place_still_fails_identify(twin_case):
    # the Kabsch start's errors come from identify as before (a station of 2 rows: at least 3 are needed)
    table, params, _ = twin_case
    two = table.subset(np.arange(len(table)))
    two.station = [s + "-b" if i < 2 else s for i, s in enumerate(table.station)]
    with pytest.raises(IdentificationError, match="has 2 measurement"):
        identify(CELL.chain, two, CELL.tool_points, params, noise=TrackerNoise())


def harmonics_reference(q, names, arcs):
    """Before issue 41: the names parsed and grouped on every call (joint_map.harmonics_by_joint's loop)."""
    clamped = {j: arc.clamp(q[:, j])[0] for j, arc in arcs.items()}
    groups = {}
    for i, name in enumerate(names):
        kind, h, j = parse_name(name)
        cols, hs = groups.setdefault((kind, j), ([], []))
        cols.append(i)
        hs.append(h)
    for (kind, j), (cols, hs) in groups.items():
        yield j, cols, (np.sin if kind == "s" else np.cos)(np.array(hs, dtype=float) * clamped[j][:, None])


@settings(deadline=None, max_examples=30)
@given(seed=st.integers(0, 2**32 - 1), order=st.integers(1, 12), share=st.floats(0.1, 1.0))
def test_harmonics_from_names_parsed_once_equal_those_parsed_each_call(seed, order, share):
    # a subset of a map's coefficients in a drawn order, on angles partly outside the arcs: the same groups, columns
    # and values, bit for bit, on the first call and on the next (the parse cached)
    rng = np.random.default_rng(seed)
    names = [nm for j in range(4) for nm in harmonic_names(j, order)]
    names = [names[i] for i in rng.permutation(len(names))[: max(1, int(share * len(names)))]]
    q = rng.uniform(-3.0, 3.0, (40, 4))
    arcs = {j: Arc.covering(q[:20, j]) for j in range(4)}
    ref = list(harmonics_reference(q, names, arcs))
    for _ in range(2):
        got = list(harmonics_by_joint(q, names, arcs))
        every = np.arange(len(names))  # the columns given as a slice when evenly spaced
        assert [(j, every[cols].tolist()) for j, cols, _ in got] == [(j, cols) for j, cols, _ in ref]
        assert all(np.array_equal(a, b) for (_, _, a), (_, _, b) in zip(got, ref, strict=True))
