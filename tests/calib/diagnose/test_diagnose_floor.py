"""The floor (issue 36): the model diagnose chooses is never worse than the geometric model on unseen poses, on effects
no candidate has the form of, on narrow joint ranges, and on designs that allow no cross-validation; implausible fits
are refused; extensions are held outside the ranges they were fitted on.

Campaigns come from tests/independent_twin.py (its own physics: motor-side gear harmonics, a sagging nest, one
station's range scale, wrist coupling, a first-order warm-up). Unseen poses are fresh poses measured after the
campaign, predicted by the models as model.json carries them (`predict_table`) and compared with the noise-free truth.
The bound 1.05 is the issue's: the floor allows 5 % of sampling noise in the held-out comparison, not a loss.
"""

import json

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.independent_twin import EFFECTS, campaign
from trackcal.calib.compensate import compensate
from trackcal.calib.diagnose import diagnose
from trackcal.calib.diagnose.confounds import growth_between_blocks, unrevisited
from trackcal.calib.diagnose.fits import context, fit_cause, whole_fit
from trackcal.calib.diagnose.plausibility import ENCODER_SCALE_MAX, implausible
from trackcal.calib.diagnose.selection import ALPHA
from trackcal.calib.diagnose.significance import HeldOut, paired_pvalue
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.identify.solver import identify
from trackcal.calib.io.table import MeasurementTable
from trackcal.calib.model.cell import load_cell
from trackcal.calib.model.extension import Ranges
from trackcal.calib.model_file import model_from_doc, predict_table
from trackcal.campaign.jobs.identify import model_doc

FLOOR = 1.05  # issue 36
CELLS = {name: load_cell(name) for name in ("kr270", "ur10")}


def rms(a: np.ndarray) -> float:
    return float(np.sqrt(np.mean(a**2)))


def held_out(cell_name: str, effect: str, seed: int, n_poses: int, **kw) -> tuple[float, float, object]:
    """(chosen model's RMS on the fresh poses against the truth, the geometric model's, the diagnosis)."""
    cell = CELLS[cell_name]
    c = campaign(cell, effect, seed, n_poses, **kw)
    d = diagnose(cell.chain, c.table, cell.tool_points, c.params, TrackerNoise(), seed=seed)
    out = []
    for res, shift in ((d.geometric, None), (d.extended or d.geometric, d.shift if d.extended else None)):
        model = model_from_doc(model_doc(cell, d.table, res, d.geometric, shift, "twin"))
        out.append(rms(predict_table(model, c.fresh).xyz - c.fresh.xyz))
    return out[1], out[0], d


def assert_floor(cell_name, effect, seed, n_poses, **kw):
    chosen, geometric, d = held_out(cell_name, effect, seed, n_poses, **kw)
    assert chosen <= FLOOR * geometric, (
        effect,
        seed,
        n_poses,
        d.cause,
        [c["cause"] for c in d.causes],
        chosen,
        geometric,
    )


# the default examples are those the code before issue 36 failed (every effect is in the slow property test below)
@pytest.mark.parametrize("effect", ["sagging_nest", "station_scale", "warm_up"])
def test_never_worse_than_geometric_on_unseen_poses(effect):
    assert_floor("kr270", effect, 36001, 20)


def test_never_worse_on_a_ur10():
    assert_floor("ur10", "motor_gear", 36002, 20)


@pytest.mark.parametrize("effect", ["station_scale"])
def test_narrow_ranges_never_worse_up_to_10_percent_outside(effect):
    # calibration poses within a 40 deg window per joint, unseen poses up to 10 % of it beyond either end
    assert_floor("kr270", effect, 36003, 20, narrow_deg=40.0, outside=0.1)


# Before the reflector-block rules (calib.diagnose.confounds) a warm-up on a narrow UR10 campaign (30 poses, seed
# 40002: its own test below) was taken for a station shift + compliance, 8 % worse; with them the 30 examples hold.
@pytest.mark.slow
@settings(max_examples=30, suppress_health_check=list(HealthCheck))
@given(
    cell_name=st.sampled_from(sorted(CELLS)),
    effect=st.sampled_from([e for e in EFFECTS if e != "sagging_nest"]),
    seed=st.integers(40000, 49999),
    n_poses=st.integers(15, 60),
    narrow=st.booleans(),
)
def test_never_worse_property(cell_name, effect, seed, n_poses, narrow):
    kw = {"narrow_deg": 40.0, "outside": 0.1} if narrow else {}
    assert_floor(cell_name, effect, seed, n_poses, **kw)


# In the campaign order (station by station, point by point) a nest measured last at a station sags in a block of time
# of its own: a station shift between two reflector blocks (seed 36002: 11 % worse before) or a growth within each
# station's time (seed 36004: 57 % worse before) absorbed it. Neither is seen within a reflector's block
# (calib.diagnose.confounds): unexplained, the geometric model kept.
@pytest.mark.slow
@pytest.mark.parametrize("seed", [36002, 36004])
def test_sagging_nest_never_worse(seed):
    assert_floor("kr270", "sagging_nest", seed, 20)


@pytest.mark.slow
def test_warm_up_on_a_narrow_ur10_never_worse():
    # before: taken for a station shift + compliance, 8 % worse on the fresh poses measured after the campaign
    assert_floor("ur10", "warm_up", 40002, 30, narrow_deg=40.0, outside=0.1)


@pytest.mark.slow
def test_warm_up_beyond_physics_on_a_narrow_ur10_never_worse():
    # one of the property's examples (CI's derandomised draw): 15 poses in a 40 deg window take a warm-up of ~3000 ppm
    # to leave 3-6x the noise unabsorbed, 6x the 500 ppm a warming steel or aluminium arm reaches
    # (calib/diagnose/plausibility.py), so every growth candidate is refused. Before, a nest's sag took part of that
    # growth (the reflectors are measured one block of time after the other) with a held-out gain of p = 0.004, and
    # made the fresh poses 6.8 % worse; beside the refused warm-up as a nuisance its F test fails: unexplained
    assert_floor("ur10", "warm_up", 40000, 15, narrow_deg=40.0, outside=0.1)


def rows_by_blocks(points_per_station: int, poses: int) -> MeasurementTable:
    """Station by station, reflector by reflector, 20 s a row (tests/independent_twin.py's order); no measurement."""
    pose, station, point = [], [], []
    for sid in ("S1", "S2"):
        for k in range(points_per_station):
            for i in range(poses):
                pose.append(f"Q{i + 1}")
                station.append(sid)
                point.append(f"P{k + 1}")
    n = len(pose)
    return MeasurementTable(np.arange(n), 20.0 * np.arange(n), pose, station, point, np.zeros((n, 6)), None)


def test_a_station_shift_between_reflector_blocks_is_found():
    # 3 reflectors x 4 poses per station: S2's rows are t = 240 .. 460 s, P1 until 300 s, P2 from 320 to 380 s
    table = rows_by_blocks(3, 4)
    assert unrevisited(table, {"station": "S2", "after_t_s": 300.0}) == ["P2", "P3"]
    assert unrevisited(table, {"station": "S2", "after_t_s": 340.0}) == []  # P2 on both sides
    assert unrevisited(table, None) == []


def growth_refusal(effect: str, seed: int) -> list[str]:
    cell = CELLS["kr270"]
    c = campaign(cell, effect, seed, 20)
    geo = identify(cell.chain, c.table, cell.tool_points, c.params, noise=TrackerNoise())
    ctx = context(cell.chain, c.table, c.params, TrackerNoise(), geo, ("thermal_drift",))
    return growth_between_blocks(ctx, (), whole_fit(ctx, ()), geo.dof - 1, ALPHA)


def test_a_growth_carried_by_one_reflector_is_not_a_warm_up():
    # seed 36004: the sagging nest is measured last at both stations; its sag was a growth within each station's time
    refused = growth_refusal("sagging_nest", 36004)
    assert len(refused) == 1 and "displacement of reflector" in refused[0]
    # a warm-up of the whole arm (seed 36001) is seen across the reflectors: it stays a cause
    assert growth_refusal("warm_up", 36001) == []


def test_paired_test_needs_more_than_a_positive_gain():
    # 20 poses: the model better on 11, worse on 9 by as much: a positive mean gain, no evidence (11 of 20 signs
    # positive, as likely as not by chance: the signed-rank null is symmetric about 105, the tied ranks give 115.5)
    pose = [f"Q{i}" for i in range(20)]
    base = HeldOut(np.full(20, 1.0), np.ones(20, dtype=int))
    model = HeldOut(np.array([0.9] * 11 + [1.1] * 9), np.ones(20, dtype=int))
    assert model.rms_mm < base.rms_mm
    assert paired_pvalue(base, model, pose) > 0.1
    # better on all 20 by distinct amounts: p = 2^-20 (one of the 2^20 equally likely sign patterns)
    better = HeldOut(1.0 - 0.01 * np.arange(1, 21), np.ones(20, dtype=int))
    assert paired_pvalue(base, better, pose) == pytest.approx(2.0**-20)


def test_no_cross_validation_keeps_the_geometric_model():
    # 5 poses: holding out a pose (or a station's time block) leaves a training set that cannot identify the geometric
    # model (~40 unknowns); one pass, so no pass can be held out. The F test and BIC alone admit no cause
    cell = CELLS["kr270"]
    c = campaign(cell, "warm_up", 36004, 5)
    d = diagnose(cell.chain, c.table, cell.tool_points, c.params, TrackerNoise(), seed=36004)
    assert d.extended is None and d.causes == []
    assert d.cause == "unexplained"
    assert d.holdout_geometric_mm is None
    assert "second pass" in d.cv_note and "the geometric model is kept" in d.cv_note


def test_implausible_encoder_scale_is_refused():
    # the ABB fit: -49 % on joint 2, 100x the physical range; 0.1 % passes
    cell = CELLS["kr270"]
    c = campaign(cell, "none", 36005, 15)
    res = fit_cause(cell.chain, c.table, cell.tool_points, c.params, TrackerNoise(), "encoder_scale")
    ext = res.extension
    theta = np.zeros(ext.size)
    theta[ext.names.index("k2")] = -0.49
    assert any("k2" in why for why in implausible(ext, theta))
    theta[ext.names.index("k2")] = 0.2 * ENCODER_SCALE_MAX
    assert implausible(ext, theta) == []


def test_extension_is_held_outside_its_ranges_for_all_terms():
    # an encoder scale and a joint map fitted together: beyond joint 2's fitted range both are held, so the model's
    # joint offsets there equal those at the range's end (no linear term carried on against a held map)
    cell = CELLS["kr270"]
    c = campaign(cell, "none", 36006, 20, narrow_deg=40.0)
    fit = fit_cause(cell.chain, c.table, cell.tool_points, c.params, TrackerNoise(), "encoder_scale+cyclic_error")
    doc = model_doc(cell, fit.table, fit.result, fit.result, None, "twin")
    hi = doc["extension"]["valid"]["joints"]["joint_2"]["to_deg"]
    model = model_from_doc(json.loads(json.dumps(doc)))
    q = np.tile(c.table.q_deg[:1], (2, 1))
    q[0, 1], q[1, 1] = hi, hi + 10.0
    rows = MeasurementTable(np.arange(2), np.zeros(2), ["a", "b"], ["-", "-"], ["-", "-"], q, None, source="t")
    ext, theta = model.extension_for(rows)
    offsets = ext.joint_offsets(theta)
    assert np.allclose(offsets[0], offsets[1], atol=1e-15)
    assert "rows 2 of 2 leave the joint ranges" in model.range_warning(np.radians(q))


def test_compensate_refuses_targets_outside_the_fitted_ranges_unless_asked():
    cell = CELLS["kr270"]
    c = campaign(cell, "none", 36007, 20, narrow_deg=40.0)  # a window well inside the joint limits
    fit = fit_cause(cell.chain, c.table, cell.tool_points, c.params, TrackerNoise(), "encoder_scale")
    model = model_from_doc(model_doc(cell, fit.table, fit.result, fit.result, None, "twin"))
    ranges = model.ranges()
    inside = np.radians(c.table.q_deg[0])
    outside = inside.copy()
    outside[1] = ranges.joints_rad[1][1] + np.radians(2.0)
    targets = np.array([inside, outside])
    tcp = np.mean(list(model.points.values()), axis=0)
    _, report = compensate(model, targets, tcp)
    assert report.failures[0] == "" and "outside the joint ranges" in report.failures[1]
    _, report = compensate(model, targets, tcp, allow_outside=True)
    assert not report.failures[1].startswith("outside the joint ranges")


def test_ranges_round_trip():
    r = Ranges(((-1.0, 1.0), (0.0, 2.0)), (0.0, 3600.0))
    assert Ranges.from_doc(json.loads(json.dumps(r.to_doc())), 2).to_doc() == r.to_doc()
