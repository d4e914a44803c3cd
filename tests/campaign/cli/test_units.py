"""issue 35: a table in metres, inches or radians is refused in one line naming the likely unit, before any fit
(calib/identify/units.py); the twin's tables and the real UR10 import are accepted. Before, x, y, z divided by 1000
gave identify exit 0, residual 0.0 um and px2 -1148.85 mm."""

import dataclasses
import math

import numpy as np
import pytest

from studies.ur10_ipa.study import DATA, SERIES
from trackcal.calib.identify.units import check_units, length_scale
from trackcal.calib.io.table import MeasurementTable, read_table, write_table
from trackcal.calib.model.cell import load_cell
from trackcal.campaign.cli import main

# The README's IRB 120 from its datasheet DH table ("A robot trackcal has never seen"), with a tool 60 mm out
IRB120 = """name: irb120
dh: {convention: standard, flange: {rpy_deg: [180, -90, 0]}, rows: [
{name: joint_1, a_mm: 0, alpha_deg: -90, d_mm: 290, limits_deg: [-165, 165]},
{name: joint_2, a_mm: 270, alpha_deg: 0, d_mm: 0, theta_offset_deg: -90, limits_deg: [-110, 110]},
{name: joint_3, a_mm: 70, alpha_deg: -90, d_mm: 0, limits_deg: [-110, 70]},
{name: joint_4, a_mm: 0, alpha_deg: 90, d_mm: 302, limits_deg: [-160, 160]},
{name: joint_5, a_mm: 0, alpha_deg: -90, d_mm: 0, limits_deg: [-120, 120]},
{name: joint_6, a_mm: 0, alpha_deg: 0, d_mm: 72, limits_deg: [-400, 400]}]}
"""
IRB120_TOOL = """name: twin-smr3
points: {P1: {xyz_mm: [60, 0, 40], normal: [1, 0, 0]}, P2: {xyz_mm: [60, 50, -30], normal: [1, 0, 0]},
         P3: {xyz_mm: [60, -50, -30], normal: [1, 0, 0]}}
"""
IRB120_CELL = """name: twin-cell
robot: irb120.yaml
tool: twin-smr3.yaml
box_mm: {min: [-600, -600, 0], max: [700, 600, 900]}
stations: {S1: {position_mm: [2000, 300, 500], yaw_deg: 180}}
"""


def twin_table(tmp_path, cell: str):
    """(cell, table) of a 20-pose twin campaign of `cell` (a name, or "irb120": the README's robot)."""
    if cell == "irb120":
        for name, text in (("irb120.yaml", IRB120), ("twin-smr3.yaml", IRB120_TOOL), ("cell.yaml", IRB120_CELL)):
            (tmp_path / name).write_text(text)
        cell = str(tmp_path / "cell.yaml")
    out = tmp_path / "t.csv"
    assert main(["simulate", "--cell", cell, "--poses", "20", "--seed", "3", "--out", str(out)]) == 0
    c = load_cell(cell)
    return cell, c, read_table(out, chain=c.chain)


@pytest.mark.parametrize("cell", ["kr270", "ur10", "irb120"])
def test_the_twins_tables_are_accepted_and_move_as_their_flange(tmp_path, cell):
    """In millimetres a reflector moves about as far as the flange (the tool's lever, 60-280 mm here, against poses
    that span the workspace): well within a factor sqrt(25.4) = 5 of 1."""
    _, c, table = twin_table(tmp_path, cell)
    check_units(table, c.chain)
    assert 1 / 2 < length_scale(table, c.chain) < 2


@pytest.mark.parametrize("cell", ["kr270", "ur10", "irb120"])
@pytest.mark.parametrize(
    "unit, change",
    [
        ("metres", lambda t: dataclasses.replace(t, xyz=t.xyz / 1000.0)),
        ("inches", lambda t: dataclasses.replace(t, xyz=t.xyz / 25.4)),  # the inch is 25.4 mm (NIST SP 811, B.6)
        ("radians", lambda t: dataclasses.replace(t, q_deg=np.radians(t.q_deg))),
    ],
)
def test_a_table_in_another_unit_is_refused_in_one_line_naming_it(tmp_path, capsys, cell, unit, change):
    ref, _, table = twin_table(tmp_path, cell)
    bad = tmp_path / f"{unit}.csv"
    write_table(change(table), bad)
    capsys.readouterr()
    for command in (
        ["identify", str(bad), "--cell", ref, "--out", str(tmp_path / "m.json")],
        ["diagnose", str(bad), "--cell", ref, "--json", str(tmp_path / "v.json")],
    ):
        assert main(command) == 2
        err = capsys.readouterr().err
        assert f"look like {unit}, not" in err and err.count("\n") == 1, err
    assert not (tmp_path / "m.json").exists() and not (tmp_path / "v.json").exists()


def test_predict_refuses_joints_in_radians(tmp_path, capsys):
    ref, _, table = twin_table(tmp_path, "kr270")
    model = tmp_path / "m.json"
    assert main(["identify", str(tmp_path / "t.csv"), "--cell", ref, "--out", str(model)]) == 0
    rows = tmp_path / "rows.csv"
    write_table(dataclasses.replace(table, q_deg=np.radians(table.q_deg), xyz=None), rows)
    capsys.readouterr()
    assert main(["predict", "--model", str(model), str(rows), "--out", str(tmp_path / "p.csv")]) == 2
    err = capsys.readouterr().err
    assert "the joints look like radians" in err and err.count("\n") == 1


def test_a_campaign_that_does_not_move_passes():
    """One pose measured again and again (a repeatability run) has no motion to judge units by."""
    c = load_cell("kr270")
    n = 5
    q = np.tile([1.0, -2.0, 2.0, 0.0, 1.0, 0.0], (n, 1))  # small angles, in degrees, that never change
    table = MeasurementTable(
        seq=np.arange(1, n + 1),
        t_s=np.arange(n, dtype=float),
        pose=["Q1"] * n,
        station=["S1"] * n,
        point=["P1"] * n,
        q_deg=q,
        xyz=np.tile([3000.0, 100.0, 900.0], (n, 1)),
    )
    check_units(table, c.chain)


IPA = DATA / SERIES["B"]


@pytest.mark.skipif(not IPA.exists(), reason="IPA data set not present")
def test_the_real_ur10_import_is_accepted(tmp_path):
    """The real UR10 + T-Mac series B as imported: positions in mm, joints in degrees."""
    out = tmp_path / "b.csv"
    assert main(["import", "ipa-ur10", str(IPA), "--out", str(out), "--virtual-points", "2"]) == 0
    c = load_cell("ur10-ipa")
    table = read_table(out, chain=c.chain)
    check_units(table, c.chain)
    assert math.isclose(length_scale(table, c.chain), 1.0, rel_tol=0.2)
