"""issue 25: the model diagnose chooses never predicts unseen poses worse than the geometric model.

Each campaign is a twin (mocks/twin.py) with one hidden effect of the twin (or none), 15-60 random poses and a tracker
1-1.5x noisier than its model; diagnose runs on it, and both the geometric model and the chosen one (as model.json
holds them, through `predict`'s code) predict fresh poses of the same twin (same seed: the same robot, stations,
points and effect; new random poses, noise-free, so what is compared is the models and not the noise of the check).

Tolerance: the fresh poses are a sample. Per fresh pose the difference of the two models' mean squared errors is
one draw; the chosen model may be worse on average by at most two standard errors of the mean of these draws (the
paired standard error of the difference over the held-out set), and otherwise not at all.
"""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from trackcal.calib.diagnose import diagnose
from trackcal.calib.diagnose.extensions import CAUSES
from trackcal.calib.doe.poses import random_poses
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.model.cell import load_cell
from trackcal.calib.model.params import irreducible_params
from trackcal.calib.model_file import model_from_doc, predict_table
from trackcal.campaign.jobs.identify import model_doc
from trackcal.mocks.twin import Twin, simulate_campaign

CELL = load_cell("kr270")
PARAMS = irreducible_params(CELL.chain)[0]
FRESH_POSES = 40


def fresh_errors(effect: str, magnitude_mm: float, n_poses: int, seed: int, noise_factor: float = 1.0):
    """(diagnosis, squared prediction error of each fresh row for the geometric and the chosen model, fresh pose
    label of each row)."""
    noise = TrackerNoise(0.005 * noise_factor, 0.0075 * noise_factor, 0.003 * noise_factor)
    twin = Twin(CELL, seed=seed, effects={} if effect == "none" else {effect: magnitude_mm}, noise=noise)
    table = simulate_campaign(twin, np.degrees(random_poses(CELL, n_poses, np.random.default_rng(seed))))
    d = diagnose(CELL.chain, table, CELL.tool_points, PARAMS, TrackerNoise())
    poses = np.degrees(random_poses(CELL, FRESH_POSES, np.random.default_rng([seed, 25])))
    fresh = simulate_campaign(twin, poses, noise_free=True)
    errors = []
    for res, shift in ((d.geometric, None), (d.extended or d.geometric, d.shift)):
        model = model_from_doc(model_doc(CELL, d.table, res, d.geometric, shift, None))
        errors.append(np.sum((predict_table(model, fresh).xyz - fresh.xyz) ** 2, axis=1))
    return d, errors[0], errors[1], np.array(fresh.pose)


def worse_beyond_tolerance(geo: np.ndarray, chosen: np.ndarray, poses: np.ndarray) -> tuple[bool, str]:
    """Is the chosen model worse than the geometric one by more than two paired standard errors (module docstring)?"""
    diff = np.array([np.mean(chosen[poses == p] - geo[poses == p]) for p in np.unique(poses)])
    se = diff.std(ddof=1) / np.sqrt(len(diff))
    rms_g, rms_c = np.sqrt(np.mean(geo) / 3) * 1000, np.sqrt(np.mean(chosen) / 3) * 1000
    why = (
        f"fresh-pose RMS {rms_c:.1f} um (chosen) against {rms_g:.1f} um (geometric), mean difference "
        f"{diff.mean():.3g} mm^2, standard error {se:.3g}"
    )
    return bool(diff.mean() > 2 * se), why


@pytest.mark.parametrize(
    ("effect", "magnitude_mm", "n_poses", "seed"),
    [
        ("cyclic_error", 0.05, 30, 3),  # was encoder_scale + cyclic_error: 6979 um on these fresh poses against 164 um
        ("cyclic_error", 0.03, 15, 215),  # was cyclic_error: 170 um against 115 um
    ],
)
def test_cases_that_predicted_unseen_poses_worse(effect, magnitude_mm, n_poses, seed):
    """Before issue 25 these campaigns were given a cause whose model predicted fresh poses worse than geometry:
    the pose folds could not identify the model, and the folds by time block it fell back on hold out rows whose
    poses the training rows had seen (other points, other stations)."""
    d, geo, chosen, _ = fresh_errors(effect, magnitude_mm, n_poses, seed)
    assert np.mean(chosen) <= np.mean(geo), (d.cause, np.sqrt(np.mean(chosen) / 3), np.sqrt(np.mean(geo) / 3))


def campaigns():
    # magnitudes 2x to 5x the tracker's ~15 um per coordinate (README: what diagnose is measured on)
    return st.tuples(
        st.sampled_from(("none", *CAUSES)),
        st.floats(0.03, 0.075),
        st.integers(15, 60),
        st.integers(0, 2**16),
        st.floats(1.0, 1.5),
    )


def check_campaign(case) -> None:
    effect, magnitude_mm, n_poses, seed, noise_factor = case
    d, geo, chosen, poses = fresh_errors(effect, magnitude_mm, n_poses, seed, noise_factor)
    worse, why = worse_beyond_tolerance(geo, chosen, poses)
    assert not worse, f"{case}: {d.cause} {[c['cause'] for c in d.causes]}: {why}"


@pytest.mark.slow  # a statistical acceptance check, among make test's slowest (issue 37): make test-slow
@settings(max_examples=3, suppress_health_check=[HealthCheck.too_slow])
@given(case=campaigns())
def test_chosen_model_never_predicts_unseen_poses_worse(case):
    check_campaign(case)


@pytest.mark.slow
@settings(max_examples=60, suppress_health_check=[HealthCheck.too_slow])
@given(case=campaigns())
def test_chosen_model_never_predicts_unseen_poses_worse_many(case):
    check_campaign(case)
