"""The program filter's bound outside the space the model was measured in (issue 38), checked against the twin's TRUTH.

A twin with a joint-dependent hidden effect (an encoder scale error: a joint error proportional to the joint's angle,
mocks.effects) is calibrated from a campaign whose poses stay within +-25 deg of the cell's test pose on every joint.
Inside those ranges the geometric model absorbs most of the effect (its offsets take the mean, the rest is residual
the covariance carries); far outside them, the scale error grows with the distance and no parameter holds it: the
stated bound, the model's own uncertainty, does not cover it. So targets far outside miss their bound more often than
inside ones, and the filter must flag them (how far, per joint) and never call them a pass.
"""

from dataclasses import replace

import numpy as np
import pytest

from tests.calib.test_program_filter import BASE, TOOL, Target, independent_fk, true_flange
from trackcal.calib.doe.design import design_for_cell, random_feasible_poses
from trackcal.calib.model.cell import load_cell
from trackcal.calib.model.params import irreducible_params
from trackcal.calib.model_file import model_from_doc
from trackcal.calib.program_filter import filter_targets
from trackcal.campaign.jobs.identify import run_identify
from trackcal.mocks.twin import Twin, simulate_campaign

HALF_DEG = 25.0  # the campaign's poses: the test pose +- this on every joint
N_TARGETS = 20  # inside and outside each
# configs/cells/ur10.yaml's test pose (deg)
TEST_POSE = np.array([-16.0, -49.0, 59.0, -19.0, -104.0, -12.0])


def narrow_model(seed: int, effect_mm: float):
    """(cell, twin, model, q_campaign rad): the UR10 twin with an encoder scale error of RMS `effect_mm` (what a
    geometric calibration over the full ranges cannot absorb, mocks.twin), calibrated on 30 poses near the test pose."""
    cell = load_cell("ur10")
    twin = Twin(cell, seed=seed, effects={"encoder_scale": effect_mm})
    bounds = np.radians(np.c_[TEST_POSE - HALF_DEG, TEST_POSE + HALF_DEG])
    design = replace(design_for_cell(cell, []), joint_bounds=bounds)
    q = random_feasible_poses(design, 30, np.random.default_rng(seed))
    out = run_identify(cell, simulate_campaign(twin, np.degrees(q)), irreducible_params(cell.chain)[0])
    return cell, twin, model_from_doc(out.doc), q


def true_tcp(twin: Twin, q_rad: np.ndarray) -> np.ndarray:
    """(3,) mm: where the twin's TRUE robot puts TOOL's TCP when commanded q_rad: its hidden joint errors (the encoder
    scale, mocks.effects) on top of its true geometry."""
    q_true = q_rad + twin.hidden.joint_errors(q_rad[None], np.zeros((1, len(q_rad))))[0]
    return (true_flange(twin, q_true) @ TOOL)[:3, 3]


def on_branch(q_deg: np.ndarray):
    """A configuration test accepting only the IK solution at q_deg (the filter then works at the joints drawn)."""
    return lambda cand: bool(np.all(np.abs(cand - q_deg) < 1.0))


def targets_at(q_deg: np.ndarray) -> tuple[list[Target], list[np.ndarray]]:
    poses = [np.linalg.inv(BASE) @ independent_fk("ur10", np.radians(qi)) @ TOOL for qi in q_deg]
    return [Target(False, p, BASE, TOOL, on_branch(qi)) for p, qi in zip(poses, q_deg, strict=True)], poses


def miss_rates(seed: int) -> dict[str, float]:
    """{"inside", "outside"}: the share of filtered targets the twin's TRUE robot puts beyond their stated 95 % bound,
    for N_TARGETS targets within the campaign's joint ranges and N_TARGETS with joints 2 and 3 (shoulder, elbow) 60
    to 90 deg beyond them; the flags checked on the way: every outside target flagged, by how far per joint."""
    _, twin, model, q_campaign = narrow_model(seed, effect_mm=0.05)
    rng = np.random.default_rng(40 + seed)
    inside = TEST_POSE + rng.uniform(-0.6 * HALF_DEG, 0.6 * HALF_DEG, (N_TARGETS, 6))
    outside = TEST_POSE + rng.uniform(-0.6 * HALF_DEG, 0.6 * HALF_DEG, (N_TARGETS, 6))
    beyond = rng.uniform(HALF_DEG + 60.0, HALF_DEG + 90.0, (N_TARGETS, 2)) * rng.choice([-1.0, 1.0], (N_TARGETS, 2))
    outside[:, 1:3] = TEST_POSE[1:3] + beyond
    lo, hi = np.degrees(q_campaign.min(axis=0)), np.degrees(q_campaign.max(axis=0))  # what the table measured
    missed = {}
    for name, q in (("inside", inside), ("outside", outside)):
        targets, poses = targets_at(q)
        res = filter_targets(model, targets, q[0])
        ok = np.flatnonzero(res.ok)
        assert len(ok) >= 0.7 * N_TARGETS, set(res.why)
        miss = np.array(
            [np.linalg.norm(true_tcp(twin, np.radians(res.q_calibrated_deg[i])) - (BASE @ poses[i])[:3, 3]) for i in ok]
        )
        missed[name] = float(np.mean(miss > res.bound95_mm[ok]))
        q_at = res.q_calibrated_deg  # where the robot will be: the joints the filtered targets command
        expected = np.maximum(np.maximum(lo - q_at, q_at - hi), 0.0)
        if name == "outside":
            assert res.extrapolated.all() and res.space_known.all()
            # how far, per joint: the distance of the target's joints from the table's own ranges (its 4 decimals)
            np.testing.assert_allclose(res.outside_joints_deg[ok], expected[ok], atol=1e-3)
            assert np.all(res.outside_joints_deg[:, 1:3].max(axis=1) >= 60.0 - 0.6 * HALF_DEG)
        else:
            assert not (res.outside_joints_deg > 0).any() and not expected[ok].any()  # within the table's ranges
    return missed


def test_targets_far_outside_the_measured_ranges_are_flagged_and_miss_their_bound_more():
    missed = miss_rates(4)
    # the reason for the flag: outside, the stated bound does not hold what the model does not model
    assert missed["outside"] >= 0.4 and missed["outside"] >= missed["inside"] + 0.3, missed


@pytest.mark.slow
def test_outside_targets_miss_more_over_many_twins():
    rates = np.array([[r["inside"], r["outside"]] for r in map(miss_rates, range(10, 20))])
    inside, outside = rates.mean(axis=0)
    assert outside >= inside + 0.2, rates
