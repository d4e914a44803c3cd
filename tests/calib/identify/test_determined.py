"""issue 25: identify names the parameters a table does not determine (calib/identify/determined.py), and its advice
after a poor fit names only the parameters left out that the table would determine."""

import json

import numpy as np
import pytest

from trackcal.calib.doe.poses import random_poses
from trackcal.calib.identify.determined import POORLY_DETERMINED, noise_floor_ratios
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.io.table import write_table
from trackcal.calib.model.cell import load_cell
from trackcal.calib.model.params import param_by_name
from trackcal.campaign.cli import main
from trackcal.campaign.jobs.identify import run_identify
from trackcal.mocks.twin import Twin, simulate_campaign

# the 16 parameters the UR10 with its one T-Mac point on the wrist_3 axis identifies (README, UR10 section)
UR10_P = [
    "px1",
    "py1",
    "phix1",
    "dq2",
    "px2",
    "phix2",
    "phiy2",
    "dq3",
    "px3",
    "phix3",
    "phiy3",
    "dq4",
    "px4",
    "py4",
    "phix4",
    "dq5",
]


def test_ratio_of_an_uncorrelated_column_and_of_a_near_dependent_one():
    """An orthogonal column reaches 1.96 / sqrt(rows) (its interval's displacement: 1.96 sigma / sqrt(3N) RMS); two
        columns a and a + 1e-3 b (a, b orthonormal) leave each a part 1e-3 of its norm independent of the other, so
    (J^T J)^-1_pp = 1e6: ratio 1.96 / 1e-3 / sqrt(rows)."""
    rng = np.random.default_rng(0)
    q, _ = np.linalg.qr(rng.standard_normal((300, 3)))
    jm = q * np.array([5.0, 0.1, 2.0])
    assert noise_floor_ratios(jm, [0, 1, 2]) == pytest.approx(np.full(3, 1.96 / np.sqrt(300)))
    near = np.column_stack([q[:, 0], q[:, 0] + 1e-3 * q[:, 1], q[:, 2]])
    r = noise_floor_ratios(near, [0, 1, 2])
    assert r[0] == pytest.approx(1.96 / 1e-3 / np.sqrt(300), rel=1e-3) and r[2] < 1


@pytest.fixture(scope="module")
def one_point_ur10():
    """The UR10 cell's twin measured at its T-Mac centre only (as the real series are), 60 poses; px4 off by 0.5 mm."""
    cell = load_cell("ur10-ipa")
    twin = Twin(cell, seed=2, deviations={"px4": 0.5})
    table = simulate_campaign(twin, np.degrees(random_poses(cell, 60, np.random.default_rng(2))), points=["TMAC"])
    return cell, table


def test_parameters_one_point_cannot_fix_are_named(one_point_ur10, tmp_path, capsys):
    """With one point on the wrist_3 axis px5 and phix5 hardly move it apart from the point's own position: the fit
    keeps them only through a near-dependence (the real Series B: px5 +-44.9 mm, phix5 +-27.4 deg, no warning)."""
    cell, table = one_point_ur10
    path = tmp_path / "u.csv"
    write_table(table, str(path))
    out = tmp_path / "m.json"
    assert (
        main(
            [
                "identify",
                str(path),
                "--cell",
                "ur10-ipa",
                "--params",
                ",".join([*UR10_P, "px5", "phix5"]),
                "--out",
                str(out),
            ]
        )
        == 0
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "poorly determined" in err[0] and "px5" in err[0] and "phix5" in err[0]
    bad = json.loads(out.read_text())["poorly_determined"]
    assert {"px5", "phix5"} <= set(bad) and all(r is None or r > POORLY_DETERMINED for r in bad.values())


def test_without_them_nothing_is_poorly_determined(one_point_ur10):
    cell, table = one_point_ur10
    params = [param_by_name(cell.chain, n) for n in UR10_P]
    assert run_identify(cell, table, params).doc["poorly_determined"] == {}


def test_advice_names_only_what_the_table_determines(one_point_ur10):
    """px4 left out (its 0.5 mm deviation makes the fit poor): the advice names it, and says px5 and phix5, also left
    out, cannot be determined by this table."""
    cell, table = one_point_ur10
    params = [param_by_name(cell.chain, n) for n in UR10_P if n != "px4"]
    outcome = run_identify(cell, table, params, weighting="tracker")
    assert outcome.doc["fit"] == "poor"
    assert "add the parameters left out (px4: this table determines them)" in outcome.warning
    assert "cannot be determined by this table (px5 phix5)" in outcome.warning


def test_ordinary_campaign_warns_nothing(kr270, kr270_params):
    """The README's 30-pose KR-270 campaign, the full irreducible set: every parameter determined."""
    twin = Twin(kr270, seed=1)
    table = simulate_campaign(twin, np.degrees(random_poses(kr270, 30, np.random.default_rng(1))))
    outcome = run_identify(kr270, table, kr270_params)
    assert outcome.doc["poorly_determined"] == {} and outcome.determination is None
    assert TrackerNoise() == outcome.result.noise
