"""`iso9283 plan | compare` on typed options: the ISO 9283 acceptance test of a cell, before and after compensation.

    trackcal iso9283 plan --cell C --json iso.json [--model model.json] [--side MM] [--centre X,Y,Z] [--cycles N]
    trackcal iso9283 compare SESSION [SESSION ...] --model model.json [--json out.json]

`plan` writes a plan that `trackcal run` walks (`order: iso9283`): the five poses of the cube (calib.doe.iso_cube)
visited P1, P5, P4, P3, P2 in each of `cycles` cycles, one reflector point measured from one station. With
`--model` the joints are the compensated targets of that model for the same poses (calib.compensate), the commanded
positions unchanged: the "after" test. `compare` computes the standard's figures (calib.iso9283) of each session's
attained positions, expressed in the robot base frame through the model's estimate of the station (the tracker
stays where the calibration left it), and puts the sessions side by side.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from datetime import UTC, datetime
from importlib.metadata import version
from pathlib import Path

import numpy as np
import yaml

from trackcal.calib.compensate import compensate
from trackcal.calib.doe.iso_cube import (
    APPROACH_FRACTION,
    CORNER_FRACTION,
    CYCLE_ORDER,
    POSE_NAMES,
    VAP_POSES,
    CubeError,
    IsoPlan,
    approach_joints,
    approach_sides,
    iso_plan,
)
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.identify.solver import Station
from trackcal.calib.io import fields
from trackcal.calib.io.files import write_json
from trackcal.calib.io.table import MeasurementTable
from trackcal.calib.iso9283 import (
    CYCLES,
    DISTANCE_POSES,
    Figure,
    IsoFigures,
    PoseFigures,
    attained_orientations,
    distance_accuracy,
    drift,
    multidirectional_variation,
    orientation_figures,
    pose_accuracy,
    pose_repeatability,
)
from trackcal.calib.model.cell import Cell, load_cell
from trackcal.calib.model.kinematics import Kinematics
from trackcal.calib.model_file import Model
from trackcal.campaign.cells.identity import stated_tracker
from trackcal.campaign.engine.steps import (
    PlanError,
    drift_block,
    iso_block,
    iso_points,
    iso_velocities,
    plan_arrays,
    vap_block,
    visibility,
)
from trackcal.campaign.errors import InputError, OptionError
from trackcal.campaign.jobs.iso9283_budget import (
    BudgetContext,
    ad_budget_of,
    centring_mm,
    other_budgets,
    pose_budgets,
    temperature_halfrange,
)
from trackcal.campaign.jobs.iso9283_departures import STANDARD_VELOCITIES, departures
from trackcal.campaign.jobs.iso9283_field import field_check
from trackcal.campaign.jobs.iso9283_trace import expired_certificate, traceability
from trackcal.campaign.jobs.trusted import trusted_model, usable_model
from trackcal.campaign.report.iso9283_conformity import conformity_doc, verdicts
from trackcal.campaign.session.session import export_table, session_cell, session_plan, stored_measurements
from trackcal.campaign.session.store import SessionStore


@dataclass(frozen=True)
class PlanOptions:
    cell: str
    json: str
    model: str | None = None
    side_mm: float | None = None
    centre_mm: tuple[float, float, float] | None = None
    cycles: int = CYCLES
    seed: int = 0
    vap_cycles: int | None = None  # the multi-directional test's cycles (ISO 9283:1998, 7.2); None: as `cycles`
    orientation: bool = False  # measure every tool point the station sees, for AP_a..RP_c (7.2)
    load: str | None = None  # what the robot carries during the test (ISO 9283:1998, 6.6), free text for the report
    accept_edited: bool = False  # --model: use it though its digest does not match its content (calib.model_trust)
    accept_poor: bool = False  # --model: use it though it is marked unusable (calib.model_trust)
    velocities: tuple[float, ...] = STANDARD_VELOCITIES  # % of the rated velocity, each a test of its own (6.7)
    warm_up_cycles: int = 0  # cycles of the test's poses before the test, nothing measured (6.2)
    drift_hours: float | None = None  # the drift test instead (7.6): P1 in groups of `cycles` over these hours
    drift_groups: int | None = None  # ... this many groups (None: one an hour and one at the start, at least 2)
    field_check: tuple[str, str, float] | None = None  # two tool points and their certified distance, mm


def plan_doc(
    cell_name: str,
    plan: IsoPlan,
    q_deg: np.ndarray,
    cycles: int,
    compensated_with: dict | None,
    vap: dict | None = None,
    points: list[str] | None = None,
) -> dict:
    return {
        "criterion": "iso9283",
        "order": "iso9283",
        "cell": cell_name,
        "poses_deg": np.round(q_deg, 4).tolist(),
        "repeat": cycles,
        "iso9283": {
            "station": plan.station,
            "point": plan.point,
            "pose_names": list(POSE_NAMES),
            "cycle_order": [POSE_NAMES[i] for i in CYCLE_ORDER],
            "cube_centre_mm": [round(float(v), 4) for v in plan.cube.centre_mm],
            "cube_side_mm": round(plan.cube.side_mm, 4),
            "corner_fraction": plan.fraction,
            "tcp_mm": np.round(plan.tcp_mm, 4).tolist(),
            "commanded_mm": np.round(plan.commanded_mm, 4).tolist(),
            "nominal_poses_deg": np.round(np.degrees(plan.q_rad), 4).tolist(),
            "compensated_with": compensated_with,
        }
        | ({"vap": vap} if vap else {})
        | ({"points": points} if points else {}),
    }


def _check_conditions(opts: PlanOptions) -> None:
    """The test's load and velocities as the standard asks them (ISO 9283:1998, 6.6 and 6.7), or an OptionError."""
    if not (opts.load or "").strip():
        raise OptionError(
            "{0} is required: what the robot carries during the test (ISO 9283:1998, 6.6), e.g. "
            "'270 kg, 100 % rated', or 'unloaded' to state that it carries nothing",
            "load",
        )
    if (
        not opts.velocities
        or any(not 0 < v <= 100 for v in opts.velocities)
        or len(set(opts.velocities)) != len(opts.velocities)
    ):
        raise OptionError(
            "{0}: expected distinct percentages of the rated velocity in (0, 100], e.g. 100,50,10", "velocities"
        )


def make_plan(opts: PlanOptions, warnings: list[str] | None = None) -> dict:
    """The ISO 9283 plan of a cell, written to opts.json; with a model (checked: campaign.jobs.trusted, its warning
    lines added to `warnings`), its compensated targets."""
    _check_conditions(opts)
    drift = _drift_options(opts)
    if opts.warm_up_cycles < 0:
        raise OptionError("{0} must be 0 (no warm-up) or more", "warm_up_cycles")
    if opts.cycles < 2:
        raise OptionError("{0} must be at least 2 (repeatability needs two cycles; the standard asks for 30)", "cycles")
    if opts.side_mm is not None and not opts.side_mm > 0:
        raise OptionError("{0} must be a positive length in mm", "side_mm")
    vap_cycles = 0 if drift else opts.cycles if opts.vap_cycles is None else opts.vap_cycles
    if vap_cycles == 1 or vap_cycles < 0:
        raise OptionError("{0} must be 0 (no multi-directional test) or at least 2", "vap_cycles")
    cell = load_cell(opts.cell)
    model = None
    if opts.model:  # checked before the cube is placed
        model, checked = trusted_model(opts.model, opts.accept_edited)
        checked += usable_model(model, opts.model, opts.accept_poor)
        if warnings is not None:
            warnings += checked
    plan = iso_plan(cell, opts.side_mm, opts.centre_mm, CORNER_FRACTION, opts.seed)
    largest = plan.cube.side_mm if opts.side_mm is None else _largest_side(cell, plan, opts.seed)
    q_deg = np.degrees(plan.q_rad)
    q_app = approach_joints(cell, plan) if vap_cycles else None  # (3 poses, 3 sides, n) rad
    compensated_with = None
    if model is not None:
        if model.chain.dof != cell.chain.dof:
            raise InputError(f"{opts.model}: a model of {model.chain.dof} joints for a cell of {cell.chain.dof}")
        bound = (cell.max_correction_mm, cell.max_correction_deg)
        q_comp, report = compensate(model, plan.q_rad, cell.tcp, max_correction=bound)
        failed = [f"{POSE_NAMES[i]}: {f}" for i, f in enumerate(report.failures) if f]
        if failed:
            raise InputError(f"{opts.model}: the ISO poses cannot be compensated: {'; '.join(failed)}")
        q_deg = np.degrees(q_comp)
        if q_app is not None:  # the approach points compensated too: the robot still comes in along the base axes
            flat, rep = compensate(model, q_app.reshape(-1, q_app.shape[-1]), cell.tcp, max_correction=bound)
            if any(rep.failures):
                raise InputError(
                    f"{opts.model}: the vAP approach points cannot be compensated: "
                    + "; ".join(f for f in rep.failures if f)
                )
            q_app = flat.reshape(q_app.shape)
        compensated_with = {
            "model": str(opts.model),
            "sha256": hashlib.sha256(Path(opts.model).read_bytes()).hexdigest(),
            "test_pose": model.doc.get("test_pose"),
        }  # the model's stated figure (calib.tcp_figure)
    points = orientation_points(cell, plan, q_deg) if opts.orientation else None
    vap = None
    if q_app is not None:
        vap = {
            "cycles": vap_cycles,
            "poses": [POSE_NAMES[i] for i in VAP_POSES],
            "approaches": approach_sides(plan),
            "approach_mm": round(APPROACH_FRACTION * plan.cube.side_mm, 4),
            "approach_deg": np.round(np.degrees(q_app), 4).tolist(),
        }
    doc = plan_doc(cell.name, plan, q_deg, opts.cycles, compensated_with, vap, points)
    doc["iso9283"]["load"] = opts.load.strip()
    doc["iso9283"]["velocities"] = [float(v) for v in opts.velocities][: 1 if drift else None]
    if drift:
        doc["iso9283"]["drift"] = drift
    doc["iso9283"]["warm_up_cycles"] = opts.warm_up_cycles
    if opts.field_check is not None:
        doc["iso9283"]["field_check"] = _field_check_block(cell, opts.field_check)
    if largest is not None:  # the report names a smaller cube as a departure (6.8)
        doc["iso9283"]["largest_side_mm"] = round(largest, 4)
    write_json(opts.json, doc)
    return doc


# ISO 9283:1998, 6.6 (load to the mechanical interface): tests run with 100 % of the rated load
# (10 % optionally); what the robot carried is the tester's to state (`iso9283 plan --load`, required; "unloaded" said
# explicitly): trackcal cannot weigh it. A plan written before --load was required may still lack it
NO_LOAD = "not stated (give it with iso9283 plan --load)"
UNLOADED = "unloaded"  # the one word that states the robot carries nothing


# the conditions of a test in the order a report reads them: what was tested, how, in which environment, when
CONDITION_ORDER = (
    "robot",
    "cell",
    "tool",
    "tool point measured",
    "station",
    "tracker (its U)",
    "tracker serial",
    "tracker certificate",
    "field check",
    "reflector centring",
    "load",
    "speed",
    "warm-up",
    "targets",
    "cube",
    "cycles",
    "temperature",
    "air pressure",
    "humidity",
    "started",
    "ended",
    "complete",
    "mode",
    "trackcal version",
)


def _drift_options(opts: PlanOptions) -> dict | None:
    """The plan's drift block (7.6) from the options, checked; None without --drift."""
    if opts.drift_hours is None:
        if opts.drift_groups is not None:
            raise OptionError("{0} needs {1}", "drift_groups", "drift_hours")
        return None
    if not 0 < opts.drift_hours < math.inf:
        raise OptionError("{0} must be a positive number of hours", "drift_hours")
    groups = opts.drift_groups if opts.drift_groups is not None else max(2, math.floor(opts.drift_hours) + 1)
    if groups < 2:
        raise OptionError("{0} must be at least 2 (the drift compares the first group with the last)", "drift_groups")
    if opts.warm_up_cycles:
        raise OptionError(
            "{0} and {1}: the drift test measures the change from the robot as it starts, no warm-up before it",
            "warm_up_cycles",
            "drift_hours",
        )
    return {"hours": float(opts.drift_hours), "groups": groups, "cycles": opts.cycles}


def _field_check_block(cell: Cell, given: tuple[str, str, float]) -> dict:
    """The plan's field check (campaign.jobs.iso9283_field), checked: two distinct tool points, a length > 0."""
    a, b, length = given
    if a == b or a not in cell.tool_points or b not in cell.tool_points or not 0 < length < math.inf:
        raise OptionError(
            "{0}: expected two distinct reference points of the tool ({points}) and their certified "
            "distance in mm > 0, e.g. P1,P3,188.012",
            "field_check",
            points=", ".join(sorted(cell.tool_points)),
        )
    return {"points": [a, b], "length_mm": float(length)}


def _largest_side(cell: Cell, plan: IsoPlan, seed: int) -> float | None:
    """The largest cube side the robot reaches about the given cube's centre (None: none found there)."""
    try:
        return iso_plan(cell, None, tuple(plan.cube.centre_mm), CORNER_FRACTION, seed).cube.side_mm
    except CubeError:
        return None


def orientation_points(cell, plan: IsoPlan, q_deg: np.ndarray) -> list[str]:
    """Every tool point the test's station sees at all five poses (nominal model), the test's point last; at least
    three (three points fix the attained orientation: calib.iso9283.attained_orientations), else InputError."""
    vis = visibility(cell, np.round(q_deg, 4))
    seen = [p for p in sorted(cell.tool_points) if p != plan.point and vis[(plan.station, p)].all()]
    if len(seen) < 2:
        raise InputError(
            f"--orientation needs three tool points that station {plan.station} sees at all five poses; "
            f"it sees {', '.join([*seen, plan.point])}"
        )
    return [*seen, plan.point]


def _utc(t_wall: float, seconds: bool = False) -> str:
    return datetime.fromtimestamp(t_wall, UTC).strftime("%Y-%m-%d %H:%M" + (":%S" if seconds else "") + " UTC")


def _session_inputs(directory: Path):
    """(cell, plan, table, conditions) of a session: when it ran, how (simulated or hardware, seed)."""
    store = SessionStore.open(directory, readonly=True)
    try:
        events, meta = store.events(), store.meta()
        seed = f" (seed {meta['seed']})" if meta.get("seed") else ""
        conditions = {
            "started": _utc(events[0].t_wall) if events else "-",
            "ended": _utc(events[-1].t_wall) if events else "-",
            "complete": "yes" if any(e.kind == "campaign_done" for e in events) else "no",
            "mode": meta.get("mode", "-") + seed,
        }
        conditions["warm-up"] = warm_up_record(events)
        docs = stored_measurements(store)
        conditions.update(_field_check_record(store, directory, docs))
        sides = [m.get("approach", "") for m in docs]  # vAP visits (7.2) name theirs
        speeds = np.array([float(m.get("velocity_pct", 0.0)) for m in docs])  # the test velocity (6.7) of each
        groups = np.array([int(m.get("drift_group", 0)) for m in docs])  # the drift test's group (7.6) of each
        overrides = sorted(
            {
                float(e.data["args"][1])
                for e in store.events("call")
                if e.data.get("device") == "robot" and e.data.get("op") == "move" and len(e.data.get("args", [])) > 1
            }
        )
        conditions["speed"] = (
            (
                ", ".join(f"{v:g}" for v in overrides) + " % joint speed override, PTP moves: the "
                "session's setting, no test velocity planned (ISO 9283:1998, 6.7: 100 %, 50 % and "
                "10 % of the rated velocity)"
            )
            if overrides
            else "no move recorded"
        )
        tool_text = store.documents().get("config/tool.yaml")
        tool_doc = yaml.safe_load(tool_text) if tool_text else None
        conditions["tool"] = str((tool_doc or {}).get("name") or "-")
        conditions.update(traceability(store, directory))
        conditions["reflector centring"] = (
            f"±{centring_mm(tool_doc) * 1000:g} µm (the tool file)"
            if centring_mm(tool_doc) is not None
            else "not stated by the tool file"
        )
        return (
            session_cell(store),
            session_plan(store),
            export_table(store, str(directory)),
            conditions,
            Visits(np.zeros(0), np.asarray(sides), speeds, group=groups),
            centring_mm(tool_doc),
        )
    finally:
        store.close()


def _field_check_record(store: SessionStore, directory: Path, docs: list) -> dict[str, str]:
    """The session's field check as the report states it ({} when its plan has none)."""
    block = (session_plan(store).get("iso9283") or {}).get("field_check")
    if not block:
        return {}
    rows = {
        p: np.array([m["xyz_mm"] for m in docs if m.get("field_check") and m["point"] == p]) for p in block["points"]
    }
    found = field_check(block, rows, stated_tracker(store), session_cell(store).tracker)
    return {"field check": found.describe() if found else "planned, not measured: a point was not seen"}


def warm_up_record(events) -> str:
    """The warm-up the session ran before the test (ISO 9283:1998, 6.2), from its recorded steps: the cycles done,
    the velocity, when it started and ended; "none" when the plan had none."""
    started = [(k, e) for k, e in enumerate(events) if e.kind == "step_started" and e.data["step"].get("warm_up")]
    if not started:
        return "none recorded (ISO 9283:1998, 6.2, conditions prior to testing: the warm-up its maker specifies)"
    done = [e for k, e in enumerate(events) if e.kind == "step_done" and k > started[-1][0]][:1]
    moves = [e.data["step"] for _, e in started if e.data["step"]["kind"] == "move"]
    cycles = len(moves) / len(POSE_NAMES)
    end = _utc(done[0].t_wall, True) if done else "not finished"
    order = " ".join(POSE_NAMES[i] for i in CYCLE_ORDER)
    return (
        f"{cycles:g} cycle{'' if cycles == 1 else 's'} of {order} at {moves[0].get('speed_pct', 0):g} "
        f"%, nothing measured, {_utc(started[0][1].t_wall, True)} to {end} (ISO 9283:1998, 6.2)"
    )


def _meteo(table, key: str, unit: str, digits: int) -> str:
    """Mean (min-max) of a meteo column of the session's measurements (the station's sensor at each measurement)."""
    v = np.array([float(x) for x in table.extra.get(key, [])]) if table.extra else np.zeros(0)
    return f"{v.mean():.{digits}f} {unit} ({v.min():.{digits}f}-{v.max():.{digits}f})" if len(v) else "not recorded"


@dataclass(frozen=True)
class InBase:
    """The attained positions of a session's rows in the base frame of the model's estimate of the ISO station,
    R^T (x - t), and their covariances R^T Sigma R (Sigma: `noise`, the tracker's)."""

    table: MeasurementTable
    station: Station
    noise: TrackerNoise

    def __call__(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        rot, xyz = self.station.rotation, self.table.xyz[rows]
        return (xyz - self.station.translation) @ rot, np.einsum("ji,njk,kl->nil", rot, self.noise.covariance(xyz), rot)


def session_tests(directory: Path, model: Model, noise: TrackerNoise | None = None) -> list[IsoFigures]:
    """The ISO 9283 tests of one session, one per test velocity of its plan (6.7), in the plan's order."""
    cell, plan, _, _, _, _ = _session_inputs(directory)
    poses, _ = plan_arrays(plan)
    iso = iso_block(plan, cell, len(poses))
    if iso is None:
        raise PlanError(f"{directory}: its plan is no ISO 9283 plan (order {plan.get('order', 'campaign')!r})")
    return [session_figures(directory, model, noise, v) for v in iso_velocities(iso)]


def drift_test(directory: Path, model: Model, noise: TrackerNoise | None = None) -> dict | None:
    """The drift test of a session of a drift plan (ISO 9283:1998, 7.6), None for any other ISO session: AP_P and
    RP_l of P1 in each group (7.2's formulas on the group's attained positions, base frame as session_figures),
    dAP = |AP(first group) - AP(last group)| and dRP alike (calib.iso9283.drift)."""
    cell, plan, table, conditions, visit, _ = _session_inputs(directory)
    poses, _ = plan_arrays(plan)
    iso = iso_block(plan, cell, len(poses))
    block = drift_block(iso or {})
    if iso is None or block is None:
        return None
    station = model.stations.get(iso["station"])
    if station is None:
        raise InputError(f"the model knows no station {iso['station']!r}: identify a campaign measured from it first")
    in_base = InBase(table, station, noise or TrackerNoise.of(cell.tracker))
    p1 = (
        (np.asarray(table.station) == iso["station"])
        & (np.asarray(table.point) == iso["point"])
        & (np.asarray(table.pose) == "Q1")
    )
    commanded = commanded_positions(iso, model)[0]
    groups, figures = [], []
    for g in range(1, block["groups"] + 1):
        rows = p1 & (visit.group == g)
        base, cov = in_base(rows)
        if len(base) < 2:
            raise InputError(f"{directory}: drift group {g} has {len(base)} measurements of P1; it needs two")
        ap, rp = pose_accuracy(base, commanded, cov)[0], pose_repeatability(base, cov)[0]
        figures.append((ap, rp))
        groups.append(
            {
                "group": g,
                "t_h": round(float(table.t_s[rows][0]) / 3600.0, 4),
                "cycles": len(base),
                "AP_P_mm": ap.value,
                "RP_l_mm": rp.value,
            }
        )
    (ap1, rp1), (ap2, rp2) = figures[0], figures[-1]
    targets = f"compensated with {iso['compensated_with']['model']}" if iso.get("compensated_with") else "nominal"
    return {
        "targets": targets,
        "first": f"{directory} group 1",
        "last": f"{directory} group {block['groups']}",
        "poses": [{"pose": "P1", "dAP": drift(ap1, ap2), "dRP": drift(rp1, rp2)}],
        "groups": groups,
        "hours": block["hours"],
        "speed": conditions["speed"],
    }


def _velocity_condition(speed: float, conditions: dict) -> str:
    """The test's velocity as the report states it: the plan's (6.7), or the session's override (an old plan)."""
    if not speed:
        return conditions["speed"]
    return f"{speed:g} % of the rated velocity (ISO 9283:1998, 6.7; the PTP moves' joint speed override)"


def session_figures(
    directory: Path, model: Model, noise: TrackerNoise | None = None, velocity: float | None = None
) -> IsoFigures:
    """The ISO 9283 figures of one session of an ISO plan at one of its test velocities (None: the first, 6.7), in
    the base frame of `model`'s station estimate; `noise` is the tracker's instrument model every figure's
    uncertainty comes from (None: the session's tracker's)."""
    cell, plan, table, conditions, visit, centring = _session_inputs(directory)
    poses, _ = plan_arrays(plan)
    iso = iso_block(plan, cell, len(poses))
    if iso is None:
        raise PlanError(f"{directory}: its plan is no ISO 9283 plan (order {plan.get('order', 'campaign')!r})")
    planned = iso_velocities(iso)
    speed = planned[0] if velocity is None else velocity
    if speed not in planned:
        raise InputError(f"{directory}: its plan has no test velocity {speed:g} %")
    label = f"{directory} at {speed:g} %" if speed else str(directory)
    conditions["speed"] = _velocity_condition(speed, conditions)
    station = model.stations.get(iso["station"])
    if station is None:
        raise InputError(f"the model knows no station {iso['station']!r}: identify a campaign measured from it first")
    commanded = commanded_positions(iso, model)
    tracker = noise.name if noise else cell.tracker.describe()  # whose noise U is
    in_base = InBase(table, station, noise or TrackerNoise.of(cell.tracker))
    visit = Visits(np.asarray(table.pose), visit.side, visit.speed, speed)
    keep = (
        (np.asarray(table.station) == iso["station"])
        & (np.asarray(table.point) == iso["point"])
        & (visit.speed == speed)
    )
    temps = table.extra.get("temp_c") if table.extra else None
    context = BudgetContext(
        model,
        iso["station"],
        iso["point"],
        _commanded_rotations(iso, model),
        tracker,
        centring,
        temperature_halfrange(None if temps is None else [temps[k] for k in np.flatnonzero(keep)]),
    )
    figures, attained, covs = _pose_figures(directory, in_base, keep, visit, commanded, context)
    a, b = DISTANCE_POSES
    ad = rd = ad_budget = None
    notes = []
    if len(attained[a]) == len(attained[b]):
        ad, rd = distance_accuracy(attained[a], attained[b], commanded[a], commanded[b], covs[a], covs[b])
        ad_budget = ad_budget_of(ad, commanded[a], commanded[b], context)
        ad = Figure(ad.value, ad_budget.expanded, ad.clause)
    else:
        notes.append(f"{POSE_NAMES[a]} and {POSE_NAMES[b]} have different numbers of cycles: no AD/RD")
    pts = iso_points(iso)
    if len(pts) >= 3:  # the attained orientation from the tool's points, cycle by cycle (7.2)
        notes += _orientations(iso, pts, model, in_base, visit, figures)
    vap, vap_attained = (
        ({}, {}) if speed != planned[0] else _multidirectional(iso, cell, in_base, keep, visit, notes)
    )  # at the first velocity only
    conditions = _iso_conditions(conditions, cell, iso, table, pts, len(attained[0]), tracker)
    departed = departures(iso, speed, len(attained[0]), conditions, NO_LOAD, UNLOADED)
    return IsoFigures(
        label,
        bool(iso.get("compensated_with")),
        figures,
        ad,
        rd,
        attained,
        commanded,
        conditions,
        notes,
        vap,
        vap_attained,
        ad_budget,
        other_budgets(rd, vap, tracker),
        speed,
        departed,
    )


@dataclass(frozen=True)
class Visits:
    """Which of a session's rows are the visits of pose Qi from a side ("" for the unidirectional test, 7.2)."""

    pose: np.ndarray
    side: np.ndarray
    speed: np.ndarray  # the test velocity (6.7) of each, % of the rated; 0 where the plan had none
    at: float | None = None  # the test velocity whose visits `of` selects (None: every one)
    group: np.ndarray | None = None  # the drift test's group (7.6) of each, 0 outside one

    def of(self, i: int, side: str = "") -> np.ndarray:
        at = np.ones(len(self.speed), bool) if self.at is None else self.speed == self.at
        return (self.pose == f"Q{i + 1}") & (self.side == side) & at


def _pose_figures(
    directory: Path, in_base: InBase, keep: np.ndarray, visit: Visits, commanded: np.ndarray, context: BudgetContext
):
    """The pose accuracy and repeatability of each pose (7.2), with its attained positions and covariances; their U
    is their uncertainty budget's (campaign.jobs.iso9283_budget)."""
    attained, covs, figures = [], [], []
    for i, name in enumerate(POSE_NAMES):
        rows = keep & visit.of(i)
        base, cov = in_base(rows)
        if len(base) < 2:
            raise InputError(f"{directory}: {name} was measured {len(base)} times; repeatability needs two cycles")
        ap, offset = pose_accuracy(base, commanded[i], cov)
        rp, lbar, s = pose_repeatability(base, cov)
        budgets = pose_budgets(base, cov, offset, rp, context.setting(i, in_base.table.xyz[rows]))
        ap = Figure(ap.value, budgets["AP_P"].expanded, ap.clause)
        rp = Figure(rp.value, budgets["RP_l"].expanded, rp.clause)
        figures.append(PoseFigures(name, len(base), ap, offset, rp, lbar, s, budgets=budgets))
        attained.append(base)
        covs.append(cov)
    return figures, attained, covs


def _orientations(
    iso: dict, pts: list[str], model: Model, in_base: InBase, visit: Visits, figures: list[PoseFigures]
) -> list[str]:
    """The attained orientation of each pose from the tool's points, cycle by cycle (7.2), into `figures`;
    returns the notes of the poses without them."""
    missing = [p for p in pts if p not in model.points]
    if missing:
        raise InputError(f"the model knows no reference point {', '.join(missing)} (the ISO orientation test's)")
    tool = np.array([model.points[p] for p in pts])
    q_nom = np.radians(fields.rows(iso.get("nominal_poses_deg"), "plan: iso9283.nominal_poses_deg", PlanError))
    rot_c, _ = Kinematics(model.chain, []).end_frames(q_nom)  # the commanded orientation of the last joint frame
    table = in_base.table
    at_station = np.asarray(table.station) == iso["station"]
    notes = []
    for i, name in enumerate(POSE_NAMES):
        each = [in_base(at_station & (np.asarray(table.point) == p) & visit.of(i)) for p in pts]
        n = min(len(x) for x, _ in each)
        if n < 2:
            notes.append(f"{name}: a tool point was measured fewer than two times: no orientation figures")
            continue
        x = np.stack([x[:n] for x, _ in each], axis=1)  # (n cycles, k points, 3): cycle j = j-th visit of each
        c = np.stack([c[:n] for _, c in each], axis=1)
        w, cov_w = attained_orientations(tool, x, rot_c[i], c)
        figures[i].orientation = orientation_figures(w, cov_w)
    return notes


def _multidirectional(
    iso: dict, cell: Cell, in_base: InBase, keep: np.ndarray, visit: Visits, notes: list[str]
) -> tuple[dict, dict]:
    """The multi-directional pose accuracy variation (7.2) of each vAP pose, and its attained positions per side;
    a pose not measured from one of its sides gets a note in `notes` instead."""
    vap, vap_attained = {}, {}
    vap_plan = vap_block(iso, cell) or {"poses": []}
    for i, sides in zip(vap_plan["poses"], vap_plan.get("approaches", []), strict=True):
        per_side = {side: in_base(keep & visit.of(i, side)) for side in sides}
        missing = [side for side, (x, _) in per_side.items() if len(x) == 0]
        if missing:
            notes.append(f"{POSE_NAMES[i]} was not measured from its {', '.join(missing)} side: no vAP")
            continue
        vap[POSE_NAMES[i]] = multidirectional_variation(
            [x for x, _ in per_side.values()], [c for _, c in per_side.values()]
        )
        vap_attained[POSE_NAMES[i]] = {side: x for side, (x, _) in per_side.items()}
    return vap, vap_attained


def _iso_conditions(
    conditions: dict, cell: Cell, iso: dict, table: MeasurementTable, pts: list[str], cycles: int, tracker: str
) -> dict:
    """The test conditions the report states (ISO 9283 clause 6), in CONDITION_ORDER first."""
    comp = iso.get("compensated_with")
    conditions.update(
        {
            "robot": cell.chain.name,
            "cell": cell.name,
            "station": iso["station"],
            "tool point measured": iso["point"]
            + (f" (for the orientation also {', '.join(pts[:-1])})" if len(pts) >= 3 else ""),
            "cube": f"side {iso.get('cube_side_mm', float('nan')):.1f} mm about "
            f"({', '.join(f'{v:.1f}' for v in iso.get('cube_centre_mm', []))}) mm",
            "cycles": str(cycles),
            "targets": f"compensated with {comp['model']}" if comp else "nominal",
            "load": iso.get("load") or NO_LOAD,
            "temperature": _meteo(table, "temp_c", "°C", 1),
            "air pressure": _meteo(table, "pressure_hpa", "hPa", 1),
            "humidity": _meteo(table, "humidity_pct", "%", 0),
            "tracker (its U)": tracker,
            "trackcal version": version("trackcal"),
        }
    )
    first = [k for k in CONDITION_ORDER if k in conditions]
    return {k: conditions[k] for k in [*first, *(k for k in conditions if k not in first)]}


def _commanded_rotations(iso: dict, model: Model) -> np.ndarray:
    """(5, 3, 3) the commanded orientation of the last joint frame at each pose (the nominal chain at the plan's
    nominal joints, as commanded_positions)."""
    q = np.radians(fields.rows(iso.get("nominal_poses_deg"), "plan: iso9283.nominal_poses_deg", PlanError))
    return Kinematics(model.chain, []).end_frames(q)[0]


def commanded_positions(iso: dict, model: Model) -> np.ndarray:
    """(5, 3) where the measured point is meant to be: the nominal chain at the nominal joints of the plan, with the
    point where the calibration found it on the tool (model.points). The plan's own `commanded_mm` uses the cell's
    nominal tool, whose points are known only to the tool drawing's tolerance (tenths of a mm on the KR-270 tool):
    against it a perfectly compensated robot would show the tool's error as pose accuracy."""
    q = np.radians(fields.rows(iso.get("nominal_poses_deg"), "plan: iso9283.nominal_poses_deg", PlanError))
    point = model.points.get(iso["point"])
    if point is None:
        raise InputError(f"the model knows no reference point {iso['point']!r} (the point the ISO test measures)")
    return Kinematics(model.chain, []).points(q, point)


@dataclass(frozen=True)
class CompareOptions:
    sessions: list[str]
    model: str
    json: str | None = None
    noise: TrackerNoise | None = None  # the tracker's model, the figures' uncertainties (None: each session's)
    accept_edited: bool = False  # use a model whose digest does not match its content (calib.model_trust)
    tolerances: dict[str, float] | None = None  # upper limits (mm) by figure key: the verdicts go into the JSON
    decision_rule: str = "guarded"  # calib.decision_rule.RULES
    certificate: bool = False  # a report or PDF will be made: a tracker certificate past its due date is refused
    accept_expired: bool = False  # ... unless this: then a warning and a note on the report


def drifts(tests: list[IsoFigures]) -> list[dict]:
    """dAP and dRP per pose (ISO 9283:1998, 7.6) between the first and the last of the tests run with the same
    targets, in the order given (the standard repeats the test over hours: give the sessions in time order)."""
    out = []
    for targets, speed in dict.fromkeys((t.conditions["targets"], t.conditions.get("speed")) for t in tests):
        same = [t for t in tests if (t.conditions["targets"], t.conditions.get("speed")) == (targets, speed)]
        if len(same) < 2:
            continue
        first, last = same[0], same[-1]
        out.append(
            {
                "targets": targets,
                "first": first.session,
                "last": last.session,
                "poses": [
                    {"pose": a.name, "dAP": drift(a.ap, b.ap), "dRP": drift(a.rp, b.rp)}
                    for a, b in zip(first.poses, last.poses, strict=True)
                ],
            }
        )
    return out


def compare(opts: CompareOptions, warnings: list[str] | None = None) -> tuple[list[IsoFigures], list[dict]]:
    """The figures of each session, in the order given (e.g. before, after), and the drifts between tests with the
    same targets; the model checked first (campaign.jobs.trusted, its warning lines added to `warnings`)."""
    model, checked = trusted_model(opts.model, opts.accept_edited)
    if warnings is not None:
        warnings += checked
    expired = [m for m in map(expired_certificate, opts.sessions) if m]
    if expired and opts.certificate and not opts.accept_expired:
        raise InputError(
            f"{expired[0]}: recalibrate the tracker, or --accept-expired-certificate to state the "
            "test anyway (the report then says so)"
        )
    tests, drift_tests = [], []
    for s in opts.sessions:
        found = drift_test(Path(s), model, opts.noise)  # the drift test (7.6): a session of its own
        if found is not None:
            drift_tests.append(found)
            continue
        for t in session_tests(Path(s), model, opts.noise):  # one per test velocity (6.7)
            t.notes += [m.removeprefix(f"{s}: ") for m in expired if m.startswith(f"{s}: ")]
            tests.append(t)
    if warnings is not None:
        warnings += expired
    if not tests and opts.certificate:
        raise InputError("a drift test alone makes no report: give it with the pose test's sessions")
    drift_list = drift_tests + drifts(tests)
    if opts.json:
        conformity = None
        if opts.tolerances:
            found = verdicts(tests, opts.tolerances, opts.decision_rule)
            conformity = conformity_doc(opts.decision_rule, opts.tolerances, found)
        write_json(
            opts.json,
            {
                "model": opts.model,
                "tests": [t.to_doc() for t in tests],
                "drift": [
                    {
                        **d,
                        "poses": [
                            {"pose": p["pose"], "dAP": p["dAP"].to_doc(), "dRP": p["dRP"].to_doc()} for p in d["poses"]
                        ],
                    }
                    for d in drift_list
                ],
                "conformity": conformity,
            },
        )
    return tests, drift_list
