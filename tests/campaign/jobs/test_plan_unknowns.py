"""Issue 35: the plan is scored for what the campaign identifies (robot, stations, points), its rho0 predicts the
report's test-pose figure, and the default plan pays off against the twin's truth."""

import numpy as np
import pytest
from scipy import stats

from trackcal.calib.doe.design import (
    _rho0_swaps,
    design_for_cell,
    optimize_plan,
    plan_rows,
    random_feasible_poses,
)
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.identify.solver import identify
from trackcal.calib.identify.unknowns import campaign_params
from trackcal.calib.io.table import MeasurementTable
from trackcal.calib.model.kinematics import Kinematics
from trackcal.calib.tcp_figure import tcp_sigma
from trackcal.campaign.cli import main
from trackcal.campaign.jobs.plan import EQUATIONS_PER_UNKNOWN, PlanOptions, build_design, plan_size
from trackcal.mocks.twin import Twin, simulate_campaign


@pytest.fixture(scope="module")
def campaign_design(kr270):
    return design_for_cell(kr270, campaign_params(kr270.chain), sigma_mm=0.01)


def test_the_plan_has_the_unknowns_of_identify(kr270, campaign_design):
    """18 irreducible robot parameters (identify's default), 6 per station, 3 per reference point."""
    u = campaign_design.unknowns
    assert [p.name for p in u.params] == [p.name for p in campaign_params(kr270.chain)]
    assert (u.k, u.n_stations, u.n_points, u.size) == (18, 2, 3, 18 + 6 * 2 + 3 * 3)


def noise_free_table(cell, design, q, repeat, seed):
    """The plan's rows (every point from every station that the design sees it from) at the twin's noise-free truth,
    the first station's rows first (the report's frame is the table's first station)."""
    pose, point, station = plan_rows(design, q, repeat)
    order = np.lexsort((pose, point, station))
    pose, point, station = pose[order], point[order], station[order]
    pids, sids = sorted(cell.tool_points), list(cell.stations)
    twin, qd = Twin(cell, seed=seed), np.degrees(q)
    xyz = np.array([twin.exact(qd[i], pids[j], sids[s]) for i, j, s in zip(pose, point, station, strict=True)])
    n = len(pose)
    return MeasurementTable(
        np.arange(1, n + 1),
        np.zeros(n),
        [f"Q{i + 1}" for i in pose],
        [sids[s] for s in station],
        [pids[j] for j in point],
        qd[pose],
        xyz,
        source="twin",
    )


@pytest.mark.parametrize("tracker", [False, True], ids=["iid", "tracker-model"])
def test_rho0_is_the_prediction_of_the_reports_tcp_sigma(kr270, tracker):
    """rho0 of a plan = the report's tcp_sigma of the campaign's identification at the plan's noise: the same
    unknowns and the same test-pose quantity, propagated to first order. The plan linearises at nominal, the
    identification at the twin's truth: robot deviations of at most ~0.5 mm (paper Table 8) on lever arms of a
    metre or more change the Jacobian by ~5e-4 relative, reference points off by 0.5 mm likewise; i.i.d. weights do
    not depend on where a station stands, and the tracker model's sigma grows by 3 um/m (AT901) on ~18 um at 3.5 m,
    so a station 20 mm off (the twin's placement error) changes it by 0.06/18 = 0.3 %: 1 % covers both."""
    noise = TrackerNoise.of(kr270.tracker) if tracker else None
    design = design_for_cell(kr270, campaign_params(kr270.chain), sigma_mm=0.01, noise=noise)
    for seed in (0, 1):
        q = random_feasible_poses(design, 8, np.random.default_rng(seed))
        table = noise_free_table(kr270, design, q, 2, seed)
        res = identify(kr270.chain, table, kr270.tool_points, campaign_params(kr270.chain), noise)
        stated = tcp_sigma(res, kr270.test_pose, table.station[0], 1.0 if tracker else 0.01**2)
        assert design.rho0(q, 2) == pytest.approx(stated, rel=0.01)


@pytest.mark.parametrize("criterion", ["rho0", "D"])
def test_refinement_gradient_over_every_unknown_matches_finite_differences(campaign_design, criterion):
    """The analytic gradient of log(criterion) now has the station and point columns (their derivative by the
    joints): against central differences, arbitrary symmetric positive row weights held fixed."""
    d = campaign_design
    rng = np.random.default_rng(7)
    x = rng.uniform(-2.0, 2.0, 8 * 6)
    b = rng.normal(size=(8 * 3, len(d.trackers), 3, 3))
    w = b @ np.swapaxes(b, -1, -2) + np.eye(3)
    f, g = d.objective(x, 8, criterion, w, d_weight=0.02)
    h = 1e-6

    def value(y):
        return d.objective(y, 8, criterion, w, d_weight=0.02)[0]

    fd = np.array([(value(x + h * e) - value(x - h * e)) / (2 * h) for e in np.eye(len(x))])
    np.testing.assert_allclose(g, fd, rtol=1e-5, atol=1e-5 * np.max(np.abs(fd)))


def test_woodbury_swaps_equal_the_exact_criterion(campaign_design):
    """The exchange's fast rho0 of every swap equals rho0^2 of the swapped plan's information matrix."""
    d = campaign_design
    pool = random_feasible_poses(d, 60, np.random.default_rng(3))
    infos, factors = d.pose_information(pool), d.pose_factors(pool)
    np.testing.assert_allclose(
        np.einsum("nrk,nrl->nkl", factors, factors), infos, rtol=1e-9, atol=1e-12 * np.abs(infos).max()
    )
    rest = infos[:12].sum(axis=0)
    fast = _rho0_swaps(d, rest, factors[12:] / d.scale)
    exact = d.criterion_values(rest + infos[12:], "rho0")
    np.testing.assert_allclose(fast, exact, rtol=1e-7)


def test_the_default_plan_size_comes_from_the_unknowns(kr270, campaign_design):
    """Stations and points unknown: distinct poses, no repeats; EQUATIONS_PER_UNKNOWN x 39 unknowns over 9
    coordinates a configuration (3 points x, y, z) = 13 configurations."""
    configs, repeat, why = plan_size(campaign_design, None, None)
    assert (configs, repeat) == (-(-EQUATIONS_PER_UNKNOWN * 39 // 9), 1) == (13, 1)
    assert "39 unknowns" in why and "before repeats" in why
    assert plan_size(campaign_design, 6, None)[:2] == (6, 1)


def test_plan_without_configs_says_why(tmp_path, capsys):
    out = tmp_path / "p.json"
    assert main(["plan", "--cell", "kr270", "--starts", "40", "--refined", "1", "--json", str(out)]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "plan size: 13 configurations x 1: the campaign identifies 39 unknowns" in text
    assert "unknowns: 18 robot parameters, 2 stations, 3 points" in text


# ---------------------------------------------------------------------- against the twin's truth
def truth_and_model(cell, poses_deg, seed, params):
    """(model - truth) of the campaign's centroid at the test pose in its first station's frame, and the stated
    1-sigma (the report's tcp_sigma), for one twin seed: simulated with noise, identified as identify does."""
    twin = Twin(cell, seed=seed)
    table = simulate_campaign(twin, poses_deg)
    res = identify(cell.chain, table, cell.tool_points, params, TrackerNoise.of(cell.tracker))
    station = res.station_ids[0]
    q0 = np.degrees(cell.test_pose)
    twin.move_to(q0)
    truth = np.mean([twin.exact(q0, p, station) for p in res.point_ids], axis=0)
    tool = np.array([res.points[p] for p in res.point_ids])
    model = res.stations[station].apply(
        Kinematics(cell.chain, params)
        .points(np.repeat(cell.test_pose[None], len(tool), axis=0), tool, res.dev)
        .mean(axis=0)
    )
    return model - truth, tcp_sigma(res, cell.test_pose, station)


@pytest.fixture(scope="module")
def default_plan(kr270):
    """The default plan (`trackcal plan --cell kr270`: size from the cell), on a smaller search budget."""
    design = build_design(kr270, PlanOptions())
    configs, repeat, _ = plan_size(design, None, None)
    return design, optimize_plan(design, configs, repeat, starts=100, refined=1, seed=0, pool_size=500)


def compare_with_random(cell, design, plan, seeds):
    params = campaign_params(cell.chain)
    ours, rand = [], []
    for seed in seeds:
        ours.append(np.linalg.norm(truth_and_model(cell, np.degrees(plan.poses), seed, params)[0]))
        q = random_feasible_poses(design, len(plan.poses), np.random.default_rng(1000 + seed))
        rand.append(np.linalg.norm(truth_and_model(cell, np.degrees(q), seed, params)[0]))
    return np.median(ours), np.median(rand)


def test_the_default_plan_is_closer_to_the_truth_than_random_poses(kr270, default_plan):
    """At equal measurement count (the same number of configurations, each measured once from every station
    that sees it), the default plan's campaign is closer to the twin's truth at the test pose than a campaign of
    random feasible poses, median over seeds (each seed its own true robot placement, stations, points, noise)."""
    design, plan = default_plan
    ours, rand = compare_with_random(kr270, design, plan, range(5))
    assert ours < rand


@pytest.mark.slow
def test_the_default_plan_beats_random_poses_over_many_seeds(kr270, default_plan):
    design, plan = default_plan
    ours, rand = compare_with_random(kr270, design, plan, range(40))
    assert ours < rand


def coverage_ratio(cell, plan, seeds) -> float:
    """sqrt(mean over seeds of |model - truth|^2 / stated^2): 1 when the stated 1-sigma 3-D figure is honest."""
    params = campaign_params(cell.chain)
    r2 = []
    for seed in seeds:
        err, stated = truth_and_model(cell, np.degrees(plan.poses), seed, params)
        r2.append(float(err @ err) / stated**2)
    return float(np.sqrt(np.mean(r2)))


def chi_bounds(n: int, alpha: float = 1e-3) -> tuple[float, float]:
    """Two-sided (1 - alpha) bounds of that ratio over n seeds. |e|^2 / sigma^2 is a weighted sum of three chi2(1)
    with weights summing to 1 (the eigenvalues of the test-pose covariance over its trace); the sum over n seeds
    has at least n degrees of freedom (all weight on one direction, the widest case), so n R^2 ~ chi2(nu) / nu x n
    with nu >= n: bounds from chi2(n) / n."""
    return (float(np.sqrt(stats.chi2.ppf(alpha / 2, n) / n)), float(np.sqrt(stats.chi2.ppf(1 - alpha / 2, n) / n)))


def test_the_stated_test_pose_figure_covers_the_truth(kr270, default_plan):
    """The report's stated 1-sigma at the test pose against the twin's truth, over 8 seeds: within the chi bounds
    of 8 seeds (0.33 to 1.9 at 1e-3, derived in `chi_bounds`)."""
    _, plan = default_plan
    low, high = chi_bounds(8)
    assert low < coverage_ratio(kr270, plan, range(8)) < high


@pytest.mark.slow
def test_the_stated_test_pose_figure_covers_the_truth_over_many_seeds(kr270, default_plan):
    """Over 100 seeds the ratio lies within [0.8, 1.25] (issue 35). chi_bounds(100) is [0.77, 1.24] at 1e-3 in the
    widest case (all the test-pose variance in one direction); with it spread over three directions (nu near 300)
    the band is [0.86, 1.14], so an honest figure fails [0.8, 1.25] with a probability near 1e-3 at most."""
    _, plan = default_plan
    assert 0.8 < coverage_ratio(kr270, plan, range(100)) < 1.25
