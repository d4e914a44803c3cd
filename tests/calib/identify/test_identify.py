"""Identification: exact recovery, invariances, honest confidence intervals, clear errors."""

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from tests.helpers import kr270_campaign, truth_of
from trackcal.calib.diagnose.extensions import build_extension
from trackcal.calib.diagnose.joint_map import Arc, harmonic_names, map_extension
from trackcal.calib.doe.poses import random_poses
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.identify.solver import IdentificationError, Problem, identify, residual_stats, significance, solve
from trackcal.calib.io.files import write_json
from trackcal.calib.model.extension import combine
from trackcal.calib.model.params import complete_params
from trackcal.calib.model.rigid import exp_so3, kabsch
from trackcal.calib.model_file import ModelError, identification_to_doc, load_model
from trackcal.mocks.twin import Twin, simulate_campaign


def test_noise_free_campaign_is_recovered_exactly(kr270, kr270_params):
    twin, table = kr270_campaign(kr270, seed=11, noise_free=True)
    res = identify(kr270.chain, table, kr270.tool_points, kr270_params)
    # 1e-9 mm for lengths; angles times the ~2 m reach of the arm must be below 1e-9 mm too
    err = res.dev - truth_of(twin, kr270_params)
    scale = np.array([1.0 if p.is_length else 2000.0 for p in kr270_params])
    assert np.max(np.abs(err * scale)) < 1e-9
    for pid, x in res.points.items():
        np.testing.assert_allclose(x, twin.true_points[pid], atol=1e-9)
    for sid, s in res.stations.items():
        np.testing.assert_allclose(s.translation, twin.true_stations[sid].translation, atol=1e-9)
    assert np.max(np.abs(res.residuals)) < 1e-9
    assert res.iterations < 20  # the paper's alternating scheme needed 280


def test_complete_model_deviations_are_absorbed_exactly(kr270, kr270_params):
    """Completeness: deviations in *every* parameter of the complete model (including the 12 eliminated
    ones) are explained exactly by the irreducible set plus stations and points."""

    devs = {p.name: (0.3 if p.is_length else 0.02) * (-1) ** i for i, p in enumerate(complete_params(kr270.chain))}
    _, table = kr270_campaign(kr270, seed=12, noise_free=True, deviations=devs)
    res = identify(kr270.chain, table, kr270.tool_points, kr270_params)
    assert np.max(np.abs(res.residuals)) < 1e-8


def test_paper_like_campaign_within_its_confidence_intervals(kr270, kr270_params):
    """18+ poses, 3 points, 2 stations, AT901 noise, Table 8 deviations (twin default)."""
    twin, table = kr270_campaign(kr270, seed=5, n_poses=60)
    assert len(set(table.pose)) >= 18 and set(table.station) == {"S1", "S2"}
    res = identify(kr270.chain, table, kr270.tool_points, kr270_params, noise=TrackerNoise())
    err = res.dev - truth_of(twin, kr270_params)
    # whole vector: e^T C^-1 e / k is F(k, dof)-distributed under the model; 99.9 % quantile
    f = err @ np.linalg.solve(res.param_cov(), err) / len(err)
    assert f < stats.f.ppf(0.999, len(err), res.dof)
    # variance factor ~ 1 when the weighting is the true noise model: chi2(dof)/dof, 99.9 % band
    lo, hi = stats.chi2.ppf([0.0005, 0.9995], res.dof) / res.dof
    assert lo < res.variance_factor < hi


def _station_moved(table, sid, r, t):
    moved = table.subset(np.arange(len(table)))
    rows = np.array([s == sid for s in table.station])
    moved.xyz = table.xyz.copy()
    moved.xyz[rows] = table.xyz[rows] @ r.T + t
    return moved


@pytest.fixture(scope="module")
def noisy(kr270, kr270_params):
    _, table = kr270_campaign(kr270, seed=7)
    return table, identify(kr270.chain, table, kr270.tool_points, kr270_params)


@settings(max_examples=10, deadline=None)
@given(
    w=st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3),
    t=st.lists(st.floats(-5000.0, 5000.0), min_size=3, max_size=3),
)
def test_station_frame_change_leaves_robot_unchanged(kr270, kr270_params, noisy, w, t):
    table, ref = noisy
    r = exp_so3(np.array(w))
    res = identify(kr270.chain, _station_moved(table, "S2", r, np.array(t)), kr270.tool_points, kr270_params)
    np.testing.assert_allclose(res.dev, ref.dev, atol=1e-9)
    np.testing.assert_allclose(res.stations["S2"].rotation, r @ ref.stations["S2"].rotation, atol=1e-9)


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_row_permutation_leaves_everything_unchanged(kr270, kr270_params, noisy, seed):
    table, ref = noisy
    perm = np.random.default_rng(seed).permutation(len(table))
    res = identify(kr270.chain, table.subset(perm), kr270.tool_points, kr270_params)
    np.testing.assert_allclose(res.dev, ref.dev, atol=1e-9)
    np.testing.assert_allclose(res.param_ci95(), ref.param_ci95(), rtol=1e-6)


def test_station_only_reestimation_keeps_robot_and_points(kr270, kr270_params, noisy):
    """fixed=("robot", "points"): a calibrated model checked from new tracker set-ups fits only the stations."""
    table, ref = noisy
    moves = {
        "S1": (exp_so3(np.array([0.3, -1.2, 2.0])), np.array([1500.0, -800.0, 40.0])),
        "S2": (exp_so3(np.array([-0.7, 0.1, 0.4])), np.array([-300.0, 2500.0, -90.0])),
    }
    moved = table
    for sid, (r, t) in moves.items():
        moved = _station_moved(moved, sid, r, t)
    res = identify(kr270.chain, moved, ref.points, kr270_params, dev0=ref.dev, fixed=("robot", "points"))
    assert np.array_equal(res.dev, ref.dev)
    assert all(np.array_equal(res.points[p], ref.points[p]) for p in ref.points)
    # the stations that were optimal with this robot model, carried along with the tracker
    for sid, (r, t) in moves.items():
        np.testing.assert_allclose(res.stations[sid].rotation, r @ ref.stations[sid].rotation, atol=1e-9)
        np.testing.assert_allclose(res.stations[sid].translation, r @ ref.stations[sid].translation + t, atol=1e-6)
        rows = np.array(table.station) == sid
        np.testing.assert_allclose(res.residuals[rows], ref.residuals[rows] @ r.T, atol=1e-6)
        # i.i.d. weights: each station is the closed-form rigid fit of the model's base-frame points
        pb = np.linalg.solve(
            ref.stations[sid].rotation, (table.xyz[rows] - ref.residuals[rows] - ref.stations[sid].translation).T
        ).T
        rk, tk = kabsch(pb, moved.xyz[rows])
        np.testing.assert_allclose(res.stations[sid].rotation, rk, atol=1e-9)
    # only 12 unknowns: the fixed ones have no variance, the degrees of freedom count the stations alone
    assert res.dof == 3 * len(table) - 12
    assert np.all(res.param_ci95() == 0) and np.all(res.point_ci95("P1") == 0)
    assert np.all(res.station_ci95("S1") > 0)
    with pytest.raises(IdentificationError, match="fixed: stations"):
        identify(kr270.chain, moved, ref.points, kr270_params, fixed=("stations",))


def test_residual_statistics_definitions():
    r = np.array([[3.0, 4.0, 0.0], [0.0, 0.0, 0.0]])
    s = residual_stats(r)
    assert s["coord_max_mm"] == 4.0 and s["dist_max_mm"] == 5.0
    assert s["coord_rms_mm"] == pytest.approx(np.sqrt(25 / 6)) and s["dist_rms_mm"] == pytest.approx(np.sqrt(25 / 2))


def test_significance_is_the_exact_effect_of_one_parameter(kr270, kr270_params):
    """Resetting dq2 moves the TCP by |dq2| times the distance of the TCP from axis 2 (lever arm)."""
    dev = np.zeros(len(kr270_params))
    i = [p.name for p in kr270_params].index("dq2")
    dev[i] = np.radians(0.01)
    q0 = np.zeros(6)  # stretched arm: TCP at 1150 + 1200 + 277 mm along x from axis 2, 41 mm below... in y-z
    sig = dict(significance(kr270.chain, kr270_params, dev, q0, kr270.tcp))
    lever = np.hypot(1150 + 1200 + kr270.tcp[0], -41 + kr270.tcp[2])
    assert sig["dq2"] == pytest.approx(2 * lever * np.sin(dev[i] / 2), rel=1e-9)
    assert all(v == 0.0 for k, v in sig.items() if k != "dq2")


def test_unknown_point_is_named_with_row_and_column(kr270, kr270_params):
    _, table = kr270_campaign(kr270, seed=3)
    table.point[4] = "P9"
    with pytest.raises(IdentificationError, match=r"row 6: column point: unknown point id 'P9'"):
        identify(kr270.chain, table, kr270.tool_points, kr270_params)


def test_station_with_too_few_rows(kr270, kr270_params):
    _, table = kr270_campaign(kr270, seed=3)
    table.station[0] = "S3"
    with pytest.raises(IdentificationError, match=r"station 'S3' has 1 measurement"):
        identify(kr270.chain, table, kr270.tool_points, kr270_params)


def test_unidentifiable_setup_is_refused(kr270, kr270_params):
    """Three poses that differ only in joint 1 cannot reveal the other links' parameters."""

    base = np.array([10.0, -60.0, 80.0, 10.0, 40.0, 0.0])
    poses = np.array([base + [d, 0, 0, 0, 0, 0] for d in np.linspace(0, 40, 12)])
    table = simulate_campaign(Twin(kr270, seed=1, noise=TrackerNoise.isotropic(0.001)), poses, stations=["S1"])
    with pytest.raises(IdentificationError, match="unidentifiable set-up"):
        identify(kr270.chain, table, kr270.tool_points, kr270_params)


@pytest.mark.parametrize("cause", ["thermal_drift", "backlash"])
def test_structured_solver_equals_a_dense_reference(kr270, kr270_params, cause):
    """The solver works on normal equations summed over row chunks, pose by pose, and reads the covariance
    from a chunked QR (TSQR). On a random problem with an extension (a per-row arm growth, or per-row joint
    offsets that differ between rows of one pose) and the tracker noise model: those sums equal J^T J and
    J^T r of the dense Jacobian, R^T R = J^T J with the singular values of J, whatever the chunking, and the
    solution is the one dense Gauss-Newton reaches."""

    twin, table = kr270_campaign(kr270, seed=21, n_poses=25)
    ext = build_extension(cause, kr270.chain, table)
    problem = Problem(kr270.chain, table, kr270.tool_points, kr270_params, TrackerNoise(), extension=ext)
    rng = np.random.default_rng(22)
    state = problem.retract(problem.initial, 1e-4 * rng.normal(size=problem.n_cols))
    r, jm = problem.residual_and_jacobian(state)
    for chunks in (1, 7):
        problem.set_chunks(np.array_split(rng.permutation(problem.n_rows), chunks))
        info, g, cost = problem.normal_equations(state)
        np.testing.assert_allclose(info, jm.T @ jm, rtol=1e-10, atol=1e-12 * np.abs(info).max())
        np.testing.assert_allclose(g, jm.T @ r, rtol=1e-9, atol=1e-12 * np.abs(g).max())
        assert cost == pytest.approx(float(r @ r), rel=1e-12)
        rf = problem.r_factor(state)
        np.testing.assert_allclose(rf.T @ rf, jm.T @ jm, rtol=1e-9, atol=1e-12 * np.abs(info).max())
        np.testing.assert_allclose(np.linalg.svd(rf, compute_uv=False), np.linalg.svd(jm, compute_uv=False), rtol=1e-8)
    ours = solve(problem, problem.initial).state
    ref = problem.initial
    for _ in range(20):  # dense Gauss-Newton by least squares on the whole Jacobian
        r, jm = problem.residual_and_jacobian(ref)
        step = np.linalg.lstsq(jm, r, rcond=None)[0]
        ref = problem.retract(ref, step)
    info, _, cost = problem.normal_equations(ref)
    std = np.sqrt(np.diag(np.linalg.inv(info)) * cost / (3 * problem.n_rows - problem.n_cols))
    k = problem.k + problem.e
    # solver tolerance: steps below 1e-9 of the noise level move parameters by ~1e-9 of their std
    assert np.all(np.abs(np.r_[ours.dev, ours.ext] - np.r_[ref.dev, ref.ext]) < 1e-6 * std[:k])


@pytest.fixture(scope="module")
def extended(kr270, kr270_params):
    """A problem with every kind of unknown: robot, a growth (thermal) and a joint-offset (backlash) extension,
    two stations, three points, the tracker noise model, away from its start."""
    _, table = kr270_campaign(kr270, seed=41, n_poses=8)
    ext = combine(
        [
            build_extension("backlash", kr270.chain, table),
            build_extension("thermal_drift", kr270.chain, table, names=["e_base"]),
        ]
    )
    return table, ext


@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), fixed=st.sampled_from([(), ("points",), ("robot", "points")]))
def test_jacobian_blocks_match_central_differences(kr270, kr270_params, extended, seed, fixed):
    """The Jacobian, assembled from its non-zero blocks (robot and extension, one station, one point per row),
    of any subset of rows in any order, against central differences of the residuals, every free column."""
    table, ext = extended
    rng = np.random.default_rng(seed)
    problem = Problem(
        kr270.chain,
        table,
        kr270.tool_points,
        kr270_params,
        TrackerNoise(),
        extension=ext,
        ext0=rng.normal(0.0, 1e-5, ext.size),
        fixed=fixed,
    )
    state = problem.retract(problem.initial, 1e-4 * rng.normal(size=problem.n_cols))
    rows = rng.permutation(problem.n_rows)[: rng.integers(1, problem.n_rows)]
    r0, jm = problem.residual_and_jacobian(state, rows)
    sel = (3 * rows[:, None] + np.arange(3)).ravel()
    np.testing.assert_allclose(r0, problem.residual(state)[sel], atol=1e-9)
    for c in range(problem.n_cols):
        step = np.zeros(problem.n_cols)
        h = 1e-4 / max(np.sqrt(np.mean(jm[:, c] ** 2)), 1e-3)  # moves the prediction by ~0.1 um
        step[c] = h
        diff = problem.residual(problem.retract(state, step)) - problem.residual(problem.retract(state, -step))
        # the Jacobian is of the prediction (residual = measured - predicted); truncation O(h^2) and rounding
        # ~1e-16 * 5000 mm / 1e-4 mm ~ 5e-9 relative to a column of unit scale
        np.testing.assert_allclose(-diff[sel] / (2 * h), jm[:, c], rtol=1e-5, atol=1e-6 * np.abs(jm[:, c]).max())


@pytest.mark.parametrize("stations", [["S1"], ["S1", "S2"]])
@pytest.mark.parametrize("noise", [None, TrackerNoise()])
def test_rows_in_order_give_what_rows_in_any_order_give(kr270, kr270_params, extended, stations, noise):
    """A pass over rows that follow each other takes the per-row arrays by slices (views), walks the chain once per
    row in row order and, for one unwhitened station, turns every row in one product: the residuals, Jacobian rows
    and normal equations are those of the same rows taken in a scrambled order, row for row (to rounding)."""
    table, ext = extended
    if stations == ["S1"]:
        poses = np.degrees(random_poses(kr270, 12, np.random.default_rng(41)))
        table = simulate_campaign(Twin(kr270, seed=41), poses, stations=["S1"])  # one station: one rotation for all
        ext = combine(
            [
                build_extension("backlash", kr270.chain, table),
                build_extension("thermal_drift", kr270.chain, table, names=["e_base"]),
            ]
        )
    problem = Problem(kr270.chain, table, kr270.tool_points, kr270_params, noise, extension=ext)
    rng = np.random.default_rng(44)
    state = problem.retract(problem.initial, 1e-4 * rng.normal(size=problem.n_cols))
    r, jm = problem.residual_and_jacobian(state)
    np.testing.assert_allclose(r, problem.residual(state), rtol=0, atol=1e-12 * np.abs(r).max())  # forward only
    scrambled = rng.permutation(problem.n_rows)
    r_s, jm_s = problem.residual_and_jacobian(state, scrambled)
    sel = (3 * scrambled[:, None] + np.arange(3)).ravel()
    np.testing.assert_allclose(r_s, r[sel], rtol=0, atol=1e-12 * np.abs(r).max())
    np.testing.assert_allclose(jm_s, jm[sel], rtol=0, atol=1e-12 * np.abs(jm).max())
    passes = []
    for rows in (np.arange(problem.n_rows), scrambled):
        problem.set_chunks([rows])
        passes.append(problem.normal_equations(state))
    (info, g, cost), (info_s, g_s, cost_s) = passes
    np.testing.assert_allclose(info_s, info, rtol=0, atol=1e-12 * np.abs(info).max())
    np.testing.assert_allclose(g_s, g, rtol=0, atol=1e-12 * np.abs(g).max())
    assert cost_s == pytest.approx(cost, rel=1e-12)


@pytest.mark.parametrize("with_base", [False, True])
@pytest.mark.parametrize("noise", [None, TrackerNoise()])
def test_normal_equations_from_the_levers_are_those_of_the_jacobian(kr270, kr270_params, with_base, noise):
    """A joint error map of 72 harmonics (6 joints, order 6: at least LEVER_GRAM_MIN) has its block of the normal
    equations formed from the rows' levers (`JointFeatures.gram`): J^T J, J^T r and r.r are those of the Jacobian's
    rows to rounding, on two stations and three points, whitened or not, beside a backlash (joint features too) and a
    thermal growth (columns formed from the Jacobian). A fold's part (`normal_rows`, rows scrambled) gives its rows'
    residual and kept columns (not the map's, never formed) as the Jacobian's rows are, bit for bit."""
    _, table = kr270_campaign(kr270, seed=45, n_poses=20)
    q = np.radians(table.q_deg)
    arcs = {j: Arc.covering(q[:, j]) for j in range(kr270.chain.dof)}
    ext = map_extension(q, names=[nm for j in arcs for nm in harmonic_names(j, 6)], arcs=arcs)
    if with_base:
        base = [build_extension(c, kr270.chain, table) for c in ("thermal_drift", "backlash")]
        ext = combine([*base, ext], cause="cyclic_error")
    problem = Problem(kr270.chain, table, kr270.tool_points, kr270_params, noise, extension=ext)
    # the map's columns: not the backlash's beside them (a cause's own run; the base's stay among the others)
    assert problem._lever_gram[0] == slice(problem.c_st - 72, problem.c_st)
    rng = np.random.default_rng(46)
    state = problem.retract(problem.initial, 1e-5 * rng.normal(size=problem.n_cols))
    r, jm = problem.residual_and_jacobian(state)
    gram, rhs, rr = problem.normal_equations(state)
    norms = np.linalg.norm(jm, axis=0)  # an entry's rounding: eps times the product of its columns' norms
    assert np.all(np.abs(gram - jm.T @ jm) <= 1e-13 * np.outer(norms, norms))
    assert np.all(np.abs(rhs - jm.T @ r) <= 1e-13 * norms * np.linalg.norm(r))
    assert rr == pytest.approx(float(r @ r), rel=1e-13)
    rows, keep = rng.permutation(problem.n_rows)[:25], problem._lever_gram[2][::2]  # the map's columns are not formed
    g_k, b_k, r_k, j_k = problem.normal_rows(state, rows, keep)
    r_rows, j_rows = problem.residual_and_jacobian(state, rows)
    assert np.array_equal(r_k, r_rows) and np.array_equal(j_k, j_rows[:, keep])
    norms = np.linalg.norm(j_rows, axis=0)
    assert np.all(np.abs(g_k - j_rows.T @ j_rows) <= 1e-13 * np.outer(norms, norms))
    assert np.all(np.abs(b_k - j_rows.T @ r_rows) <= 1e-13 * norms * np.linalg.norm(r_rows))
    with pytest.raises(IdentificationError, match="not formed"):
        problem.normal_rows(state, rows, np.array([problem._lever_gram[0].start]))
    # the chunks formed in threads (a diagnosis's) and summed in chunk order: the same sums, bit for bit
    problem.set_chunks(np.array_split(rng.permutation(problem.n_rows), 3))
    alone = problem.normal_equations(state)
    with ThreadPoolExecutor(2) as ex:
        threaded = problem.normal_equations(state, ex)
    assert all(np.array_equal(a, b) for a, b in zip(alone, threaded, strict=True))


def test_normal_equations_pass_gives_the_residual_cost(kr270, kr270_params, extended):
    """The solver judges a trial point by the cost of the pass that forms its normal equations: it equals the
    cost of the residuals computed on their own (forward kinematics only), for any chunking."""
    table, ext = extended
    problem = Problem(kr270.chain, table, kr270.tool_points, kr270_params, TrackerNoise(), extension=ext)
    rng = np.random.default_rng(43)
    state = problem.retract(problem.initial, 1e-4 * rng.normal(size=problem.n_cols))
    r = problem.residual(state)
    for chunks in (1, 3):
        problem.set_chunks(np.array_split(rng.permutation(problem.n_rows), chunks))
        assert problem.normal_equations(state)[2] == pytest.approx(float(r @ r), rel=1e-12)


def test_a_fit_that_did_not_converge_says_so_in_model_json(kr270, kr270_params, tmp_path):
    _, table = kr270_campaign(kr270, seed=11)
    capped = identify(kr270.chain, table, kr270.tool_points, kr270_params, max_iter=1)
    assert capped.converged is False and "stopped after 1 iterations" in capped.message
    write_json(tmp_path / "capped.json", identification_to_doc(capped))
    model = load_model(tmp_path / "capped.json")
    assert model.doc["converged"] is False and model.doc["message"] == capped.message
    assert model.converged is False and model.message == capped.message
    done = identify(kr270.chain, table, kr270.tool_points, kr270_params)
    assert done.converged is True and done.message
    doc = identification_to_doc(done)
    assert doc["converged"] is True and doc["message"] == done.message
    old = {k: v for k, v in doc.items() if k not in ("converged", "message")}  # a model.json written before
    write_json(tmp_path / "old.json", old)
    assert load_model(tmp_path / "old.json").converged is None
    write_json(tmp_path / "bad.json", {**doc, "converged": "yes"})
    with pytest.raises(ModelError, match="converged: expected true or false"):
        load_model(tmp_path / "bad.json")


@pytest.mark.parametrize("seed", [3, 17])
def test_the_solvers_last_step_moves_its_normal_equations_to_first_order(kr270, kr270_params, seed):
    """A fit that stops on a step taken without forming the normal equations there hands them moved by that step
    (J^T J kept, J^T r - J^T J d, |r - J d|^2, `Solution.normal`). Against those formed at the returned state they
    differ by the model's curvature times the last step, which the solver's test bounds (below 1e-9 of the noise
    divided by the rate of convergence, ~1e-3 on these campaigns): the difference in J^T r would move a Gauss-Newton
    step (a cross-validation fold's, `calib.diagnose.crossval`) by less than 1e-7 of the noise (measured: 1e-9 to
    8e-9), J^T J agrees to 1e-7 (measured 1e-9 at most) and r.r to 1e-10 (a few 1e-12)."""
    table = kr270_campaign(kr270, seed=seed, n_poses=12)[1]
    ext = combine([build_extension("backlash", kr270.chain, table)])
    problem = Problem(kr270.chain, table, kr270.tool_points, kr270_params, TrackerNoise(), extension=ext)
    sol = solve(problem, problem.initial)
    assert sol.converged and sol.normal is not None
    gram, grad, cost = problem.normal_equations(sol.state)
    g_lin, b_lin, c_lin = sol.normal
    sigma = np.sqrt(cost / (3 * problem.n_rows - problem.n_cols))  # the whitened noise per coordinate
    d = np.linalg.solve(gram, b_lin - grad)  # the step the difference in J^T r would add
    assert np.sqrt(d @ gram @ d) < 1e-7 * sigma
    assert np.abs(g_lin - gram).max() < 1e-7 * np.abs(gram).max()
    assert c_lin == pytest.approx(cost, rel=1e-10)
