"""A twin that deviates for every robot, the truth it writes (`simulate --truth`, `run --sim --truth`), and the one
figure at the test pose (calib/tcp_figure.py) checked against that truth on a UR10 campaign: identify recovers the
true deviations within their intervals and compensation brings the true robot to the intended TCP."""

import json
import re
from html import unescape

import numpy as np
import pytest
from scipy import stats

from tests.helpers import feasible_plan
from trackcal.calib.compensate import compensate
from trackcal.calib.io.files import write_json
from trackcal.calib.model.cell import load_cell
from trackcal.calib.model.kinematics import Kinematics
from trackcal.calib.model.params import irreducible_params
from trackcal.calib.model_file import load_model
from trackcal.campaign.cli import main
from trackcal.campaign.jobs.end_of_run import report_files
from trackcal.campaign.jobs.history import HistoryOptions, history
from trackcal.campaign.jobs.identify import IdentifyOptions, identify_table
from trackcal.campaign.jobs.simulate import SimulateOptions, simulate
from trackcal.mocks.twin import DEVIATION_SIGMA_DEG, DEVIATION_SIGMA_MM, PAPER_TABLE8, Twin


def test_every_robot_deviates_from_nominal_and_the_kr270_keeps_table8():
    """The UR10's twin deviates in every irreducible parameter, the same for the same seed, another robot for
    another seed; the KR-270's is the paper's Table 8 whatever the seed; `deviations={}` is the nominal robot."""
    ur10 = load_cell("ur10")
    kept = irreducible_params(ur10.chain)[0]
    a, b, c = Twin(ur10, seed=1), Twin(ur10, seed=1), Twin(ur10, seed=2)
    idx = [a.params.index(p) for p in kept]
    assert np.all(a.true_dev[idx] != 0.0)
    assert np.array_equal(a.true_dev, b.true_dev) and not np.allclose(a.true_dev, c.true_dev)
    others = np.delete(a.true_dev, idx)
    assert not others.any()  # the rest of the complete model is redundant with the stations and points
    # the size of an uncalibrated robot's errors: every deviation within 5 sigma of the stated distribution
    scale = np.array([DEVIATION_SIGMA_MM if p.is_length else np.radians(DEVIATION_SIGMA_DEG) for p in kept])
    assert np.all(np.abs(a.true_dev[idx]) < 5.0 * scale)
    assert not Twin(ur10, seed=1, deviations={}).true_dev.any()
    kr = load_cell("kr270")
    for seed in (1, 7):
        t = Twin(kr, seed=seed)
        for name, v in PAPER_TABLE8.items():
            p = next(p for p in t.params if p.name == name)
            assert t.true_dev[t.params.index(p)] == pytest.approx(v if p.is_length else np.radians(v), abs=1e-15)


def test_the_truth_file_holds_the_twin(tmp_path):
    """`simulate --truth`: the parameters, stations and points are the twin's, and the test pose's centroid in each
    station's frame is the twin's own exact() of its points there (no approach history, t = 0)."""
    path = tmp_path / "truth.json"
    cell, twin, _ = simulate(SimulateOptions(cell="ur10", poses=3, seed=5, truth=str(path)))
    truth = json.loads(path.read_text())
    fresh = Twin(cell, seed=5)
    for p, v in zip(fresh.params, fresh.true_dev, strict=True):
        if p.name in truth["parameters"]:
            entry = truth["parameters"][p.name]
            assert entry["value"] == pytest.approx(v if p.is_length else np.degrees(v), abs=1e-12)
            assert entry["unit"] == ("mm" if p.is_length else "deg")
    assert {p.name for p in irreducible_params(cell.chain)[0]} <= set(truth["parameters"])
    q0 = np.degrees(cell.test_pose)
    assert truth["test_pose"]["joints_deg"] == pytest.approx(q0.tolist())
    for sid, st in fresh.true_stations.items():
        assert np.array(truth["stations"][sid]["rotation"]) == pytest.approx(st.rotation, abs=1e-12)
        exact = np.mean([fresh.exact(q0, pid, sid) for pid in sorted(fresh.true_points)], axis=0)
        assert np.array(truth["test_pose"]["centroid_mm"][sid]) == pytest.approx(exact, abs=1e-9)
    for pid, x in fresh.true_points.items():
        assert np.array(truth["tool_points"][pid]["xyz_mm"]) == pytest.approx(x, abs=1e-12)
    assert truth["effects"] == {"magnitudes_mm": {}, "parameters": {}}


def test_run_sim_writes_the_same_truth(tmp_path, monkeypatch):
    """`run --sim --truth` writes the truth of the twin it ran on: the one `simulate --truth` writes for that cell
    and seed."""
    monkeypatch.chdir(tmp_path)
    write_json(tmp_path / "plan.json", feasible_plan(load_cell("kr270"), 1, seed=3, repeat=1))
    assert (
        main(
            [
                "run",
                "--sim",
                "--cell",
                "kr270",
                "--plan",
                "plan.json",
                "--seed",
                "4",
                "--truth",
                "truth.json",
                "--session",
                "s",
                "--no-analysis",
            ]
        )
        == 0
    )
    simulate(SimulateOptions(cell="kr270", poses=1, seed=4, truth=str(tmp_path / "simulated.json")))
    assert json.loads((tmp_path / "truth.json").read_text()) == json.loads((tmp_path / "simulated.json").read_text())


SEEDS = (1, 2, 3)
N_POSES = 30  # the README's UR10 campaign size order (20 there), random feasible poses, 2 stations, 3 points


def _ur10_campaign(tmp_path, seed: int):
    cell, twin, _ = simulate(
        SimulateOptions(
            cell="ur10",
            out=str(tmp_path / f"t{seed}.csv"),
            poses=N_POSES,
            seed=seed,
            truth=str(tmp_path / f"truth{seed}.json"),
        )
    )
    outcome = identify_table(
        IdentifyOptions(data=str(tmp_path / f"t{seed}.csv"), cell="ur10", out=str(tmp_path / f"m{seed}.json"))
    )
    return cell, twin, outcome, json.loads((tmp_path / f"truth{seed}.json").read_text())


def test_a_ur10_twin_campaign_recovers_the_truth_and_compensation_pays_off(tmp_path):
    """On the UR10 twin (its own deviations), over a few campaigns: (1) the true deviations lie inside identify's 95 %
    intervals but for a binomially expected few: with k independent 95 % intervals the number outside is
    Binomial(k, 0.05); we allow the count that is exceeded with probability under 1 %; (2) at the test pose, the
    nominal robot's TCP is off the truth (truth file) by the deviations' effect, tenths of a mm to a mm (0.3 mm /
    0.02 deg per parameter), while the true robot commanded to the compensated target (calib.compensate) lands where
    the nominal robot was meant to, to the identification's accuracy (the figure's few µm): at least 5x closer."""
    outside, count = 0, 0
    for seed in SEEDS:
        cell, twin, outcome, truth = _ur10_campaign(tmp_path, seed)
        doc = outcome.doc
        assert doc["fit"] == "good"
        for name, p in doc["parameters"].items():
            count += 1
            outside += abs(p["value"] - truth["parameters"][name]["value"]) > p["ci95"]
        # the test pose, in the first station's frame: the nominal robot (the model's station and points) and truth
        model = load_model(tmp_path / f"m{seed}.json")
        station = doc["test_pose"]["station"]
        q0 = cell.test_pose[None]
        points = np.array([model.points[p] for p in sorted(model.points)])
        nominal_base = Kinematics(model.chain, model.params).points(np.repeat(q0, len(points), axis=0), points)
        intended = model.stations[station].apply(nominal_base.mean(axis=0))
        true_tcp = np.array(truth["test_pose"]["centroid_mm"][station])
        before = float(np.linalg.norm(intended - true_tcp))
        qc, report = compensate(model, q0, points.mean(axis=0))
        assert report.failures == [""]
        twin.approach = np.zeros(cell.chain.dof)  # the neutral context of the truth file's test pose
        attained = np.mean([twin.exact(np.degrees(qc[0]), p, station) for p in sorted(twin.true_points)], axis=0)
        after = float(np.linalg.norm(attained - intended))
        assert before > 0.1, before  # the twin deviates
        assert after * 5.0 <= before, (seed, before, after)
    allowed = int(stats.binom.isf(0.01, count, 0.05))  # P(X > allowed) <= 1 %
    assert stats.binom.sf(allowed, count, 0.05) <= 0.01
    assert outside <= allowed, (outside, count, allowed)


def test_one_figure_at_the_test_pose_in_model_summary_report_and_history(tmp_path, capsys):
    """model.json's test_pose is the identify summary's, the line identify prints, the report's figure and history's:
    one computation (calib.tcp_figure), 1-sigma everywhere."""
    _, _, outcome, _ = _ur10_campaign(tmp_path, 1)
    summary = tmp_path / "summary.json"
    capsys.readouterr()
    assert (
        main(
            [
                "identify",
                str(tmp_path / "t1.csv"),
                "--cell",
                "ur10",
                "--out",
                str(tmp_path / "m.json"),
                "--json",
                str(summary),
            ]
        )
        == 0
    )
    stdout = capsys.readouterr().out
    model = json.loads((tmp_path / "m.json").read_text())
    tp = model["test_pose"]
    assert tp == outcome.doc["test_pose"] == json.loads(summary.read_text())["test_pose"]
    assert tp["sigma_mm"] > 0 and np.sqrt(np.sum(np.square(tp["sigma_xyz_mm"]))) == pytest.approx(tp["sigma_mm"])
    line = next(x for x in stdout.splitlines() if x.startswith("TCP at the test pose"))
    assert f"±{tp['sigma_mm'] * 1000:.1f} µm (1σ 3-D" in line
    page = unescape(
        report_files(str(tmp_path / "t1.csv"), str(tmp_path / "m.json"), str(tmp_path / "report")).read_text()
    )
    shown = re.search(r"TCP at the test pose is determined to ±([0-9.]+) µm", page)
    assert shown is not None and float(shown[1]) == pytest.approx(tp["sigma_mm"] * 1000, abs=0.05)
    h = history(HistoryOptions(calibrations=[str(tmp_path / "m.json")]))
    assert h.calibrations[0].tcp_sigma_mm == tp["sigma_mm"]
    assert h.calibrations[0].tcp_correction_mm == tp["correction_mm"]
    capsys.readouterr()
    assert (
        main(
            [
                "iso9283",
                "plan",
                "--cell",
                "ur10",
                "--load",
                "unloaded",
                "--model",
                str(tmp_path / "m.json"),
                "--json",
                str(tmp_path / "iso.json"),
            ]
        )
        == 0
    )
    assert f"±{tp['sigma_mm'] * 1000:.1f} µm 1-sigma" in capsys.readouterr().out
    iso = json.loads((tmp_path / "iso.json").read_text())["iso9283"]
    assert iso["compensated_with"]["test_pose"] == tp
