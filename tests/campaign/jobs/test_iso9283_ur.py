"""The ISO 9283 test on the UR cell (configs/cells/ur10.yaml): `iso9283 plan`, `run` and `compare` give the signed
report there too. By default on `run --sim` (the twin behind the in-process lockstep UR controller); the whole
before/after chain against `trackcal mock --cell ur10` (the mock UR controller in its own process, `run --hardware`)
is slow (`make test-slow`)."""

import subprocess
from pathlib import Path

import numpy as np
import pytest

from tests.helpers import TRACKCAL, mock_process
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.model.cell import load_cell
from trackcal.calib.model.kinematics import Kinematics
from trackcal.calib.model_file import Model
from trackcal.campaign.jobs.iso9283 import PlanOptions, make_plan, session_figures
from trackcal.campaign.report.iso9283 import render
from trackcal.mocks.twin import Twin

SEED = 3
CONDITIONS = ("robot", "cell", "tool", "load", "speed", "temperature", "started", "trackcal version")


def run(*argv, cwd, timeout=600):
    done = subprocess.run([*TRACKCAL, *argv], cwd=cwd, capture_output=True, text=True, timeout=timeout)
    assert done.returncode == 0, done.stderr
    return done.stdout


def test_ur10_sim_gives_every_figure_and_the_conditions(tmp_path):
    """Plan with the multi-directional and orientation parts, run on the simulated UR cell, figures in the twin's own
    frame: all five poses' AP/RP, vAP at P1, P2, P4, orientation from the three nests, and a report naming the
    conditions of the test."""
    plan = make_plan(
        PlanOptions(
            cell="ur10",
            json=str(tmp_path / "iso.json"),
            cycles=2,
            vap_cycles=2,
            orientation=True,
            load="unloaded",
            velocities=(100.0,),
        )
    )
    assert len(plan["iso9283"]["points"]) == 3
    run(
        "run",
        "--sim",
        "--cell",
        "ur10",
        "--plan",
        "iso.json",
        "--seed",
        str(SEED),
        "--session",
        "s",
        "--no-analysis",
        cwd=tmp_path,
    )
    twin = Twin(load_cell("ur10"), seed=SEED)
    model = Model(twin.cell.chain, [], np.zeros(0), twin.true_stations, twin.true_points, {})
    figs = session_figures(Path(tmp_path / "s"), model, TrackerNoise())
    assert [p.n for p in figs.poses] == [2] * 5
    assert set(figs.vap) == {"P1", "P2", "P4"}
    assert all(set(p.orientation) == {f"{k}_{a}" for k in ("AP", "RP") for a in "abc"} for p in figs.poses)
    # the nominal targets on the twin's robot (its own deviations, mocks/twin.py): AP is how far the true robot puts
    # the point from where the nominal one would, plus the mean of 2 cycles of ~10 µm tracker noise per coordinate
    # (3-D: ~12 µm; 0.05 mm is 4 of them)
    iso = plan["iso9283"]
    q = np.array(iso["nominal_poses_deg"])
    nominal = Kinematics(twin.cell.chain, []).points(np.radians(q), twin.true_points[iso["point"]])
    true = np.array([twin.point_in_base(qi, iso["point"]) for qi in q])
    expected = np.linalg.norm(true - nominal, axis=1)
    assert expected.max() > 0.1  # the twin's robot deviates (0.3 mm / 0.02 deg per parameter)
    assert np.abs(np.array([p.ap.value for p in figs.poses]) - expected).max() < 0.05
    assert figs.conditions["robot"] == "ur10" and figs.conditions["cell"] == "ur10"
    page = render([figs], [], "the twin's station")
    for key in CONDITIONS:
        assert f"<td class=l>{key}</td>" in page, key
    assert "vAP_P" in page and "AP_a, AP_b, AP_c" in page


@pytest.mark.slow
def test_ur10_mock_controller_before_and_after(tmp_path):
    """The customer's chain on the UR mock: calibrate (simulated table), plan the nominal and the compensated test,
    run both against `trackcal mock --cell ur10` over its protocols, compare with the report."""
    run("simulate", "--cell", "ur10", "--poses", "20", "--seed", "1", "--out", "t.csv", cwd=tmp_path)
    run("identify", "t.csv", "--cell", "ur10", "--out", "model.json", cwd=tmp_path)
    common = (
        "--cell",
        "ur10",
        "--cycles",
        "3",
        "--vap-cycles",
        "2",
        "--orientation",
        "--load",
        "unloaded",
        "--velocities",
        "100",
    )
    run("iso9283", "plan", *common, "--json", "iso.json", cwd=tmp_path)
    run("iso9283", "plan", *common, "--model", "model.json", "--json", "iso-comp.json", cwd=tmp_path)
    hw = tmp_path / "H.yaml"
    with mock_process("ur10", SEED, hw, timeout_s=60.0, sim_speed=50.0):
        for plan, session in (("iso.json", "before"), ("iso-comp.json", "after")):
            run(
                "run",
                "--cell",
                "ur10",
                "--plan",
                plan,
                "--hardware",
                str(hw),
                "--session",
                session,
                "--no-analysis",
                cwd=tmp_path,
            )
    out = run("iso9283", "compare", "before", "after", "--model", "model.json", "--report", "iso.html", cwd=tmp_path)
    assert "vAP_P nominal" in out and "AP_P compensated" in out
    page = (tmp_path / "iso.html").read_text()
    for key in CONDITIONS:
        assert f"<td class=l>{key}</td>" in page, key
    assert "hardware" in page  # the mode of both sessions: measured over the controller's protocols
