"""The uncertainty budget of the ISO 9283 figures (calib.uncertainty_budget): each line's contribution recomputed by a
second method (finite differences of the figure computed from scratch, or a plain Monte-Carlo of the figure), the
temperature lines by hand, the coverage interval against distributions whose quantiles are known."""

import warnings

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from trackcal.calib.iso9283 import pose_accuracy, pose_repeatability
from trackcal.calib.uncertainty_budget import (
    _LAM_TABLE,
    _T_TABLE,
    ALPHA_STEEL,
    FC_GRID,
    FC_TAIL,
    FC_TRIALS,
    MC_SEED,
    PROBABILITY,
    RATIO_DIP,
    REFRACTION_PER_K,
    PoseSetting,
    _lam_hat,
    _log_ratio,
    _noisy_repeatability,
    _quantile_of_lowest,
    _ratio_quantile,
    _sqrt_psd,
    ap_budget,
    joint_draws,
    norm_interval,
    pose_inputs,
    repeatability,
    rp_budget,
    shortest_interval,
)

RNG = np.random.default_rng(39)
R_STATION = Rotation.from_rotvec([0.3, -0.2, 2.5]).as_matrix()  # station <- base
T_STATION = np.array([-900.0, 3100.0, -700.0])
R_TOOL = Rotation.from_rotvec([0.1, 1.2, -0.4]).as_matrix()  # the last joint frame at the commanded joints
O_TOOL = np.array([1500.0, 300.0, 1200.0])
POINT = np.array([277.0, -47.0, -94.0])  # the KR-270 tool's P1 (configs/tools/kr270-3point.yaml)
STATION_U = np.array([0.004, 0.003, 0.005, 2e-6, 3e-6, 1.5e-6])  # mm, rad
POINT_U = np.array([0.002, 0.003, 0.0025])
OFFSET_TRUE = np.array([0.9, -0.5, 0.7])  # mm: a robot that misses by 1.2 mm


def scene(n=30, sigma=0.005):
    """n measurements (station frame) of a point attained OFFSET_TRUE away from the commanded one, isotropic tracker
    noise sigma."""
    c = O_TOOL + R_TOOL @ POINT
    x = c + OFFSET_TRUE + RNG.normal(0.0, sigma, (n, 3))
    y = x @ R_STATION.T + T_STATION
    covs = np.broadcast_to(np.eye(3) * sigma**2, (n, 3, 3)).copy()
    return c, x, y, covs


def ap_from_scratch(y, rot, t, point):
    """AP_P with the station (rot, t) and the tool point given: the standard's |x_bar - c|, x = rot^T (y - t)."""
    x = (y - t) @ rot
    return np.linalg.norm(x.mean(axis=0) - (O_TOOL + R_TOOL @ point))


def line(budget, name):
    return next(ln for ln in budget.lines if ln.name == name).contribution_mm


def test_station_and_point_lines_by_finite_differences():
    """Each calibration line's contribution sqrt(sum_k (dAP/dtheta_k u_k)^2), the derivatives by central differences
    of AP recomputed from scratch with the station moved as the solver moves it (R' = exp([w]) R, t' = exp([w]) t + v)
    or the tool point moved: within 1 % of the budget's (the budget's are exact gradients; 10 % is the issue's
    bound)."""
    c, x, y, covs = scene()
    s = PoseSetting(y, R_STATION, STATION_U, R_TOOL, POINT, POINT_U, "test tracker")
    b = ap_budget(x.mean(axis=0) - c, pose_inputs(x, covs, s))
    h = 1e-6  # small: a 1e-4 rad turn moves the point 0.3 mm, and |o| curves over that

    def d_station(k):
        d = np.zeros(6)
        d[k] = h
        out = []
        for sign in (1, -1):
            e = Rotation.from_rotvec(sign * d[3:]).as_matrix()
            out.append(ap_from_scratch(y, e @ R_STATION, e @ T_STATION + sign * d[:3], POINT))
        return (out[0] - out[1]) / (2 * h)

    def d_point(k):
        d = np.eye(3)[k] * h
        return (
            ap_from_scratch(y, R_STATION, T_STATION, POINT + d) - ap_from_scratch(y, R_STATION, T_STATION, POINT - d)
        ) / (2 * h)

    translation = np.sqrt(sum((d_station(k) * STATION_U[k]) ** 2 for k in range(3)))
    rotation = np.sqrt(sum((d_station(k) * STATION_U[k]) ** 2 for k in range(3, 6)))
    point = np.sqrt(sum((d_point(k) * POINT_U[k]) ** 2 for k in range(3)))
    assert translation > 1e-3 and rotation > 1e-3 and point > 1e-3  # each line matters here
    assert line(b, "station estimate, translation") == pytest.approx(translation, rel=0.01)
    assert line(b, "station estimate, rotation") == pytest.approx(rotation, rel=0.01)
    assert line(b, "tool point estimate") == pytest.approx(point, rel=0.01)


def test_each_line_by_a_plain_monte_carlo():
    """Each input alone: the standard deviation of AP over 20000 draws of that input (a plain Monte-Carlo of the
    figure, normal or rectangular as the line states) is its GUM contribution within 10 % (the issue's bound)."""
    c, x, y, covs = scene()
    s = PoseSetting(
        y, R_STATION, STATION_U, R_TOOL, POINT, POINT_U, "test tracker", centring_mm=0.01, temp_halfrange_k=0.5
    )
    offset = x.mean(axis=0) - c
    inputs = pose_inputs(x, covs, s)
    b = ap_budget(offset, inputs)
    rng = np.random.default_rng(5)
    for inp, ln in zip(inputs, b.lines, strict=True):
        if ln.contribution_mm < 1e-5:
            continue
        draws = np.linalg.norm(offset + inp.draw(rng, 20000), axis=1)
        assert draws.std() == pytest.approx(ln.contribution_mm, rel=0.1), ln.name


def test_temperature_lines_by_hand():
    """A barycentre 2000 mm from the base along x, tool at the flange's origin (point 0), 5000 mm from the tracker
    along the beam, temperatures within +-1 K: u(dT) = 1/sqrt 3 = 0.577 K (rectangular, JCGM 100:2008, 4.3.7); the
    steel arm moves the point by 11.5e-6 /K * 2000 mm * 0.577 K = 13.28 µm, the air's refraction (-0.927 ppm/K,
    Edlen) the range by 0.927e-6 * 5000 mm * 0.577 K = 2.68 µm."""
    x = np.array([[2000.0, 0.0, 0.0]] * 3)
    y = np.array([[5000.0, 0.0, 0.0]] * 3)
    s = PoseSetting(y, np.eye(3), np.zeros(6), np.eye(3), np.zeros(3), np.zeros(3), "t", temp_halfrange_k=1.0)
    inputs = pose_inputs(x, np.zeros((3, 3, 3)), s)
    b = ap_budget(np.array([0.5, 0.0, 0.0]), inputs)
    assert ALPHA_STEEL == 11.5e-6
    assert abs(REFRACTION_PER_K - 0.927e-6) < 1e-9
    assert line(b, "temperature: arm (steel) and tool (aluminium) expansion") == pytest.approx(0.01328, rel=1e-3)
    assert line(b, "temperature: air along the beam (refraction)") == pytest.approx(0.00268, rel=3e-3)


def test_shortest_interval_of_known_distributions():
    """N(0, 1): the shortest 95 % interval is -+1.95996 (the normal quantile); Exp(1), a decreasing density: it starts
    at 0 and ends at -ln 0.05 = 2.9957 (JCGM 101:2008, 7.7.2: shortest, not symmetric)."""
    rng = np.random.default_rng(1)
    lo, hi = shortest_interval(rng.standard_normal(400_000))
    assert lo == pytest.approx(-1.96, abs=0.02) and hi == pytest.approx(1.96, abs=0.02)
    lo, hi = shortest_interval(rng.exponential(1.0, 400_000))
    assert lo == pytest.approx(0.0, abs=0.005) and hi == pytest.approx(2.9957, abs=0.03)


def test_ap_budget_is_deterministic_and_its_interval_holds_the_value():
    """The same inputs give the same budget (a fixed seed: a report's numbers are reproducible); far from AP = 0 the
    Monte-Carlo interval is value -+ about 2 u_c (a nearly linear figure: k = 2 covers about 95 %)."""
    c, x, y, covs = scene()
    s = PoseSetting(y, R_STATION, STATION_U, R_TOOL, POINT, POINT_U, "test tracker")
    a = ap_budget(x.mean(axis=0) - c, pose_inputs(x, covs, s))
    b = ap_budget(x.mean(axis=0) - c, pose_inputs(x, covs, s))
    assert a.to_doc() == b.to_doc()
    lo, hi = a.interval
    assert lo < a.value < hi
    assert (hi - lo) / 2 == pytest.approx(1.96 * a.u_c, rel=0.05)


def test_rp_budget_matches_its_linear_propagation():
    """A robot scattering 50 µm per axis measured with 5 µm tracker noise: RP_l is nearly linear in the noise, so
    the Monte-Carlo interval's half-width is 1.96 times the tracker line's GUM contribution within 10 %, and the
    inputs common to every cycle contribute nothing."""
    rng = np.random.default_rng(3)
    x = rng.normal(0.0, 0.05, (30, 3))
    covs = np.broadcast_to(np.eye(3) * 0.005**2, (30, 3, 3)).copy()
    rp, _, _ = pose_repeatability(x, covs)
    b = rp_budget(x, covs, rp.u95 / 2, "test tracker")
    lo, hi = b.interval
    assert b.value == pytest.approx(rp.value)
    assert (hi - lo) / 2 == pytest.approx(1.96 * rp.u95 / 2, rel=0.1)
    assert [ln.contribution_mm for ln in b.lines[1:]] == [0.0] * (len(b.lines) - 1)
    assert pose_accuracy(x, np.zeros(3), covs)[0].value >= 0.0


def test_lam_hat_is_np_interp_bit_for_bit():
    """_lam_hat replaces np.interp on the uniform table (issue 41: the search was 40 % of `iso9283 compare`): the same
    value in every bit on every knot, beside every knot (one ulp either side: where the linspace's rounding decides
    the interval) and between them."""
    t = np.concatenate([_T_TABLE, np.nextafter(_T_TABLE, -1.0), np.nextafter(_T_TABLE, 11.0)])
    t = np.concatenate([t, np.random.default_rng(41).uniform(0.0, 10.0, 200_000)])
    t = t[(t >= 0.0) & (t <= _T_TABLE[-1])]
    assert np.array_equal(_lam_hat(t), np.interp(t, _T_TABLE, _LAM_TABLE))


def log_ratio_as_first_written(t, lam):
    """_log_ratio before issue 41: lam as a full array, np.interp, both branches of log sinhc computed everywhere."""

    def log_sinhc(t, lam):
        z = np.maximum(t * lam, 1e-300)
        big = z + np.log1p(-np.exp(-2.0 * z)) - np.log(2.0) - np.log(np.maximum(lam, 1e-300))
        return np.where(z < 1e-8, np.log(np.maximum(t, 1e-300)), big)

    far = np.sqrt(np.maximum(t * t - 4.0, 0.0))
    hat = np.where(t <= _T_TABLE[-1], np.interp(t, _T_TABLE, _LAM_TABLE), 0.5 * (t + far))
    with np.errstate(divide="ignore"):
        return log_sinhc(t, np.full_like(t, lam)) - lam * lam / 2 - (log_sinhc(t, hat) - hat * hat / 2)


@given(
    st.lists(st.floats(0.0, 30.0), min_size=1, max_size=300),
    st.one_of(st.just(0.0), st.floats(0.0, 20.0)),
)
def test_log_ratio_gives_the_first_form_bit_for_bit(ts, lam):
    """The ranking of the Feldman-Cousins construction is unchanged in every bit, so are the intervals it gives."""
    t = np.array(ts)
    assert np.array_equal(_log_ratio(t, lam), log_ratio_as_first_written(t, lam))


def test_ap_budget_near_zero_warns_of_nothing():
    """A compensated pose (AP of the noise's size): draws with t near 0 underflow sinh's argument; the report's console
    showed numpy's 'divide by zero encountered in log1p' (issue 41's profile of `iso9283 compare`)."""
    c, x, y, covs = scene()
    s = PoseSetting(y, R_STATION, STATION_U, R_TOOL, POINT, POINT_U, "test tracker")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        budget = ap_budget(np.array([0.001, 0.0, 0.0]), pose_inputs(x - x.mean(axis=0) + c, covs, s))
    assert budget.interval[0] == 0.0  # an upper limit: the construction's lower end at 0 (module docstring)


def every_trial_ranked(offset, inputs):
    """norm_interval as first written (issue 39): every trial value of the grid ranked, the interval the accepted
    ones' min and max (or the best-ranked one when none is accepted)."""
    t_obs = float(np.linalg.norm(offset))
    cov = sum((i.cov() for i in inputs), np.zeros((3, 3)))
    sigma = float(np.sqrt(np.trace(cov) / 3.0))
    u = offset / t_obs
    e = joint_draws(inputs, np.random.default_rng(MC_SEED), FC_TRIALS)
    ue, ee = e @ u, np.einsum("ij,ij->i", e, e)
    reach = 6.0 * float(np.sqrt(np.linalg.eigvalsh(cov).max()))
    thetas = np.linspace(max(0.0, t_obs - reach), t_obs + reach, FC_GRID)
    score = np.empty(FC_GRID)
    for k, th in enumerate(thetas):
        t = np.sqrt(np.maximum(th * th + 2.0 * th * ue + ee, 0.0)) / sigma
        cut = np.quantile(_log_ratio(t, th / sigma), 1.0 - PROBABILITY)
        score[k] = _log_ratio(np.array([t_obs / sigma]), th / sigma)[0] - cut
    inside = thetas[score >= 0] if (score >= 0).any() else thetas[[int(np.argmax(score))]]
    return float(inside.min()), float(inside.max())


@pytest.mark.parametrize("scale", [0.0005, 0.004, 0.02, 1.0])  # mm: below, near and far above the noise (5 µm)
def test_the_interval_walked_in_from_its_ends_is_every_trial_ranked(scale):
    """norm_interval ranks trial values from each end of the grid inwards and stops at the first accepted one: the
    same ends, bit for bit, as ranking the whole grid; from an upper limit (AP near 0) to a far-off pose."""
    c, x, y, covs = scene()
    s = PoseSetting(y, R_STATION, STATION_U, R_TOOL, POINT, POINT_U, "test tracker")
    inputs = pose_inputs(x - x.mean(axis=0) + c, covs, s)
    offset = scale * np.array([0.6, -0.3, 0.74])
    assert norm_interval(offset, inputs) == every_trial_ranked(offset, inputs)


def test_log_ratio_rises_to_its_mode_and_falls_after_it():
    """What _ratio_quantile ranks on: as a function of t the ratio has one mode, no point lying lower than both sides
    of it by more than RATIO_DIP (the table's interpolation makes dips of 2e-11), for non-centralities from 0 to far
    beyond the table (1500 sigma: a pose 7.5 mm off with 5 µm of noise) and t up to 2000."""
    t = np.concatenate([np.linspace(0.0, 40.0, 40_001), np.linspace(40.0, 2000.0, 20_001)[1:]])
    for lam in np.concatenate([np.linspace(0.0, 40.0, 401), np.linspace(40.0, 1500.0, 74)[1:]]):
        r = _log_ratio(t, lam)
        rise, fall = np.maximum.accumulate(r), np.maximum.accumulate(r[::-1])[::-1]
        assert (np.minimum(rise, fall) - r).max() < RATIO_DIP, lam


@pytest.mark.parametrize("tail", [FC_TAIL, 1_001])  # the ranked ends, and too few of them: every draw ranked
@pytest.mark.parametrize("scale", [0.0, 0.004, 0.02, 1.0])  # mm: the true AP of the trial value, as norm_interval's
def test_the_quantile_of_the_ends_is_the_quantile_of_every_draw(tail, scale):
    """_ratio_quantile ranks the draws at the ends of T only: the 5 % quantile norm_interval cuts at, bit for bit,
    on the draws it makes (isotropic and not; normal and rectangular inputs) from below the noise to far above it."""
    c, x, y, covs = scene()
    s = PoseSetting(y, R_STATION, STATION_U, R_TOOL, POINT, POINT_U, "test tracker")
    inputs = pose_inputs(x - x.mean(axis=0) + c, covs, s)
    e = joint_draws(inputs, np.random.default_rng(MC_SEED), FC_TRIALS)
    u = np.array([0.6, -0.3, 0.74]) / np.linalg.norm([0.6, -0.3, 0.74])
    sigma = float(np.sqrt(np.trace(np.cov(e.T)) / 3.0))
    for th in scale + sigma * np.linspace(-6.0, 6.0, 13):
        th = max(th, 0.0)
        t = np.sqrt(np.maximum(th * th + 2.0 * th * (e @ u) + np.einsum("ij,ij->i", e, e), 0.0)) / sigma
        q = 1.0 - PROBABILITY
        assert _ratio_quantile(t, th / sigma, q, tail) == np.quantile(_log_ratio(t, th / sigma), q), th


@given(
    st.lists(st.floats(-50.0, 50.0), min_size=1, max_size=200),
    st.lists(st.floats(0.0, 1e3), max_size=300),
    st.floats(0.0, 1.0),
)
def test_the_quantile_of_the_lowest_is_np_quantile_bit_for_bit(values, above, q):
    """_quantile_of_lowest reads np.quantile's two order statistics among the ranked values and interpolates as numpy
    does: the same bits as np.quantile over every value (the others at or above the floor, here the ranked values'
    largest, ties included) and over the values padded with +inf (the form before issue 37); with a floor below a
    statistic it reads, no answer."""
    v = np.array(values)
    n = len(v) + len(above)
    others = v.max() + np.array(above)
    got = _quantile_of_lowest(v, n, q, v.max())
    if int((n - 1) * q) + 2 >= len(v):
        assert got is None
        return
    assert got == np.quantile(np.concatenate([v, others]), q)
    assert got == np.quantile(np.concatenate([v, np.full(len(above), np.inf)]), q)
    assert _quantile_of_lowest(v, n, q, v.min() - 1.0) is None


def shortest_interval_by_full_sort(samples, p=PROBABILITY):
    """shortest_interval before issue 37: every sample sorted."""
    y = np.sort(np.asarray(samples, dtype=float))
    q = int(round(p * len(y)))
    widths = y[q:] - y[: len(y) - q]
    r = int(np.argmin(widths))
    return float(y[r]), float(y[r + q])


@given(
    st.lists(st.floats(-1e3, 1e3), min_size=2, max_size=400),
    st.sampled_from([PROBABILITY, 0.5, 0.3, 0.99]),
)
def test_shortest_interval_is_the_full_sorts_bit_for_bit(samples, p):
    """Sorting only the two ends of the sample gives the same interval as sorting it all (ties included; a share p
    under one half, where the ends overlap, too)."""
    q = int(round(p * len(samples)))
    if 0 < q < len(samples):
        assert shortest_interval(np.array(samples), p) == shortest_interval_by_full_sort(samples, p)


@given(
    st.integers(2, 40),  # cycles: the fewest that give RP, the 4 of the docs' example, the standard's 30 and more
    st.sampled_from([1, 7, 1_000]),  # draws: the last, short chunk of RP's Monte-Carlo among them
    st.sampled_from([1e-3, 0.05, 3.0]),  # mm: the robot's scatter, from below the tracker noise to far above it
    st.integers(0, 2**32 - 1),
)
def test_noisy_repeatability_is_the_direct_form(n, m, scatter, seed):
    """RP's Monte-Carlo on the draws as rp_budget makes them (issue 37): the values of the direct form, repeatability
    of x plus each cycle's tracker noise chol z, to a few ulps of a coordinate: x is ~1,000 mm, where an ulp is 1.1e-13
    mm, and the noise's three products are summed in another order (the distances inherit the coordinates' rounding,
    not more)."""
    rng = np.random.default_rng(seed)
    x = rng.normal(0.0, scatter, (n, 3)) + rng.normal(0.0, 1000.0, 3)
    a = rng.normal(0.0, 0.003, (n, 3, 3))
    chol = np.array([_sqrt_psd(c) for c in a @ a.transpose(0, 2, 1)])
    z = rng.standard_normal((m, n, 3))
    got = _noisy_repeatability(x, chol, z)
    want = repeatability(x + np.einsum("nij,mnj->mni", chol, z))
    ulp = np.spacing(np.abs(x).max())
    assert np.abs(got - want).max() <= 16 * ulp


@given(st.floats(0.0, 30.0), st.lists(st.floats(0.0, 1500.0), min_size=1, max_size=400))
def test_log_ratio_over_trial_values_is_each_ones_bit_for_bit(t, lams):
    """norm_interval ranks the measured |o| at every trial value in one call (issue 37): each entry the same bits as
    that trial value's own call, as before."""
    one = [_log_ratio(np.array([t]), lam)[0] for lam in lams]
    assert np.array_equal(_log_ratio(np.full(len(lams), t), np.array(lams)), one)
