"""The filter's 95 % bound when the model's form is not the robot's (calib.lack_of_fit, issue 38), checked against the
TRUTH: the twin's true robot (its true geometry and its hidden effects), never the model.

The KR-270 twin with joint compliance: every joint deflects by its compliance times the gravity torque of the TRUE
masses, which differ from the robot config's (the ones the model's `joint_compliance` extension computes its torques
with) by ~15 % and whose centres of mass are ~20 mm off (mocks.effects): the extension has the right cause but not the
robot's exact form, so the identified model is wrong at every pose by what its form cannot absorb. The parameters'
covariance does not hold that; the fit's residual beyond the tracker's noise floor does (calib.lack_of_fit).

Coverage is counted per target: the lack of fit is the misfit's spread over the poses, a different draw at each target
(the parameters' error, shared by one model's targets, is the smaller part here); the slow test also takes the
conservative interval with one trial per campaign (test_program_filter.coverage_interval).
"""

import numpy as np
import pytest
from scipy.stats import binom

from tests.calib.test_extension_uncertainty import scaled, true_tcp
from tests.calib.test_program_filter import BASE, TOOL, Target, coverage_interval, independent_fk, kuka_config
from trackcal.calib.doe.design import design_for_cell, random_feasible_poses
from trackcal.calib.errors import CalibError
from trackcal.calib.lack_of_fit import KEYS, lack_of_fit_variance
from trackcal.calib.model.cell import load_cell
from trackcal.calib.model.params import irreducible_params
from trackcal.calib.model_file import model_from_doc
from trackcal.calib.program_filter import filter_targets
from trackcal.campaign.jobs.identify import run_identify
from trackcal.mocks.twin import Twin, simulate_campaign

ONE_AXIS_95 = 1.959964  # the normal law's 97.5 % point (a table of the normal law): |x| <= it with 95 %, x ~ N(0, 1)


def compliant(seed: int, magnitude_mm: float = 0.3):
    """(twin, model) of the KR-270 twin with joint compliance of RMS `magnitude_mm` (its true masses off the config's,
    mocks.effects), identified with the joint_compliance extension on 40 poses."""
    cell = load_cell("kr270")
    twin = Twin(cell, seed=seed, effects={"joint_compliance": magnitude_mm})
    q = random_feasible_poses(design_for_cell(cell, []), 40, np.random.default_rng(seed))
    out = run_identify(
        cell, simulate_campaign(twin, np.degrees(q)), irreducible_params(cell.chain)[0], extend="joint_compliance"
    )
    return twin, model_from_doc(out.doc)


def without_lack_of_fit(model):
    """The same model as one written before its residual and noise floor were recorded: no lack of fit."""
    stripped = model_from_doc(model.doc)
    stripped.doc = {k: v for k, v in model.doc.items() if k not in KEYS}
    return stripped


def filtered_misses(twin, model, n: int, seed: int):
    """(miss, bound) (mm) of n random targets inside the measured poses' distribution (the design's random feasible
    poses, as the campaign's), filtered: the miss is the TRUE robot's TCP at the commanded joints from the intended."""
    cell = twin.cell
    q = random_feasible_poses(design_for_cell(cell, []), n, np.random.default_rng(500 + seed))
    q = q[np.abs(q[:, 4]) > 0.3]  # away from the wrist singularity (A5 = 0)
    poses = [np.linalg.inv(BASE) @ independent_fk("kr270", qi) @ TOOL for qi in q]
    res = filter_targets(model, [Target(False, p, BASE, TOOL, kuka_config) for p in poses], np.degrees(q[0]))
    ok = np.flatnonzero(res.ok & ~res.extrapolated)  # the bound is claimed inside the measured space only
    miss = [np.linalg.norm(true_tcp(twin, np.radians(res.q_calibrated_deg[i])) - (BASE @ poses[i])[:3, 3]) for i in ok]
    return np.array(miss), res.bound95_mm[ok], res


def per_target_floor(n: int) -> float:
    """The 99.9 % binomial lower limit of a 95 % coverage over n independent targets."""
    return binom.ppf(0.0005, n, 0.95) / n


def test_the_lack_of_fit_is_the_residual_variance_beyond_the_noise_floor():
    # a 3-4-5 triangle: residual 0.05 mm, floor 0.03 mm: the misfit is 0.04 mm per coordinate
    assert lack_of_fit_variance({"residual_rms_mm": 0.05, "noise_floor_mm": 0.03}) == pytest.approx(0.04**2)
    assert lack_of_fit_variance({"residual_rms_mm": 0.029, "noise_floor_mm": 0.03}) == 0.0  # at the noise: none
    assert lack_of_fit_variance({"noise_floor_mm": 0.03}) is None  # not recorded
    for bad in (float("nan"), -1.0, "0.05", True):
        with pytest.raises(CalibError, match="residual_rms_mm"):
            lack_of_fit_variance({"residual_rms_mm": bad, "noise_floor_mm": 0.03})


def test_mismatched_compliance_targets_land_within_their_bound():
    twin, model = compliant(21)
    miss, bound, res = filtered_misses(twin, model, 40, 21)
    s = np.sqrt(model.doc["residual_rms_mm"] ** 2 - model.doc["noise_floor_mm"] ** 2)
    assert res.lack_of_fit_mm == pytest.approx(s) and s > 0.5 * model.doc["noise_floor_mm"]
    # every target's 95 % radius holds at least the misfit's alone, all along one axis (the worst direction): the
    # normal law's 97.5 % point 1.95996 times its 3-D RMS sqrt(3) s
    assert np.all(bound >= ONE_AXIS_95 * np.sqrt(3) * s * (1 - 1e-9))
    assert len(miss) >= 25 and np.mean(miss <= bound) >= per_target_floor(len(miss)), (np.sum(miss <= bound), len(miss))
    # without the lack of fit, the bound is the parameters' uncertainty alone: it covers far fewer than 95 %
    miss0, bound0, res0 = filtered_misses(twin, without_lack_of_fit(model), 40, 21)
    assert np.mean(miss0 <= bound0) < 0.6 and any("lack of fit" in w for w in res0.warnings)


def test_a_model_of_the_right_form_s_bound_grows_by_its_residual_excess_only():
    """The KR-270 twin with hidden encoder scales, identified with the encoder_scale extension: the model's form is
    the robot's, its fit at the noise floor up to the noise's chance; the bound grows by what the excess warrants."""
    _, twin, model, _ = scaled(21)
    rms, floor = model.doc["residual_rms_mm"], model.doc["noise_floor_mm"]
    assert rms < 1.2 * floor  # the right form: at the noise floor (up to chance)
    s2 = max(rms**2 - floor**2, 0.0)
    miss, bound, res = filtered_misses(twin, model, 30, 21)
    miss0, bound0, _ = filtered_misses(twin, without_lack_of_fit(model), 30, 21)
    np.testing.assert_array_equal(miss, miss0)  # the same commanded joints: only the bound changes
    assert np.all(bound >= bound0 - 1e-12)
    predicted = res.predicted_mm[res.ok & ~res.extrapolated]  # ~0 for a filtered target; the radius is on top
    bound, bound0 = bound - predicted, bound0 - predicted
    # the parameters' radius and the misfit's, all its 3 s2 along one axis (1.95996 sqrt(3) s: the normal law's 97.5 %
    # point), in quadrature: the bound grows by the residual excess's own radius and no more
    np.testing.assert_allclose(bound**2, bound0**2 + 3 * ONE_AXIS_95**2 * s2, rtol=1e-9, atol=1e-12)
    assert np.mean(miss <= bound) >= per_target_floor(len(miss))


@pytest.mark.slow  # ten identifications with an extension and ~200 targets: ~2 min
def test_mismatched_compliance_coverage_over_many_campaigns():
    hits, hits0, n, groups = 0, 0, 0, 0
    for seed in range(30, 40):
        twin, model = compliant(seed)
        miss, bound, _ = filtered_misses(twin, model, 30, seed)
        miss0, bound0, _ = filtered_misses(twin, without_lack_of_fit(model), 30, seed)
        hits, hits0 = hits + np.sum(miss <= bound), hits0 + np.sum(miss0 <= bound0)
        n, groups = n + len(miss), groups + 1
    lo, hi = coverage_interval(n, groups)
    assert lo <= hits / n <= hi and hits / n >= per_target_floor(n), (hits, n)
    assert hits0 / n < 0.6, (hits0, n)
