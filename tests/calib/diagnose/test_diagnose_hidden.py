"""diagnose on campaigns from an independent generator (not mocks/): effects whose form is NOT a
candidate's exact form, two effects at once, and trackers noisier than their model.

The generator below is written for these tests only: its own true robot (random deviations of every
parameter of the complete model), its own stations and reference points, its own effect physics, and
the AT901 noise model (calib/identify/noise.py) scaled by a factor. Each effect is scaled so that what a geometric
calibration cannot absorb (RMS per coordinate of the noise-free residual of the geometric fit) is a
random multiple of the tracker noise, 3x to 6x (NOISE_RMS_MM ~15 um: AT901 at the cell's 2-4 m ranges).

An out-of-form effect must be named by its nearest physical candidate:
  harmonic 3-4 / high-order joint error -> cyclic_error; smooth (tanh) backlash -> backlash;
  compliance with the payload 30 % off the mass model -> joint_compliance;
  saturating (exponential warm-up) growth of the whole arm and tool -> thermal_warmup (its own form since that
  candidate landed), or thermal_drift when the campaign cannot see the curvature (calib/diagnose/warmup.py);
  a station drifting gradually -> station_shift (the nearest: the station is not where it started).
Seeds: the decision rules in calib/diagnose/selection.py were designed on seeds 0-99; these tests use seeds from
5000 up (fast set) and 7000 up (slow set), never looked at while designing. Magnitudes and effect
parameters are drawn from each seed.
"""

import json
from dataclasses import replace

import numpy as np
import pytest

from tests.independent_twin import TrueCell
from trackcal.calib.diagnose import diagnose
from trackcal.calib.doe.poses import random_poses
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.identify.solver import identify
from trackcal.calib.io.table import MeasurementTable, write_table
from trackcal.calib.model.cell import load_cell
from trackcal.calib.model.params import irreducible_params
from trackcal.calib.model.pinmodel import gravity_torques
from trackcal.calib.model.rigid import exp_so3
from trackcal.campaign.cli import main

NOISE_RMS_MM = 0.015  # AT901 model (calib/identify/noise.py) at 2-4 m: sqrt((5^2 + 2 * 16^2) / 3) um
SECONDS_PER_ROW = 20.0  # a tracker measurement with the robot settling (paper section 7.3 campaign pace)
CELL = load_cell("kr270")
PARAMS = irreducible_params(CELL.chain)[0]


class World(TrueCell):
    """A true KR-270 cell: robot deviations (~0.3 mm lengths, ~0.02 deg angles: paper Table 8 orders of magnitude),
    stations and points drawn from the seed, as the independent twin draws them (tests/independent_twin.py)."""

    def __init__(self, rng: np.random.Generator):
        super().__init__(CELL, rng)

    def rows(self, poses: np.ndarray, passes: int = 1):
        """Campaign order: station by station, point by point, pass by pass, poses in order."""
        out = []
        for sid in self.stations:
            for pid in self.points:
                for _ in range(passes):
                    for i, q in enumerate(poses):
                        out.append((f"Q{i + 1}", sid, pid, q))
        return out


def last_moves(q: np.ndarray) -> np.ndarray:
    """(N, n) rad: each joint's last non-zero move before the row (0 before the first)."""
    out = np.zeros_like(q)
    state = np.zeros(q.shape[1])
    for r in range(1, len(q)):
        d = q[r] - q[r - 1]
        state = np.where(np.abs(d) > 1e-9, d, state)
        out[r] = state
    return out


def effect(name: str, rng: np.random.Generator, n_rows: int):
    """A unit-scale effect: (joint error fn(q, t) -> dq, arm scale fn(t) -> s, station drift fn(sid, t))."""
    n = CELL.chain.dof
    duration = n_rows * SECONDS_PER_ROW
    none = (None, None, None)
    if name in ("harmonic34", "high_order"):
        joints = rng.choice(np.arange(1, 5), 2, replace=False)  # A2..A5: they move the points most
        orders = rng.integers(3, 5, 2) if name == "harmonic34" else rng.integers(12, 30, 2)
        phases = rng.uniform(0, 2 * np.pi, 2)

        def dq(q, t):
            out = np.zeros_like(q)
            for j, h, ph in zip(joints, orders, phases, strict=True):
                out[:, j] += np.sin(h * q[:, j] + ph)
            return out

        return dq, None, None
    if name == "tanh_backlash":
        width = np.radians(rng.uniform(1.0, 3.0))  # the dead band is taken up over a few degrees of travel
        shape = rng.uniform(0.5, 1.5, n)
        return (lambda q, t: shape * np.tanh(last_moves(q) / width)), None, None
    if name == "payload_off":
        joints = list(CELL.chain.joints)
        joints[-1] = replace(joints[-1], mass_kg=joints[-1].mass_kg * (1 + rng.choice([-0.3, 0.3])))
        true_chain = replace(CELL.chain, joints=tuple(joints))
        soft = rng.uniform(0.5, 1.5, n)
        return (lambda q, t: soft * gravity_torques(true_chain, q)), None, None
    if name == "encoder":
        k = rng.choice([-1.0, 1.0], n) * rng.uniform(0.5, 1.0, n)
        return (lambda q, t: k * q), None, None
    if name == "warm_up":
        tau = duration * rng.uniform(0.2, 0.5)  # exponential approach to the warm length
        return None, (lambda t: 1.0 - np.exp(-t / tau)), None
    if name == "drifting_station":
        sid = sorted(CELL.stations)[rng.integers(0, len(CELL.stations))]
        v, w = rng.normal(0, 1, 3), rng.normal(0, 1e-4, 3)
        start = duration * rng.uniform(0.0, 0.3)
        return None, None, (sid, lambda t: np.clip((t - start) / duration, 0, None), v, w)
    if name == "station_step":  # the candidate's own form: a station moved once, at a row
        sid = sorted(CELL.stations)[rng.integers(0, len(CELL.stations))]
        v, w = rng.normal(0, 1, 3), rng.normal(0, 1e-4, 3)
        cut = SECONDS_PER_ROW * rng.integers(n_rows // 8, n_rows // 2)
        return None, None, (sid, lambda t: (t > cut).astype(float), v, w)
    if name == "none":
        return none
    raise ValueError(name)


def measure(world: World, rows, t: np.ndarray, effects: list, scales: list[float]) -> np.ndarray:
    q = np.array([r[3] for r in rows])
    dq = np.zeros_like(q)
    growth = np.zeros(len(rows))
    for (jf, sf, _), a in zip(effects, scales, strict=True):
        if jf is not None:
            dq += a * jf(q, t)
        if sf is not None:
            growth += a * sf(t)
    tool = np.array([world.points[r[2]] for r in rows])
    p = world.kin.points(q + dq, tool, world.dev)
    o0 = CELL.chain.base[:3, 3]
    p = o0 + (1.0 + growth)[:, None] * (p - o0)  # the whole arm and the tool grow
    x = np.array([world.stations[r[1]].apply(pi[None])[0] for r, pi in zip(rows, p, strict=True)])
    for (_, _, drift), a in zip(effects, scales, strict=True):
        if drift is None:
            continue
        sid, f, v, w = drift
        m = np.array([r[1] == sid for r in rows])
        s = a * f(t[m])
        rot = np.array([exp_so3(si * w) for si in s])
        x[m] = np.einsum("nij,nj->ni", rot, x[m]) + s[:, None] * v
    return x


def table_of(rows, t, xyz) -> MeasurementTable:
    return MeasurementTable(
        np.arange(1, len(rows) + 1),
        t,
        [r[0] for r in rows],
        [r[1] for r in rows],
        [r[2] for r in rows],
        np.degrees(np.array([r[3] for r in rows])),
        xyz,
        source="independent generator",
    )


def unabsorbed(rows, t, xyz) -> float:
    """RMS per coordinate of what the geometric model cannot absorb (noise-free table)."""
    res = identify(CELL.chain, table_of(rows, t, xyz), CELL.tool_points, PARAMS)
    return float(np.sqrt(np.mean(res.residuals**2)))


def campaign(
    seed: int,
    names: tuple[str, ...],
    n_poses: int = 30,
    noise_factor: float = 1.0,
    passes: int = 1,
    times_noise: tuple[float, float] = (3.0, 6.0),
    radial_factor: float = 1.0,
):
    rng = np.random.default_rng(seed)
    world = World(rng)
    rows = world.rows(np.round(random_poses(CELL, n_poses, rng), 6), passes)
    t = np.arange(len(rows)) * SECONDS_PER_ROW
    effects = [effect(n, rng, len(rows)) for n in names]
    scales = []
    for i, e in enumerate(effects):
        if e == (None, None, None):
            scales.append(0.0)
            continue
        # a small trial scale, then linear scaling to the drawn magnitude of what geometry cannot absorb
        base = measure(world, rows, t, effects, [0.0] * len(effects))
        probe = [1e-6 if k == i else 0.0 for k in range(len(effects))]
        got = unabsorbed(rows, t, measure(world, rows, t, effects, probe)) - unabsorbed(rows, t, base)
        scales.append(1e-6 * rng.uniform(*times_noise) * NOISE_RMS_MM / max(got, 1e-300))
    xyz = measure(world, rows, t, effects, scales)
    tracker = TrackerNoise(0.005 * noise_factor * radial_factor, 0.0075 * noise_factor, 0.003 * noise_factor)
    for sid in world.stations:
        m = np.array([r[1] == sid for r in rows])
        xyz[m] += tracker.sample(xyz[m], rng)
    return table_of(rows, t, xyz)


# the candidates nearest each effect. A first-order warm-up g0 (1 - exp(-t / tau)) about the base origin is
# thermal_warmup's own form (calib/diagnose/extensions.py, pivot e_inf_base); thermal_drift, the linear drift, is the
# same growth's limit of a tau long against the campaign, and the one diagnose offers when the warm-up's curvature is
# not significant (calib/diagnose/warmup.py). This table named thermal_drift alone, written before thermal_warmup was a
# candidate: naming the exact form failed the check (seed 5001: thermal_warmup, held-out 65 -> 15 um, the noise).
NEAREST = {
    "harmonic34": {"cyclic_error"},
    "high_order": {"cyclic_error"},
    "tanh_backlash": {"backlash"},
    "payload_off": {"joint_compliance"},
    "encoder": {"encoder_scale"},
    "warm_up": {"thermal_warmup", "thermal_drift"},
    "drifting_station": {"station_shift"},
}


def verdict(seed: int, names: tuple[str, ...], **kw):
    d = diagnose(CELL.chain, campaign(seed, names, **kw), CELL.tool_points, PARAMS, TrackerNoise(), seed=seed)
    return d, [c["cause"] for c in d.causes]


def check(seed: int, names: tuple[str, ...], **kw) -> str | None:
    """None when diagnose names every hidden effect by its nearest candidate with a held-out gain."""
    d, named = verdict(seed, names, **kw)
    if names == ("high_order",) and d.cause == "unexplained":
        # issue 36: 30 poses sample a harmonic of 12-30 cycles per revolution less than twice per cycle over a joint's
        # range: aliased, as a motor-side gear error is; unexplained with the geometric model is a right verdict
        return None
    want = [NEAREST[n] for n in names if n != "none"]
    if not want:
        return None if d.cause == "none" else f"seed {seed} {names}: {d.cause} {named}"
    gained = all(c["gain_mm"] is None or c["gain_mm"] > 0 for c in d.causes)
    if not all(w & set(named) for w in want) or d.cause not in set().union(*want) or not gained:
        return f"seed {seed} {names}: {d.cause} {named}"
    return None


def finite_or_null(obj) -> bool:
    """Every number in a (nested) verdict is finite or None."""
    if isinstance(obj, dict):
        return all(finite_or_null(v) for v in obj.values())
    if isinstance(obj, (list, tuple)):
        return all(finite_or_null(v) for v in obj)
    if isinstance(obj, float):
        return bool(np.isfinite(obj))
    return True


@pytest.mark.slow  # a statistical acceptance check, among make test's slowest (issue 37): make test-slow
@pytest.mark.parametrize("names", [("tanh_backlash",), ("payload_off",), ("warm_up",), ("drifting_station",)])
def test_out_of_form_effect_is_named_by_its_nearest_cause(names):
    assert check(5001, names) is None


def test_harmonic_3_4_joint_error_is_cyclic_error():
    assert check(5001, ("harmonic34",)) is None


@pytest.mark.slow  # a statistical acceptance check, among make test's slowest (issue 37): make test-slow
@pytest.mark.parametrize("names", [("payload_off", "tanh_backlash"), ("encoder", "warm_up")])
def test_two_effects_are_both_named(names):
    assert check(5002, names) is None


@pytest.mark.slow  # one diagnosis of 60 rows with two causes, ~1 min on a loaded machine
def test_warm_up_with_an_encoder_scale_names_no_third_cause():
    # the generator's warm-up is thermal_warmup's exact form and its encoder error encoder_scale's: the two explain the
    # data to the noise, a third cause is a false one. Before tau was profiled again against the causes chosen after
    # it (calib/diagnose/warmup.py), tau stayed where the geometric residual, the encoder error in it, put it, and a
    # range scale of station S2 joined on a 0.3 um held-out gain
    d, named = verdict(5002, ("encoder", "warm_up"))
    assert sorted(named) == ["encoder_scale", "thermal_warmup"], named


def test_high_order_joint_error_is_never_noise():
    # a joint error at 12-30 cycles per revolution must never pass for noise: named, or detected structure
    d, named = verdict(5003, ("high_order",))
    assert d.cause != "none" and (d.causes or d.structure["structure"]), (d.cause, named)


@pytest.mark.slow  # a statistical acceptance check, among make test's slowest (issue 37): make test-slow
def test_high_order_joint_error_is_cyclic_error():
    assert check(5003, ("high_order",)) is None


@pytest.mark.slow  # a statistical acceptance check, among make test's slowest (issue 37): make test-slow
@pytest.mark.parametrize("seed", [5004, 5005, 5006])
def test_noisier_tracker_is_none_with_its_noise_scale(seed):
    d, named = verdict(seed, ("none",), noise_factor=1.5)
    assert d.cause == "none", named
    # the residual RMS over the model's noise: 1.5 (the generator's factor); with ~500 degrees of freedom
    # its sampling sd is ~1.5 / sqrt(2 * 500) = 0.05, so +-0.2 is four of them
    assert d.noise_scale == pytest.approx(1.5, abs=0.2)


@pytest.mark.slow  # a statistical acceptance check, among make test's slowest (issue 37): make test-slow
@pytest.mark.parametrize("seed", [5010, 5011])
def test_tracker_noisier_along_its_line_of_sight_is_none(seed):
    # the distance meter 2x noisier than the model, the angles as modelled: a noise model wrong in shape,
    # not only in scale, is still not a cause
    d, named = verdict(seed, ("none",), radial_factor=2.0)
    assert d.cause == "none", (named, d.structure)


def test_planned_campaign_verdict_has_no_inf_or_nan():
    # 6 configurations x 3 passes (the plan trackcal makes): whole-pose folds leave 5 configurations,
    # which cannot identify the model; the verdict falls back or says so, never inf / NaN
    table = campaign(5007, ("tanh_backlash",), n_poses=6, passes=3)
    d = diagnose(CELL.chain, table, CELL.tool_points, PARAMS, TrackerNoise(), seed=5007)
    assert finite_or_null([d.holdout_geometric_mm, d.holdout_extended_mm, d.causes, d.structure])
    assert finite_or_null([[c.holdout_rms_mm, c.f_pvalue, c.delta_bic, c.rms_mm] for c in d.candidates])
    assert (d.holdout_geometric_mm is None) == (d.cv_note is not None)


def test_planned_campaign_verdict_is_strict_json(tmp_path):
    data, out = tmp_path / "t.csv", tmp_path / "v.json"
    write_table(campaign(5012, ("tanh_backlash",), n_poses=6, passes=3), data)
    assert main(["diagnose", str(data), "--cell", "kr270", "--json", str(out)]) == 0

    def reject(name):
        raise ValueError(f"verdict.json holds {name}")

    v = json.loads(out.read_text(), parse_constant=reject)
    assert (v["holdout"]["rms_geometric_mm"] is None) == (v["holdout"]["note"] is not None)
    assert all(c["holdout_rms_mm"] is not None or c["cv_note"] for c in v["candidates"])


def test_station_step_change_point_is_found_exactly():
    # a 10x-noise step: misplacing the cut by one row costs ~100 noise variances, so the exact cut is the
    # only answer the data allow
    seed = 5008
    rng = np.random.default_rng(seed)
    table = campaign(seed, ("station_step",), times_noise=(10.0, 10.0))
    World(rng)  # replay the generator's draws up to the effect's cut
    random_poses(CELL, 30, rng)
    rows = 30 * len(CELL.tool_points) * len(CELL.stations)
    sid = sorted(CELL.stations)[rng.integers(0, len(CELL.stations))]
    rng.normal(0, 1, 3), rng.normal(0, 1e-4, 3)
    cut = SECONDS_PER_ROW * rng.integers(rows // 8, rows // 2)
    d = diagnose(CELL.chain, table, CELL.tool_points, PARAMS, TrackerNoise(), seed=seed)
    assert d.cause == "station_shift"
    assert d.shift == {"station": sid, "after_t_s": float(cut)}


@pytest.mark.slow  # a statistical acceptance check, among make test's slowest (issue 37): make test-slow
def test_floor_from_comparable_repeats_ignores_backlash():
    # three passes: repeats of a pose with the same approach directions, a pass apart; a backlash seen
    # from alternating directions must not enter the floor, which is then the tracker's own scatter
    table = campaign(5009, ("tanh_backlash",), passes=3, times_noise=(6.0, 6.0))
    d = diagnose(CELL.chain, table, CELL.tool_points, PARAMS, TrackerNoise(), seed=5009)
    expected = float(np.sqrt(np.mean(np.trace(TrackerNoise().covariance(table.xyz), axis1=1, axis2=2) / 3)))
    assert d.floor_source.startswith("comparable repeats")
    # ~1000 degrees of freedom: the floor's sampling sd is ~2 %; 10 % is five of them
    assert d.noise_floor_mm == pytest.approx(expected, rel=0.1)
    assert d.cause == "backlash"


EFFECTS = ("none", "tanh_backlash", "payload_off", "warm_up", "drifting_station", "harmonic34", "high_order")
PAIRS = (("payload_off", "tanh_backlash"), ("encoder", "warm_up"))


@pytest.mark.slow
def test_many_seeds_out_of_form_pairs_and_noisier_trackers():
    failures = [
        f
        for seed in range(7000, 7006)
        for names in (*[(e,) for e in EFFECTS], *PAIRS)
        if (f := check(seed, names)) is not None
    ]
    failures += [
        f"seed {s} none x1.5: {verdict(s, ('none',), noise_factor=1.5)[0].cause}"
        for s in range(7100, 7106)
        if verdict(s, ("none",), noise_factor=1.5)[0].cause != "none"
    ]
    assert not failures, failures
