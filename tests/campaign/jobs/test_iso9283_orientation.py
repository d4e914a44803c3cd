"""Orientation figures of ISO 9283 (AP_a..AP_c, RP_a..RP_c: ISO 9283:1998, 7.2) from three or more tool points:
each cycle's attained orientation is the rigid fit of the tool's points. By hand, on synthetic clusters of known
angular offset and spread (hypothesis), the fit's covariance against Monte Carlo, and on the twin."""

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.helpers import inproc_live
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.iso9283 import IsoError, attained_orientations, log_so3, orientation_figures
from trackcal.calib.model.cell import load_cell
from trackcal.calib.model.kinematics import Kinematics
from trackcal.calib.model.rigid import exp_so3, rpy_matrix
from trackcal.calib.model_file import Model
from trackcal.campaign.jobs.campaign import new_session, run_session
from trackcal.campaign.jobs.iso9283 import PlanOptions, make_plan, session_figures
from trackcal.mocks.twin import Twin

# the KR-270 tool's three nests (configs/tools/kr270-3point.yaml, paper Table 7), last joint frame, mm
TOOL = np.array([[277.0, -47.0, -94.0], [276.0, -48.0, 94.0], [278.0, 104.0, -2.0]])


def test_by_hand_three_cycles_about_z():
    """Commanded orientation the identity, three cycles turned 0.01, 0.02, 0.03 deg about the base z axis, exact
    points: AP_c = mean - commanded = 0.02 deg, RP_c = 3 S_c with S_c = sample std of (0.01, 0.02, 0.03) = 0.01 deg,
    so 0.03 deg; nothing about x and y."""
    angles = [0.01, 0.02, 0.03]
    x = np.array([TOOL @ exp_so3(np.radians([0.0, 0.0, a])).T + [1000.0, 200.0, 50.0] for a in angles])
    w, cov = attained_orientations(TOOL, x, np.eye(3))
    assert cov is None
    figs = orientation_figures(w)
    assert figs["AP_c"].value == pytest.approx(0.02, abs=1e-9)
    assert figs["RP_c"].value == pytest.approx(0.03, abs=1e-9)
    for k in ("AP_a", "AP_b", "RP_a", "RP_b"):
        assert figs[k].value == pytest.approx(0.0, abs=1e-9)
    assert figs["AP_c"].clause == "ISO 9283:1998, 7.2" and figs["RP_c"].clause == "ISO 9283:1998, 7.2"


def test_collinear_points_fix_no_orientation():
    line = np.array([[0.0, 0, 0], [100.0, 0, 0], [200.0, 0, 0]])
    with pytest.raises(IsoError, match="collinear"):
        attained_orientations(line, line[None], np.eye(3))


@settings(deadline=None, max_examples=30)  # each example fits up to 30 clusters: 30 examples keep it to seconds
@given(
    seed=st.integers(0, 2**32 - 1),
    offset_mdeg=st.floats(-50.0, 50.0),
    spread_mdeg=st.floats(0.0, 100.0),
    n=st.integers(3, 30),
    rpy=st.tuples(*[st.floats(-3.0, 3.0)] * 3),
)
def test_synthetic_clusters_recover_their_offset_and_spread(seed, offset_mdeg, spread_mdeg, n, rpy):
    """Cycles turned by w_j = w0 + spread * z_j (z_j standard normal per axis) from a commanded orientation, points
    measured with the tracker's noise 3 m away: AP_a..c and RP_a..c from the noisy points equal those of the exact
    rotations (the mean of w_j, 3 times their sample std) within 2.5 U, five standard uncertainties (a miss has
    probability 6e-7 per figure: the test does not flake). RP only where the spread is at least 10 times the noise
    of the fitted angle (about 6 mdeg here: 16.5 µm across the line of sight over the tool's ~150 mm): noise adds to
    the spread in quadrature, S^2 + sigma^2, a bias of at most sigma / 20 there, which the linear U does not hold
    (below that RP measures the tracker as much as the robot, as the position RP does)."""
    rng = np.random.default_rng(seed)
    rc = rpy_matrix(*rpy)
    w0 = np.radians(offset_mdeg / 1000.0) * rng.normal(size=3) / np.sqrt(3)
    w_true = w0 + np.radians(spread_mdeg / 1000.0) * rng.normal(size=(n, 3))
    where = np.array([3000.0, 500.0, 800.0])
    exact = np.array([(exp_so3(wj) @ rc @ TOOL.T).T + where for wj in w_true])
    noise = TrackerNoise()
    cov = noise.covariance(exact.reshape(-1, 3)).reshape(n, 3, 3, 3)
    noisy = exact + noise.sample(exact.reshape(-1, 3), rng).reshape(exact.shape)
    w, cov_w = attained_orientations(TOOL, noisy, rc, cov)
    got = orientation_figures(w, cov_w)
    want = orientation_figures(np.array([log_so3(exp_so3(wj)) for wj in w_true]))
    sigma = np.degrees(np.sqrt(cov_w[:, [0, 1, 2], [0, 1, 2]].mean(axis=0)))  # per axis, deg
    for key, fig in got.items():
        if key.startswith("RP") and want[key].value / 3.0 < 10.0 * sigma["abc".index(key[-1])]:
            continue
        assert abs(fig.value - want[key].value) <= 2.5 * fig.u95 + 1e-9, (key, fig, want[key])


def test_the_fits_covariance_is_the_monte_carlo_one():
    """cov w of the linearised fit against 4000 noisy fits of one cluster: each variance within 10 % (the relative
    standard error of a variance from N draws is sqrt(2 / N) = 2.2 %, so 10 % is 4.5 of them)."""
    rng = np.random.default_rng(7)
    rc = rpy_matrix(0.3, -0.2, 1.1)
    x = (rc @ TOOL.T).T + [2500.0, -800.0, 600.0]
    noise = TrackerNoise()
    cov = noise.covariance(x)
    _, cov_w = attained_orientations(TOOL, x[None], rc, cov[None])
    draws = x + np.array([noise.sample(x, rng) for _ in range(4000)])
    w, _ = attained_orientations(TOOL, draws, rc)
    assert np.diag(np.cov(w.T)) == pytest.approx(np.diag(cov_w[0]), rel=0.10)


def test_on_the_twin_ap_is_the_orientation_error_the_twin_knows(kr270, tmp_path):
    """The twin's robot (paper Table 8 deviations) at the nominal joints of the plan is turned by what its true chain
    does against the nominal one: AP_a..c are that rotation within 2.5 U (the twin's robot returns to the same joints,
    so only the tracker's noise separates them), in the base frame of the twin's own station and points."""
    plan = make_plan(
        PlanOptions(
            cell="kr270",
            json=str(tmp_path / "iso.json"),
            cycles=3,
            vap_cycles=0,
            orientation=True,
            load="unloaded",
            velocities=(100.0,),
        )
    )
    assert len(plan["iso9283"]["points"]) == 3
    store, campaign = new_session(tmp_path / "s", "kr270", plan, "sim", 1)
    assert run_session(store, campaign, inproc_live(kr270, 1)[1]).exit_status == "success"
    store.close()
    twin = Twin(load_cell("kr270"), seed=1)
    model = Model(twin.cell.chain, [], np.zeros(0), twin.true_stations, twin.true_points, {})
    figs = session_figures(Path(tmp_path / "s"), model, TrackerNoise())
    q = np.radians(np.array(plan["iso9283"]["nominal_poses_deg"]))
    r_true, _ = twin.kin.end_frames(q, twin.true_dev)
    r_nom, _ = Kinematics(twin.cell.chain, []).end_frames(q)
    for i, pose in enumerate(figs.poses):
        known = np.degrees(log_so3(r_true[i] @ r_nom[i].T))
        assert np.linalg.norm(known) > 0.005  # the twin's robot is turned by more than 5 mdeg: something to show
        for k, axis in enumerate("abc"):
            fig = pose.orientation[f"AP_{axis}"]
            assert fig.value == pytest.approx(known[k], abs=2.5 * fig.u95), (pose.name, axis)
