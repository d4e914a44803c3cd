"""The UR10 campaign cell (configs/cells/ur10.yaml): its plan parameters are identifiable, its tool and test pose fit
its box, and a planned campaign runs on the twin (`trackcal run --sim --cell ur10`)."""

import json
import subprocess

import numpy as np
import pytest

from tests.helpers import TRACKCAL, feasible_plan
from trackcal.calib.doe.poses import points_in_box
from trackcal.calib.model.cell import load_cell
from trackcal.calib.model.identifiability import numerical_rank, random_configuration
from trackcal.calib.model.kinematics import Kinematics
from trackcal.calib.model.params import param_by_name


def test_plan_params_identifiable_with_base_and_tool_known():
    """Base and tool known: the Jacobian of the plan parameters alone (no station, no point columns) has full rank at
    random poses, so a plan can target each of them (README `trackcal plan`)."""
    cell = load_cell("ur10")
    params = [param_by_name(cell.chain, n) for n in cell.plan_params]
    kin = Kinematics(cell.chain, params)
    q = random_configuration(cell.chain, 20, np.random.default_rng(5))
    jac = np.vstack([kin.jacobian(q, p).d_params.reshape(-1, len(params)) for p in cell.tool_points.values()])
    assert numerical_rank(jac) == len(params)
    # and dropping the known base makes dq1 a rotation of the station: one rank less with a free base
    assert "dq1" in cell.plan_params


def test_test_pose_and_tool_inside_the_box():
    cell = load_cell("ur10")
    assert points_in_box(cell, cell.test_pose[None])[0]
    pts = np.array(list(cell.tool_points.values()))
    # three nests on a circle of radius 100 mm (configs/tools/ur10-3point.yaml): non-collinear, 173.2 mm apart
    d = np.linalg.norm(pts[:, None] - pts[None], axis=2)
    assert np.allclose(d[np.triu_indices(3, 1)], 100 * np.sqrt(3), atol=0.05)


@pytest.mark.slow  # 20 s: the same run --sim path as the KR-270 (tests/test_campaign_cli.py)
def test_run_sim_ur10_end_to_end(tmp_path):
    cell = load_cell("ur10")
    plan = tmp_path / "plan.json"
    plan.write_text(json.dumps(feasible_plan(cell, 3, seed=2, repeat=1)))
    r = subprocess.run(
        [
            *TRACKCAL,
            "run",
            "--sim",
            "--cell",
            "ur10",
            "--plan",
            str(plan),
            "--session",
            str(tmp_path / "s"),
            "--seed",
            "4",
            "--no-analysis",
        ],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stderr
    subprocess.run([*TRACKCAL, "export", str(tmp_path / "s"), "--csv", str(tmp_path / "t.csv")], check=True)
    rows = [line.split(",")[2:5] for line in (tmp_path / "t.csv").read_text().splitlines()[1:]]
    assert {pose for pose, _, _ in rows} == {"Q1", "Q2", "Q3"}  # every planned pose measured
    for pose, station in {(p, s) for p, s, _ in rows}:  # from each station that sees it: every point of the tool
        assert {pt for p, s, pt in rows if (p, s) == (pose, station)} == {"P1", "P2", "P3"}
