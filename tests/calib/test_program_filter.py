"""Program filtering (calib.program_filter) checked against the truth: the twin's TRUE robot, an independent forward
kinematics written here from the robot's YAML, and the binomial law of a 95 % interval's coverage.

The filtered target, sent through the controller's nominal inverse kinematics in the same configuration, gives the
joints q_cal; the twin's true robot at q_cal must put the TCP within the stated 95 % bound of the intended pose in
about 95 % of the targets, and the unfiltered target (q_nom) must not. Each campaign gives one identified model, whose
error is one draw for all its targets, so the targets of one model are not independent: the coverage is counted per
(campaign, target) over several campaigns, and its acceptance interval is the binomial one widened for that (below).
"""

import functools
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation
from scipy.stats import binom

from trackcal.calib.doe.design import design_for_cell, random_feasible_poses
from trackcal.calib.model.cell import load_cell
from trackcal.calib.model.params import irreducible_params
from trackcal.calib.model_file import model_from_doc
from trackcal.calib.program_filter import UNUSED, filter_targets, radius95
from trackcal.campaign.jobs.identify import run_identify
from trackcal.drivers.program_text import ProgramRead, ProgramTarget
from trackcal.mocks.twin import Twin, simulate_campaign

CONFIGS = Path(__file__).resolve().parents[2] / "configs" / "robots"


@dataclass
class Target:
    """A program's target as the filter sees it (drivers.program_text.ProgramTarget's fields it reads)."""

    joint: bool
    value: np.ndarray
    base: np.ndarray
    tool: np.ndarray
    config: object = field(default=None)  # accepts(q_deg) -> bool, None: any
    motion: str = "PTP"  # a move uses it

    def accepts(self, q_deg) -> bool:
        return True if self.config is None else bool(self.config(q_deg))


@functools.lru_cache
def robot_doc(robot: str) -> dict:
    return yaml.safe_load((CONFIGS / f"{robot}.yaml").read_text())


def independent_fk(robot: str, q_rad: np.ndarray) -> np.ndarray:
    """(4, 4) flange pose (mm) of the NOMINAL robot `robot` at q_rad, from configs/robots/ROBOT.yaml with scipy's
    rotations: base, then per joint Rot(axis, q) Trans(link_mm) Rot(link_rpy_deg) (URDF rpy: Rz(y) Ry(p) Rx(r), the
    YAML schema of configs/robots)."""
    doc = robot_doc(robot)
    out = np.eye(4)
    out[:3, 3] = (doc.get("base") or {}).get("translation_mm", [0, 0, 0])
    for jd, j in zip(doc["joints"], q_rad, strict=True):
        sign = -1.0 if jd["axis"].startswith("-") else 1.0
        turn = np.eye(4)
        turn[:3, :3] = Rotation.from_euler(jd["axis"][-1], sign * j).as_matrix()
        link = np.eye(4)
        link[:3, 3] = jd.get("link_mm", [0, 0, 0])
        link[:3, :3] = Rotation.from_euler("xyz", jd.get("link_rpy_deg", [0, 0, 0]), degrees=True).as_matrix()
        out = out @ turn @ link
    return out


def true_flange(twin: Twin, q_rad: np.ndarray) -> np.ndarray:
    """(4, 4) the twin's TRUE robot's flange at q_rad (its hidden deviations: mocks.twin)."""
    r, o = twin.kin.end_frames(q_rad[None], twin.true_dev)
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = r[0], o[0]
    return out


def frame(rotvec, xyz) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = Rotation.from_rotvec(rotvec).as_matrix(), xyz
    return out


# a user frame 0.7 m out, turned 40 deg about z and tilted; a tool 180 mm long, 30 mm off the flange axis, tilted
BASE = frame([0.05, -0.1, 0.7], [700.0, -250.0, 120.0])
TOOL = frame([0.2, 0.0, 0.3], [30.0, -10.0, 180.0])


def identified(cell_name: str, seed: int, poses: int = 30):
    """(cell, twin, model): a model identified from a simulated campaign of `poses` random feasible poses on the twin
    of `seed` (its deviations drawn, or the paper's Table 8 for the KR-270)."""
    cell = load_cell(cell_name)
    twin = Twin(cell, seed=seed)
    q = np.degrees(random_feasible_poses(design_for_cell(cell, []), poses, np.random.default_rng(seed)))
    out = run_identify(cell, simulate_campaign(twin, q), irreducible_params(cell.chain)[0])
    return cell, twin, model_from_doc(out.doc)


def misses(robot: str, cell, twin, model, n: int, seed: int, config=None):
    """(filtered miss, unfiltered miss, 95 % bound) (mm) of the targets filtered: n random reachable Cartesian targets
    in BASE with TOOL; the miss is the distance from the intended TCP to where the TRUE robot puts it."""
    q = random_feasible_poses(design_for_cell(cell, []), n, np.random.default_rng(1000 + seed))
    poses = [np.linalg.inv(BASE) @ independent_fk(robot, qi) @ TOOL for qi in q]
    targets = [Target(False, p, BASE, TOOL, config) for p in poses]
    res = filter_targets(model, targets, np.degrees(q[0]))
    ok = res.ok
    assert ok.mean() > 0.8, set(res.why)  # random poses: a few near a singularity or with large corrections are kept
    out = []
    for i in np.flatnonzero(ok):
        q_cal, q_nom = np.radians(res.q_calibrated_deg[i]), np.radians(res.q_nominal_deg[i])
        # q_cal is what the nominal controller turns the filtered target into: its nominal flange is B P' T^-1
        np.testing.assert_allclose(independent_fk(robot, q_cal), BASE @ res.values[i] @ np.linalg.inv(TOOL), atol=1e-6)
        # and q_nom is the nominal IK of the intended target (independent FK)
        np.testing.assert_allclose(independent_fk(robot, q_nom), BASE @ poses[i] @ np.linalg.inv(TOOL), atol=1e-6)
        intended = (BASE @ poses[i])[:3, 3]
        out.append(
            [
                np.linalg.norm((true_flange(twin, q_cal) @ TOOL)[:3, 3] - intended),
                np.linalg.norm((true_flange(twin, q_nom) @ TOOL)[:3, 3] - intended),
                res.bound95_mm[i],
            ]
        )
    return np.array(out).T


def coverage_interval(trials: int, groups: int) -> tuple[float, float]:
    """The 99.9 % acceptance interval of a 95 % coverage over `trials` targets drawn from `groups` models: binomial,
    with the effective sample size of the groups (the targets of one model share its error: at worst one trial per
    model, so the interval is taken for `groups` trials, the conservative side)."""
    lo, hi = binom.ppf([0.0005, 0.9995], groups, 0.95)
    return lo / groups, hi / groups


def test_the_95_radius_is_the_normal_law_s():
    # isotropic 3-D: |x| / sigma is chi with 3 degrees of freedom, its 95 % quantile sqrt(7.8147) = 2.7955
    # (chi-square table, 3 dof, 0.95); one axis only: 1.95996 sigma (the normal law's 97.5 % point)
    cov = np.array([np.eye(3) * 0.04, np.diag([0.0, 0.0, 0.25])])
    np.testing.assert_allclose(radius95(cov), [2.7955 * 0.2, 1.95996 * 0.5], rtol=5e-3)


def test_ur10_filtered_targets_reach_the_intended_pose_within_the_stated_bound():
    hits, unfiltered, n = 0, 0, 0
    seeds = (1, 2, 3)
    for seed in seeds:
        cell, twin, model = identified("ur10", seed)
        miss, miss0, bound = misses("ur10", cell, twin, model, 30, seed)
        hits, unfiltered, n = hits + np.sum(miss <= bound), unfiltered + np.sum(miss0 <= bound), n + len(miss)
    lo, hi = coverage_interval(n, len(seeds))
    assert lo <= hits / n <= hi, (hits, n)
    assert unfiltered / n < 0.2  # uncorrected, the TCP is off by the robot's ~1 mm, far beyond the bound


@pytest.mark.slow
def test_ur10_coverage_over_many_campaigns():
    hits, n, groups = 0, 0, 0
    for seed in range(10, 40):
        cell, twin, model = identified("ur10", seed)
        miss, _, bound = misses("ur10", cell, twin, model, 30, seed)
        hits, n, groups = hits + np.sum(miss <= bound), n + len(miss), groups + 1
    lo, hi = coverage_interval(n, groups)
    assert lo <= hits / n <= hi, (hits, n)


def kuka_config(q_deg) -> bool:
    """A KRL-like configuration bit: the wrist flipped or not (A5 > 0), as a status word S's bit 2 says."""
    return q_deg[4] > 0


def test_kr270_cartesian_and_joint_targets_in_a_configuration():
    cell, twin, model = identified("kr270", 5)
    miss, miss0, bound = misses("kr270", cell, twin, model, 30, 5, config=kuka_config)
    assert np.mean(miss <= bound) >= 0.8 and np.mean(miss0 <= bound) < 0.2
    # a joint target: corrected in joint space, the true robot reaches the nominal robot's pose at the target
    q = random_feasible_poses(design_for_cell(cell, []), 6, np.random.default_rng(7))
    q = q[np.abs(q[:, 4]) > 0.3]  # away from the wrist singularity (A5 = 0)
    targets = [Target(True, np.degrees(qi), np.eye(4), TOOL) for qi in q]
    res = filter_targets(model, targets, np.degrees(q[0]))
    for i, qi in enumerate(q):
        assert not res.why[i], res.why[i]
        intended = (independent_fk("kr270", qi) @ TOOL)[:3, 3]
        reached = (true_flange(twin, np.radians(res.values[i])) @ TOOL)[:3, 3]
        assert np.linalg.norm(reached - intended) <= max(res.bound95_mm[i], 0.05)


def test_the_configuration_chooses_the_solution():
    cell, _, model = identified("kr270", 5)
    q = np.radians([10.0, -80.0, 100.0, 30.0, 40.0, -20.0])  # A5 = +40 deg: one wrist configuration
    pose = np.linalg.inv(BASE) @ independent_fk("kr270", q) @ TOOL
    for flip in (kuka_config, lambda qd: qd[4] < 0):
        res = filter_targets(model, [Target(False, pose, BASE, TOOL, flip)], np.degrees(q))
        assert flip(res.q_nominal_deg[0]) and not res.why[0]
        np.testing.assert_allclose(
            independent_fk("kr270", np.radians(res.q_nominal_deg[0])), BASE @ pose @ np.linalg.inv(TOOL), atol=1e-6
        )


def test_unreachable_and_singular_targets_are_kept_with_the_reason():
    cell, _, model = identified("ur10", 1)
    far = frame([0.0, 0.0, 0.0], [5000.0, 0.0, 0.0])  # 5 m out: the UR10 reaches 1.3 m (its data sheet)
    # the wrist singularity: q5 = 0 puts joints 4 and 6 on one axis
    singular = np.linalg.inv(BASE) @ independent_fk("ur10", np.radians([10, -70, 80, -100, 0, 30])) @ TOOL
    res = filter_targets(
        model, [Target(False, far, BASE, TOOL), Target(False, singular, BASE, TOOL)], [0, -90, 90, -90, -90, 0]
    )
    assert res.values == [None, None]
    assert res.why[0].startswith("unreachable")
    # kept: near the singularity, or its correction diverges (beyond the limits or the cell's max_correction)
    assert re.search(r"singular|max_correction|leaves the joint limits|did not converge", res.why[1]), res.why[1]
    assert np.isnan(res.bound95_mm[0]) and np.isfinite(res.bound95_mm[1])


def test_a_target_no_move_uses_is_kept_not_corrected_in_default_frames():
    """A declared pose no move of the given files uses has no known tool and base (a reader gives it the
    language's defaults); correcting it in those frames would move it by the wrong correction: it is kept."""
    cell, _, model = identified("ur10", 1)
    q = np.radians([10, -70, 80, -100, 60, 30])
    pose = np.linalg.inv(BASE) @ independent_fk("ur10", q) @ TOOL
    res = filter_targets(
        model, [Target(False, pose, BASE, TOOL, motion=""), Target(False, pose, BASE, TOOL)], np.degrees(q)
    )
    assert res.values[0] is None and res.why[0] == UNUSED
    assert res.values[1] is not None and not res.why[1]


def test_a_synthetic_kuka_program_read_is_filtered_and_written():
    """The shape the KRL reader returns (drivers.program_text), built here by hand for the KR-270: an E6AXIS-like
    joint target, an E6POS-like one in a base with a tool and a configuration, an unreachable one."""
    cell, twin, model = identified("kr270", 5)
    q_axis = np.array([5.0, -70.0, 95.0, 10.0, 35.0, -15.0])
    q_pos = np.radians([20.0, -85.0, 105.0, -20.0, 50.0, 30.0])
    pos = np.linalg.inv(BASE) @ independent_fk("kr270", q_pos) @ TOOL
    far = frame([0, 0, 0], [9000.0, 0.0, 0.0])  # 9 m: the KR 270 reaches 2.7 m (its data sheet)
    text = "HOME: AXIS\nP1: POS\nP2: POS\n"

    def target(i, joint, value):
        start = text.index(":", sum(len(x) + 1 for x in text.splitlines()[:i])) + 2
        end = text.index("\n", start)
        return ProgramTarget(
            file="a.src",
            start=start,
            end=end,
            line=i + 1,
            name=f"P{i}",
            joint=joint,
            value=value,
            base=np.eye(4) if joint else BASE,
            tool=TOOL,
            config=(2,),
            accepts=kuka_config,
            render=lambda v: "NEW",
            motion="PTP",
        )

    read = ProgramRead(
        "KRL", {"a.src": text}, [target(0, True, q_axis), target(1, False, pos), target(2, False, far)], ";"
    )
    res = filter_targets(model, read.targets, q_axis)
    assert res.why[0] == res.why[1] == "" and res.why[2].startswith("unreachable")
    out = read.write({i: v for i, v in enumerate(res.values) if v is not None}, {2: res.why[2]})["a.src"]
    assert out.splitlines()[:2] == ["HOME: NEW", "P1: NEW"] and out.splitlines()[2].startswith("P2: POS ; unreachable")
    reached = (true_flange(twin, np.radians(res.q_calibrated_deg[1])) @ TOOL)[:3, 3]
    assert np.linalg.norm(reached - (BASE @ pos)[:3, 3]) <= max(res.bound95_mm[1], 0.05)
    assert kuka_config(res.q_nominal_deg[1])


def test_a_model_without_covariance_says_its_bounds_hold_no_uncertainty():
    cell, _, model = identified("ur10", 1)
    model.doc = {k: v for k, v in model.doc.items() if k != "covariance"}
    q = np.radians([-16.0, -49.0, 59.0, -19.0, -104.0, -12.0])  # the cell's test pose (configs/cells/ur10.yaml)
    res = filter_targets(model, [Target(True, np.degrees(q), np.eye(4), TOOL)], np.degrees(q))
    # what remains is the model's lack of fit alone (calib.lack_of_fit: its misfit, 3 s^2 over the three coordinates)
    assert res.sigma_mm[0] == pytest.approx(np.sqrt(3.0) * res.lack_of_fit_mm, abs=1e-12)
    assert any("no covariance" in w for w in res.warnings)
