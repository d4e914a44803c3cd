"""Calibration history (calib.history, campaign.jobs.history): a robot that changed is flagged, one that did not is
flagged at the rate the test claims."""

import json
import subprocess

import numpy as np
import pytest
from scipy import stats

from tests.helpers import TRACKCAL
from trackcal.calib.doe.poses import random_poses
from trackcal.calib.history import ALPHA, compare_estimates
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.identify.solver import identify
from trackcal.calib.io.files import write_json
from trackcal.calib.model_file import identification_to_doc
from trackcal.mocks.twin import Twin, simulate_campaign

TRUTH_SEED = 11


def calibrate(cell, params, noise_seed: int, dq2_shift_deg: float = 0.0, n_poses: int = 30) -> dict:
    """model.json of a 30-pose campaign on one twin robot (TRUTH_SEED), with its own poses and its own noise; dq2 of
    the robot shifted by `dq2_shift_deg` (a knocked joint, re-zeroed encoder)."""
    twin = Twin(cell, seed=TRUTH_SEED)
    twin.seed = noise_seed  # the twin draws its robot at construction: the robot stays, the noise stream changes
    if dq2_shift_deg:
        twin.true_dev[[p.name for p in twin.params].index("dq2")] += np.radians(dq2_shift_deg)
    poses = np.degrees(random_poses(cell, n_poses, np.random.default_rng(noise_seed)))
    table = simulate_campaign(twin, poses)
    res = identify(cell.chain, table, dict(cell.tool_points), params, noise=TrackerNoise())
    return identification_to_doc(res, test_pose=cell.test_pose)  # as identify writes it


def change(a: dict, b: dict):
    def parts(doc):
        names = doc["covariance_order"]
        return names, [doc["parameters"][n]["value"] for n in names], doc["covariance"], doc["dof"]

    return compare_estimates(*parts(a), *parts(b))


def test_by_hand():
    # one parameter, d = 0.3, S = 0.01 + 0.03 = 0.04 (sigma 0.2): T = 0.09 / 0.04 = 2.25 on F(1, 1000),
    # p = P(|t_1000| > 1.5) = 0.1339 (F(1, nu) is t(nu)^2), close to the normal's 0.1336
    c = compare_estimates(["a"], [1.0], [[0.01]], 1000, ["a"], [1.3], [[0.03]], 2000)
    assert c.statistic == pytest.approx(2.25)
    assert c.p_value == pytest.approx(2 * stats.t.sf(1.5, 1000), rel=1e-9)
    assert c.p_value == pytest.approx(2 * stats.norm.sf(1.5), rel=5e-3)
    assert not c.changed and not c.moved[0]
    assert c.dof == (1, 1000)


def test_only_common_parameters_are_compared():
    c = compare_estimates(["a", "b"], [0, 0], np.eye(2), 50, ["b", "c"], [5, 0], np.eye(2), 50)
    assert c.names == ["b"] and c.difference == pytest.approx([5.0])


def test_a_shifted_joint_offset_is_flagged(kr270, kr270_params):
    """dq2 moved by 0.003 deg between two calibrations (about 20 standard deviations of a 30-pose estimate, 0.1 mm
    at the KR-270's 2 m reach): the robot changed and dq2 is among the parameters that moved."""
    for seed in (1, 2, 3):
        a = calibrate(kr270, kr270_params, 100 + seed)
        b = calibrate(kr270, kr270_params, 200 + seed, dq2_shift_deg=0.003)
        c = change(a, b)
        assert c.changed, c.p_value
        assert c.moved[c.names.index("dq2")]
        assert c.difference[c.names.index("dq2")] == pytest.approx(0.003, abs=4 * c.sigma[c.names.index("dq2")])


def _false_alarms(cell, params, seeds) -> int:
    return sum(change(calibrate(cell, params, 300 + s), calibrate(cell, params, 400 + s)).changed for s in seeds)


def test_an_unchanged_robot_is_not_flagged(kr270, kr270_params):
    """The test claims a 5 % false alarm rate. Over 10 pairs of independent campaigns of the same robot, 3 or more
    alarms happen with probability 1.2 % (binomial(10, 0.05))."""
    assert stats.binom.sf(2, 10, ALPHA) < 0.012
    assert _false_alarms(kr270, kr270_params, range(10)) <= 2


@pytest.mark.slow
def test_false_alarm_rate_over_many_robots_campaigns(kr270, kr270_params):
    """150 pairs: the number of alarms is Binomial(150, 0.05) if the test holds the 5 % it claims (mean 7.5); its
    central 99.9 % band is [1, 18], so too many alarms (a test too eager) and none at all (a test too cautious,
    P(0) = 0.95^150 = 4.6e-4) both fail."""
    lo, hi = stats.binom.interval(0.999, 150, ALPHA)
    assert (lo, hi) == (1, 18)
    assert lo <= _false_alarms(kr270, kr270_params, range(150)) <= hi


def test_history_command(kr270, kr270_params, tmp_path):
    """The command line over two model files dated by --dates: the sentence names the change and dq2."""
    write_json(tmp_path / "a.json", calibrate(kr270, kr270_params, 501))
    write_json(tmp_path / "b.json", calibrate(kr270, kr270_params, 502, dq2_shift_deg=0.003))
    write_json(tmp_path / "c.json", calibrate(kr270, kr270_params, 503, dq2_shift_deg=0.003))
    done = subprocess.run(
        [
            *TRACKCAL,
            "history",
            "c.json",
            "a.json",
            "b.json",
            "--dates",
            "2026-12-01,2026-04-01,2026-08-01",
            "--json",
            "h.json",
        ],
        cwd=tmp_path,
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stderr
    doc = json.loads((tmp_path / "h.json").read_text())
    assert [c["source"] for c in doc["calibrations"]] == ["a.json", "b.json", "c.json"]  # in time order
    assert doc["steps"][0]["changed"] and not doc["steps"][1]["changed"]
    assert doc["sentence"].startswith("recalibrate: the robot changed since 2026-04-01") and "dq2" in doc["sentence"]
    assert doc["sentence"] in done.stdout.replace("\n", " ") or doc["sentence"][:40] in done.stdout
    # the correction at the test pose: 0.003 deg of dq2 moves the TCP by about 0.1 mm, determined when beyond twice
    # the two calibrations' combined 1-sigma 3-D uncertainty there (calib.tcp_figure; campaign/report/tcp.py)
    a, b = doc["calibrations"][:2]
    assert abs(b["tcp_correction_mm"] - a["tcp_correction_mm"]) > 2.0 * np.hypot(a["tcp_sigma_mm"], b["tcp_sigma_mm"])
    bad = subprocess.run(
        [*TRACKCAL, "history", "a.json", "--dates", "yesterday"], cwd=tmp_path, capture_output=True, text=True
    )
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "--dates" in bad.stderr
