"""Instrument models (calib.model.instruments): each named tracker's one-sigma terms against its datasheet formula,
the cell's `tracker:` key parsed and refused in one line, and the cell's instrument reaching identify's weighting,
its noise floor, plan's rho0 and the twin."""

import copy
import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from tests.helpers import kr270_campaign
from trackcal.calib.doe.design import random_feasible_poses
from trackcal.calib.identify.noise import TrackerNoise, model_instrument, model_noise, noise_for
from trackcal.calib.io.table import write_table
from trackcal.calib.model.cell import load_cell
from trackcal.calib.model.instruments import InstrumentError, instrument_from_doc, named
from trackcal.calib.model.params import param_by_name
from trackcal.campaign.cli import main
from trackcal.campaign.jobs.end_of_run import analysed
from trackcal.campaign.jobs.identify import run_identify
from trackcal.campaign.jobs.plan import PlanOptions, build_design, evaluate_doc, write_plan_csv
from trackcal.campaign.report.analysis import Provenance
from trackcal.campaign.report.html import write_report
from trackcal.mocks.twin import Twin

RANGES_M = np.array([1.0, 3.0, 10.0])

# The datasheet formulas, written out (µm; MPE or 2-sigma figures, one sigma = half of them: Leica, "typical results
# are half of the MPE"; see calib/model/instruments.py for the sources and the reading of each).
DATASHEETS = {
    # Leica AT901: distance MPE 10 µm; angle MPE 15 µm + 6 µm/m
    "AT901": (lambda L: 10 / 2 + 0 * L, lambda L: (15 + 6 * L) / 2),
    # Leica AT960 datasheet (J. Robotics 2021, 9995787, Table 1): dynamic lock-on ±10 µm; angle ±15 µm + 6 µm/m (MPE)
    "AT960": (lambda L: 10 / 2 + 0 * L, lambda L: (15 + 6 * L) / 2),
    # Leica AT500 User Manual 2.8.2: ADM e_ADM ±10 µm + 0.3 µm/m; transverse e_T ±15 µm + 6 µm/m (MPE)
    "AT500": (lambda L: (10 + 0.3 * L) / 2, lambda L: (15 + 6 * L) / 2),
}


@pytest.mark.parametrize("name", list(DATASHEETS))
def test_each_model_has_its_datasheet_sigmas(name):
    radial, transverse = DATASHEETS[name]
    noise = TrackerNoise.of(named(name))
    sr, st = noise.sigmas(RANGES_M * 1000.0)
    assert np.allclose(sr * 1000, radial(RANGES_M), rtol=1e-12)
    assert np.allclose(st * 1000, transverse(RANGES_M), rtol=1e-12)
    # the covariance of a point on the x axis: radial variance along x, transverse across
    cov = noise.covariance(np.c_[RANGES_M * 1000.0, np.zeros(3), np.zeros(3)])
    assert np.allclose(np.sqrt(cov[:, 0, 0]) * 1000, radial(RANGES_M), rtol=1e-12)
    assert np.allclose(np.sqrt(cov[:, 1, 1]) * 1000, transverse(RANGES_M), rtol=1e-12)
    assert np.allclose(np.sqrt(cov[:, 2, 2]) * 1000, transverse(RANGES_M), rtol=1e-12)
    # whitening stays the inverse square root of the covariance with a range-dependent radial term
    w = noise.whitening(np.c_[RANGES_M * 1000.0, 200.0 * np.ones(3), -50.0 * np.ones(3)])
    c = noise.covariance(np.c_[RANGES_M * 1000.0, 200.0 * np.ones(3), -50.0 * np.ones(3)])
    assert np.allclose(np.einsum("nji,njk,nkl->nil", w, w, c), np.eye(3), atol=1e-9)


def test_the_at901_is_still_the_default_and_bit_for_bit_the_old_numbers():
    # trackcal's numbers before instruments: 5 µm radial, 7.5 µm + 3 µm/m transverse (the AT901 datasheet's MPE / 2)
    old = (0.005, 0.0075, 0.003)
    assert (TrackerNoise().radial_mm, TrackerNoise().transverse_mm, TrackerNoise().transverse_mm_per_m) == old
    assert TrackerNoise.of(named("AT901")) == TrackerNoise() == noise_for("tracker")
    cell = load_cell("kr270")
    assert cell.tracker.assumed and TrackerNoise.of(cell.tracker) == TrackerNoise()
    assert "assumed" in cell.tracker.describe() and "Leica AT901" in cell.tracker.describe()


def test_custom_and_short_forms_parse():
    custom = instrument_from_doc({"model": "custom", "radial_um": 10, "transverse_um": 15, "transverse_um_per_m": 6})
    sr, st = TrackerNoise.of(custom).sigmas(np.array([0.0, 2000.0]))
    assert np.allclose(sr, [0.010, 0.010]) and np.allclose(st, [0.015, 0.015 + 2 * 0.006])
    with_ppm = instrument_from_doc(
        {"model": "custom", "radial_um": 4, "radial_um_per_m": 1, "transverse_um": 6, "transverse_um_per_m": 2}
    )
    assert np.isclose(TrackerNoise.of(with_ppm).sigmas(3000.0)[0], 0.004 + 3 * 0.001)
    assert instrument_from_doc("AT960") == instrument_from_doc({"model": "at960"}) == named("AT960")
    assert instrument_from_doc({"model": "at500"}).name == "Leica AT500"
    assert not instrument_from_doc({"model": "AT960"}).assumed


@pytest.mark.parametrize(
    "doc, message",
    [
        ({"model": "AT999"}, "'AT999' is no tracker model; choose one of AT901, AT960"),
        ({"model": "AT960", "radial_um": 3}, "radial_um: only a custom tracker takes its own numbers"),
        ({"model": "custom", "radial_um": 5, "transverse_um": 7}, "transverse_um_per_m: missing"),
        ({"model": "custom", "radial_um": -5, "transverse_um": 7, "transverse_um_per_m": 1}, "cannot be negative"),
        ({"model": "custom", "radial_um": 0, "transverse_um": 7, "transverse_um_per_m": 1}, "must be positive"),
        ({"model": "custom", "radial_um": 5, "transverse_um": "x", "transverse_um_per_m": 1}, "expected a number"),
        ({"model": "custom", "radial": 5, "transverse_um": 7, "transverse_um_per_m": 1}, "radial: not a custom"),
        ([1, 2], "expected a mapping"),
    ],
)
def test_bad_tracker_keys_are_named(doc, message):
    with pytest.raises(InstrumentError, match=None) as exc:
        instrument_from_doc(doc, "cell.yaml: tracker")
    assert message in str(exc.value) and str(exc.value).startswith("cell.yaml: tracker")


def _cell_file(tmp_path, tracker) -> str:
    doc = yaml.safe_load(Path(load_cell("kr270").source).read_text())
    doc["tracker"] = tracker
    path = tmp_path / "cell.yaml"
    path.write_text(yaml.safe_dump(doc))
    return str(path)


def test_a_bad_tracker_in_the_cell_is_one_line_and_exit_2(tmp_path, capsys):
    cell = _cell_file(tmp_path, {"model": "Laser3000"})
    assert main(["simulate", "--cell", cell, "--poses", "3", "--out", str(tmp_path / "t.csv")]) == 2
    err = capsys.readouterr().err
    assert "tracker.model: 'Laser3000' is no tracker model" in err and err.count("\n") == 1
    assert "Traceback" not in err


def with_tracker(cell, tracker):
    out = copy.copy(cell)
    out.tracker = instrument_from_doc(tracker)
    return out


# A custom instrument twice as noisy as the AT901 in every term (one sigma: 10 µm, 15 µm + 6 µm/m)
TWICE_AT901 = {"model": "custom", "radial_um": 10, "transverse_um": 15, "transverse_um_per_m": 6}


def test_the_cells_instrument_reaches_identify(kr270):
    """Weighted least squares with W/4 has the same estimate, a variance factor 4x smaller and (a-posteriori
    intervals, s^2 (J^T W J)^-1) the same intervals; the noise floor of the model doubles, the fit ratio halves.
    An instrument of another shape (transverse noise growing 10x faster with range) weighs far points otherwise:
    the intervals move."""
    _, table = kr270_campaign(kr270, seed=5, n_poses=20)
    params = [param_by_name(kr270.chain, n) for n in ("px1", "px2", "px3", "pz3", "dq2", "dq3")]
    a = run_identify(kr270, table, params, "tracker").doc
    b = run_identify(with_tracker(kr270, TWICE_AT901), table, params, "tracker").doc
    assert (a["tracker"]["model"], a["tracker"]["name"], a["tracker"]["assumed"]) == ("AT901", "Leica AT901", True)
    assert b["tracker"] == {
        "model": "custom",
        "name": "custom tracker",
        "assumed": False,
        "radial_um": 10.0,
        "radial_um_per_m": 0.0,
        "transverse_um": 15.0,
        "transverse_um_per_m": 6.0,
    }
    assert b["variance_factor"] == pytest.approx(a["variance_factor"] / 4, rel=1e-6)
    assert b["noise_floor_mm"] == pytest.approx(2 * a["noise_floor_mm"], rel=1e-12)
    assert b["fit_ratio"] == pytest.approx(a["fit_ratio"] / 2, rel=1e-6)
    for n in a["parameters"]:
        assert b["parameters"][n]["value"] == pytest.approx(a["parameters"][n]["value"], abs=1e-7)
        assert b["parameters"][n]["ci95"] == pytest.approx(a["parameters"][n]["ci95"], rel=1e-5)
    steep = {"model": "custom", "radial_um": 5, "transverse_um": 7.5, "transverse_um_per_m": 30}
    c = run_identify(with_tracker(kr270, steep), table, params, "tracker").doc
    moved = [abs(c["parameters"][n]["ci95"] / a["parameters"][n]["ci95"] - 1) for n in a["parameters"]]
    assert max(moved) > 0.05
    # model.json keeps the instrument: report and end-of-run read it back
    assert model_noise(b) == TrackerNoise(0.010, 0.015, 0.006, 0.0, "custom tracker")
    assert model_instrument(a).describe() == "Leica AT901 (assumed: the cell names no tracker)"
    assert model_noise({**b, "weighting": "iid"}) is None


def test_the_cells_instrument_reaches_plan_rho0(kr270):
    """rho0 is an a-priori figure ((J^T W J)^-1): twice the noise in every term doubles it exactly."""
    opts = PlanOptions(noise="tracker")
    design_a = build_design(kr270, opts)
    design_b = build_design(with_tracker(kr270, TWICE_AT901), opts)
    q = np.vstack([kr270.test_pose, random_feasible_poses(design_a, 11, np.random.default_rng(3))])
    assert evaluate_doc(design_b, q)["rho0_mm"] == pytest.approx(2 * evaluate_doc(design_a, q)["rho0_mm"], rel=1e-9)


def test_plan_says_which_instrument_it_planned_for(kr270, tmp_path, capsys):
    q = random_feasible_poses(build_design(kr270, PlanOptions()), 12, np.random.default_rng(4))
    write_plan_csv(tmp_path / "p.csv", q, 1)
    cell = _cell_file(tmp_path, {"model": "AT500"})
    argv = ["plan", "--cell", cell, "--evaluate", str(tmp_path / "p.csv"), "--json", str(tmp_path / "e.json")]
    assert main([*argv, "--noise", "tracker"]) == 0
    assert "noise: tracker model of the Leica AT500)" in " ".join(capsys.readouterr().out.split())
    assert json.loads((tmp_path / "e.json").read_text())["tracker"]["model"] == "AT500"
    assert main(argv) == 0  # i.i.d. (the default): no instrument in it
    assert "noise: i.i.d.)" in capsys.readouterr().out
    assert "tracker" not in json.loads((tmp_path / "e.json").read_text())


def test_the_twin_measures_with_the_cells_instrument(kr270):
    assert Twin(kr270).noise == TrackerNoise()
    assert Twin(with_tracker(kr270, TWICE_AT901)).noise == TrackerNoise(0.010, 0.015, 0.006, 0.0, "custom tracker")


def test_identify_and_the_report_name_the_instrument(kr270, tmp_path, capsys):
    _, table = kr270_campaign(kr270, seed=7, n_poses=12)
    # one row per pose, station and point: no repeats, so the report's noise floor is the instrument's noise model
    keys = list(zip(table.pose, table.station, table.point, strict=True))
    table = table.subset(np.array([i for i, key in enumerate(keys) if key not in keys[:i]]))
    write_table(table, tmp_path / "t.csv")
    cell = _cell_file(tmp_path, {"model": "AT960"})
    assert main(["identify", str(tmp_path / "t.csv"), "--cell", cell, "--out", str(tmp_path / "m.json")]) == 0
    out = capsys.readouterr().out
    assert "tracker Leica AT960" in out and "assumed" not in out
    assert main(["identify", str(tmp_path / "t.csv"), "--cell", "kr270", "--out", str(tmp_path / "m0.json")]) == 0
    assert "tracker Leica AT901 (assumed: the cell names no tracker)" in " ".join(capsys.readouterr().out.split())
    at960 = with_tracker(kr270, "AT960")
    doc = run_identify(at960, table, [param_by_name(kr270.chain, n) for n in ("px2", "dq2")], "tracker").doc
    page = write_report(analysed(at960, table, doc, provenance=Provenance()), tmp_path / "rep").read_text()
    assert '<td class="l">tracker</td><td class="l">Leica AT960</td>' in page
    assert "(Leica AT960 noise model;" in page  # the noise floor's source
