"""A robot file alone stands for a cell: identify and diagnose take the reference points from the table, starting
where the measurements put them (calib.identify.points), and reach the same model as with the tool file that names
the nests. The start itself is checked against the twin's true points."""

import json

import numpy as np
import pytest

from tests.helpers import ROOT, kr270_campaign
from trackcal.calib.identify.points import PointsError, points_from_table
from trackcal.calib.io.table import write_table
from trackcal.campaign.cli import main

ROBOT = str(ROOT / "configs" / "robots" / "kr270.yaml")


@pytest.fixture(scope="module")
def campaign(tmp_path_factory, kr270):
    d = tmp_path_factory.mktemp("points")
    twin, table = kr270_campaign(kr270, seed=8, n_poses=30)
    write_table(table, d / "t.csv")
    return twin, table, d


def test_the_start_is_near_the_true_points(campaign, kr270):
    # On the nominal chain the start can only be as good as the nominal chain: the twin's geometric deviations
    # (mm-sized, mocks/twin.py) move every point by up to a few mm. The nests are 100-300 mm from the flange
    # (configs/tools/kr270-3point.yaml), so a start within 10 mm is already inside identification's basin.
    twin, table, _ = campaign
    start = points_from_table(kr270.chain, table)
    assert sorted(start) == sorted(kr270.tool_points)
    for pid, p in start.items():
        assert np.linalg.norm(p - twin.true_points[pid]) < 10.0, pid


def test_noise_free_points_on_the_nominal_robot_are_exact(kr270):
    # A twin without deviations or noise: the measurements are the nominal chain's, so the alternation must land
    # on the tool file's points (the only exact solution; the fit is then 0), to float rounding.
    twin, table = kr270_campaign(kr270, seed=9, n_poses=12, noise_free=True, deviations={})
    start = points_from_table(kr270.chain, table)
    for pid, p in start.items():
        np.testing.assert_allclose(p, twin.true_points[pid], atol=1e-6)


def test_identify_from_the_robot_file_equals_identify_from_the_cell(campaign):
    # Same table, same parameters, same weighting: the least-squares optimum does not depend on where the points
    # start, so both routes end on the same model (to the solver's convergence tolerance).
    _, _, d = campaign
    assert main(["identify", str(d / "t.csv"), "--cell", "kr270", "--out", str(d / "cell.json")]) == 0
    assert main(["identify", str(d / "t.csv"), "--cell", ROBOT, "--out", str(d / "robot.json")]) == 0
    a, b = (json.loads((d / f"{n}.json").read_text()) for n in ("cell", "robot"))
    assert list(b["parameters"]) == list(a["parameters"])
    for name, p in a["parameters"].items():
        assert b["parameters"][name]["value"] == pytest.approx(p["value"], abs=1e-6), name
    for pid, p in a["tool_points"].items():
        np.testing.assert_allclose(b["tool_points"][pid]["xyz_mm"], p["xyz_mm"], atol=1e-5)


def test_a_table_that_cannot_place_its_points_says_so(campaign, kr270):
    _, table, _ = campaign
    with pytest.raises(PointsError, match="cannot place"):
        points_from_table(kr270.chain, table.subset(np.arange(2)))
