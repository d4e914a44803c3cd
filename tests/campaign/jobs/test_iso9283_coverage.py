"""Stated = delivered for the certificate's U: over many twins (seeds), the Monte-Carlo 95 % interval of AP_P that the
budget states (campaign.jobs.iso9283_budget, calib.uncertainty_budget) holds the twin's TRUE AP_P about 95 % of the
time. Each seed is a whole acceptance test: a calibration campaign on the twin identified into a model (model.json's
document, its 95 % intervals the budget reads), then the ISO cube's P1 measured over its cycles from the model's
station and expressed in the model's base frame as `iso9283 compare` does. The truth is the twin's, never the
measured data's: |the true point at the commanded joints - the nominal chain's position of the TRUE tool point| (the
twin's robot returns to the same joints: its AP is that distance exactly). After compensation (`iso9283 plan --model`:
the joints are calib.compensate's targets for the same commanded positions) the true AP is a few µm, the size of the
noise, where |o| is biased upward (calib.uncertainty_budget's docstring)."""

import numpy as np
import pytest

from trackcal.calib.compensate import compensate
from trackcal.calib.doe.iso_cube import CORNER_FRACTION, iso_plan
from trackcal.calib.doe.poses import random_poses
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.identify.solver import identify
from trackcal.calib.iso9283 import pose_accuracy, pose_repeatability
from trackcal.calib.model.cell import load_cell
from trackcal.calib.model.kinematics import Kinematics
from trackcal.calib.model.params import irreducible_params
from trackcal.calib.model_file import identification_to_doc, model_from_doc
from trackcal.calib.uncertainty_budget import ap_budget, pose_inputs
from trackcal.campaign.jobs.iso9283_budget import BudgetContext
from trackcal.mocks.twin import REFERENCE_POSES, Twin, simulate_campaign

CYCLES = 10  # the standard's 30 (ISO 9283:1998, 6.9) would only shrink the tracker's line; 10 keep a seed short


@pytest.fixture(scope="module")
def setting():
    cell = load_cell("kr270")
    return cell, iso_plan(cell, None, None, CORNER_FRACTION, 0)


def covered(cell, plan, seed: int, compensated: bool = False) -> bool:
    """One twin's acceptance test of P1 (with the model's compensated joints: the "after" test): does the stated
    interval hold the true AP_P?"""
    noise = TrackerNoise.of(cell.tracker)
    twin = Twin(cell, seed=seed)
    table = simulate_campaign(twin, np.degrees(random_poses(cell, REFERENCE_POSES, np.random.default_rng(seed))))
    res = identify(cell.chain, table, cell.tool_points, irreducible_params(cell.chain)[0], noise=noise)
    model = model_from_doc(identification_to_doc(res))
    q_nom = plan.q_rad[:1]
    if compensated:  # as campaign.jobs.iso9283.make_plan does with --model
        q_nom, _ = compensate(model, q_nom, cell.tcp, max_correction=(cell.max_correction_mm, cell.max_correction_deg))
    q_deg = np.round(np.degrees(q_nom), 4)  # P1, as the plan writes its joints
    kin = Kinematics(cell.chain, [])
    rot, _ = kin.end_frames(plan.q_rad[:1])  # the commanded orientation: the nominal chain at the nominal joints
    st = model.stations[plan.station]
    y = np.array([twin.measure(q_deg[0], plan.point, plan.station, f"iso/P1/{j}") for j in range(CYCLES)])
    x = (y - st.translation) @ st.rotation
    covs = np.einsum("ji,njk,kl->nil", st.rotation, noise.covariance(y), st.rotation)
    commanded = kin.points(plan.q_rad[:1], model.points[plan.point])[0]
    _, offset = pose_accuracy(x, commanded, covs)
    context = BudgetContext(model, plan.station, plan.point, rot, noise.name, None, None)
    lo, hi = ap_budget(offset, pose_inputs(x, covs, context.setting(0, y))).interval
    true_ap = np.linalg.norm(
        twin.point_in_base(q_deg[0], plan.point) - kin.points(plan.q_rad[:1], twin.true_points[plan.point])[0]
    )
    assert pose_repeatability(x)[0].value < 0.1  # the twin's robot does return: RP is tracker noise
    return bool(lo <= true_ap <= hi)


def test_ap_interval_covers_the_twins_truth(setting):
    """20 twins: at a true coverage of 95 % the count covered is Binomial(20, 0.95), and P(count <= 15) =
    C(20,5) 0.05^5 0.95^15 + C(20,6) 0.05^6 0.95^14 + ... = 0.00225 + 0.00030 + ... < 0.3 %: 16 or more must be covered.
    The tracker's U alone (main before #39) held it in 14 of these 20: it fails this test."""
    cell, plan = setting
    hits = sum(covered(cell, plan, seed) for seed in range(1, 21))
    assert hits >= 16, hits


@pytest.mark.slow
def test_ap_interval_covers_the_twins_truth_over_200_seeds(setting):
    """200 twins: Binomial(200, 0.95) has mean 190 and standard deviation sqrt(200 * 0.95 * 0.05) = 3.08; 181 to 199
    (about -3 sigma, and short of all 200, whose probability is 0.95^200 = 3.5e-5) hold it with more than 99.5 %: an
    interval too narrow (below ~0.90) or degenerate-wide (always covering) fails. Measured: 197 of 200."""
    cell, plan = setting
    hits = sum(covered(cell, plan, seed) for seed in range(1, 201))
    assert 181 <= hits <= 199, hits


def test_ap_interval_covers_the_twins_truth_after_compensation(setting):
    """10 twins after compensation, where the true AP is a few µm: at a coverage of 95 % the count covered is
    Binomial(10, 0.95), P(count <= 7) = 1 - 0.95^10 - 10 0.05 0.95^9 - 45 0.05^2 0.95^8 = 1.2 %: 8 or more must be
    covered. The plug-in Monte-Carlo interval of |o_measured + E| (before this test) held it in 6 of these 10."""
    cell, plan = setting
    hits = sum(covered(cell, plan, seed, compensated=True) for seed in range(1, 11))
    assert hits >= 8, hits


@pytest.mark.slow
def test_ap_interval_covers_the_twins_truth_after_compensation_over_200_seeds(setting):
    """200 twins after compensation: at a coverage of at least 95 % the count covered is at least Binomial(200, 0.95),
    mean 190, standard deviation 3.08: 181 or more (about -3 sigma) with more than 99.5 %. No upper bound here: the
    budget is conservative after compensation (the station's components taken independent, calib.uncertainty_budget's
    docstring), and an interval covering always would still show in the default test's widths. Measured on 60 seeds:
    60 covered (the plug-in interval before: 40)."""
    cell, plan = setting
    hits = sum(covered(cell, plan, seed, compensated=True) for seed in range(1, 201))
    assert hits >= 181, hits
