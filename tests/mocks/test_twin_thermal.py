"""The twin's thermal growth is a uniform linear expansion of every length of the robot, tool included, about a
pivot its effect chooses (mocks/effects.py), and diagnose names it and recovers its rate for both pivots.

The hidden growth is 4x the tracker noise RMS of what a geometric calibration cannot absorb (the twin's magnitude,
mocks/effects.py), as in tests/test_diagnose.py; the seeds here were not used while writing these tests.
"""

from dataclasses import replace

import numpy as np
import pytest

from trackcal.calib.diagnose import diagnose
from trackcal.calib.diagnose.plausibility import GROWTH_MAX
from trackcal.calib.doe.poses import random_poses
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.model.kinematics import Kinematics
from trackcal.calib.model.params import irreducible_params
from trackcal.mocks.effects import THERMAL_PIVOTS
from trackcal.mocks.twin import Twin, simulate_campaign

NOISE_RMS_MM = 0.015  # AT901 model (calib/identify/noise.py) at 2-4 m: sqrt((5^2 + 2 * 16^2) / 3) um
FORM_OF_PIVOT = {"base": "e_base", "first_joint": "e"}  # calib.extensions.THERMAL_FORMS


def scaled_robot_point(twin: Twin, q_deg: np.ndarray, point: str, factor: float, pivot: str) -> np.ndarray:
    """The reflector of a rigid robot whose every length is `factor` times the twin's: link translations, their
    deviations, the tool point, and the base column when it grows too (pivot at the base origin)."""
    chain = twin.cell.chain
    joints = tuple(replace(j, translation=factor * j.translation) for j in chain.joints)
    base = chain.base.copy()
    if pivot == "base":
        base[:3, 3] *= factor
    dev = np.where([p.is_length for p in twin.params], factor, 1.0) * twin.true_dev
    kin = Kinematics(replace(chain, base=base, joints=joints), twin.params)
    return kin.points(np.radians(q_deg)[None], factor * twin.true_points[point][None], dev)[0]


@pytest.mark.parametrize("pivot", THERMAL_PIVOTS)
def test_twin_growth_is_a_scaled_robot(kr270, pivot):
    twin = Twin(kr270, seed=11, effects={"thermal_drift": 0.05}, thermal_pivot=pivot)
    rate = twin.hidden.thermal_per_s
    assert rate > 0
    q = np.degrees(random_poses(kr270, 5, np.random.default_rng(11)))
    t_s = 1e-3 / rate  # 1000 ppm: far above round-off, so a length left out would show
    for qi in q:
        for pid in sorted(twin.true_points):
            twin.move_to(qi)
            got = twin.point_in_base(qi, pid, t_s)
            want = scaled_robot_point(twin, qi, pid, 1.0 + rate * t_s, pivot)
            np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)  # 3 m at double precision: ~1e-12 mm


def test_unknown_pivot_is_refused(kr270):
    with pytest.raises(ValueError, match="unknown thermal pivot"):
        Twin(kr270, seed=1, effects={"thermal_drift": 0.05}, thermal_pivot="floor")


def diagnosed_rate(cell, seed: int, pivot: str) -> tuple[str, list[str], float, float, float, float]:
    """(cause, thermal form names, fitted rate, its 95 % half-width, true rate, true growth over the campaign's time
    span) of diagnose on a twin campaign."""
    twin = Twin(cell, seed=seed, effects={"thermal_drift": 4.0 * NOISE_RMS_MM}, thermal_pivot=pivot)
    table = simulate_campaign(twin, np.degrees(random_poses(cell, 40, np.random.default_rng(seed))))
    d = diagnose(cell.chain, table, cell.tool_points, irreducible_params(cell.chain)[0], TrackerNoise(), seed=seed)
    truth = twin.hidden.thermal_per_s
    growth = truth * float(table.t_s.max() - table.t_s.min())
    if d.extension is None:
        return d.cause, [], 0.0, 0.0, truth, growth
    at = 0
    for cause, names in d.extension.parts():
        if cause == "thermal_drift":
            return d.cause, names, d.extended.ext[at], d.extended.ext_ci95()[at], truth, growth
        at += len(names)
    return d.cause, [], 0.0, 0.0, truth, growth


@pytest.mark.parametrize("pivot", THERMAL_PIVOTS)
def test_diagnose_names_thermal_drift_and_recovers_its_rate(kr270, pivot):
    cause, names, rate, ci, truth, _ = diagnosed_rate(kr270, 4100 + THERMAL_PIVOTS.index(pivot), pivot)
    assert cause == "thermal_drift"
    assert names == [FORM_OF_PIVOT[pivot]]  # the data choose the twin's pivot
    assert abs(rate - truth) < ci


@pytest.mark.slow
@pytest.mark.parametrize("pivot", THERMAL_PIVOTS)
def test_thermal_rate_interval_covers_the_truth_many_seeds(kr270, pivot):
    """Over 10 seeds the cause and the form must be right every time the twin's growth is physical, and refused
    (unexplained) when it is beyond the 500 ppm a warming arm reaches over a campaign (GROWTH_MAX,
    calib/diagnose/plausibility.py): seed 4205 about the first joint grows 514 ppm over its 2800 s. Of n named
    seeds, 95 % intervals cover the true rate fewer than n - 2 times with probability 1.2 % for n = 10, 0.8 % for
    n = 9 (binomial, p = 0.95)."""
    runs = [diagnosed_rate(kr270, seed, pivot) for seed in range(4200, 4210)]
    named = [run for run in runs if abs(run[5]) <= GROWTH_MAX]
    assert all(c == "unexplained" for c, *_, growth in runs if abs(growth) > GROWTH_MAX), runs
    assert all(c == "thermal_drift" and n == [FORM_OF_PIVOT[pivot]] for c, n, *_ in named), runs
    assert sum(abs(r - t) < ci for _, _, r, ci, t, _ in named) >= len(named) - 2, runs
