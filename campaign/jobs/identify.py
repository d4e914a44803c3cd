"""`identify` and `predict` on typed options: the geometric model of a table, or the model extended by a cause,
its quality against the noise floor, and the model document (model.json) and summary written from it."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from trackcal.calib.diagnose.extensions import CAUSES
from trackcal.calib.diagnose.fits import fit_cause
from trackcal.calib.diagnose.noise_floor import Floor, noise_floor
from trackcal.calib.identify.determined import POORLY_DETERMINED, noise_floor_ratios
from trackcal.calib.identify.noise import DEFAULT_WEIGHTING, TrackerNoise, noise_for
from trackcal.calib.identify.points import PointsError, points_from_table
from trackcal.calib.identify.solver import (
    Identification,
    IdentificationError,
    Problem,
    Rows,
    State,
    identify,
    residual_stats,
    significance,
)
from trackcal.calib.identify.units import read_measured
from trackcal.calib.identify.unknowns import campaign_params
from trackcal.calib.io.files import write_json, writing
from trackcal.calib.io.table import MeasurementTable, write_table
from trackcal.calib.measured_space import KEY as MEASURED
from trackcal.calib.measured_space import fitted_space
from trackcal.calib.model.cell import Cell, load_cell
from trackcal.calib.model.chain import ChainError
from trackcal.calib.model.extension import Ranges
from trackcal.calib.model.identifiability import still_joints, unidentifiable_params
from trackcal.calib.model.instruments import Instrument
from trackcal.calib.model.kinematics import Kinematics
from trackcal.calib.model.params import Param, param_by_name
from trackcal.calib.model_file import identification_to_doc, predict_table
from trackcal.calib.model_trust import sealed
from trackcal.campaign.errors import InputError, OptionError
from trackcal.campaign.jobs.trusted import trusted_model

# Above twice the noise floor three quarters of the residual variance (1 - 1/2^2) is something the model does not
# describe; the intervals assume what is left is tracker noise, so they cannot be trusted (a parameter subset or a
# non-geometric effect then biases the parameters far outside them: issue 15, 5 of 6 true values outside at 30x).
POOR_FIT_RATIO = 2.0


def sha256_of(path: str | Path) -> str:
    """The sha256 of a file's bytes: what model.json and verdict.json name as the table they were made from."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def choose_params(cell: Cell, names: str | None) -> list[Param]:
    """The `params` option, else the robot parameters a campaign identifies (calib.identify.unknowns: the plan is
    scored for the same ones)."""
    kept = campaign_params(cell.chain)
    if not names:
        return kept
    try:
        return [param_by_name(cell.chain, n.strip()) for n in names.split(",") if n.strip()]
    except ChainError as exc:
        raise OptionError(
            "{0}: {exc}; the irreducible set is {kept}", "params", exc=exc, kept=" ".join(p.name for p in kept)
        ) from None


@dataclass(frozen=True)
class IdentifyOptions:
    """What `trackcal identify` is asked."""

    data: str  # the measurement table
    cell: str  # cell name or path
    out: str  # model.json to write
    params: str | None = None  # comma-separated names; None: the irreducible set
    weighting: str = DEFAULT_WEIGHTING
    extend: str = "none"  # none, auto or causes joined by +
    json: str | None = None  # the summary to write


@dataclass
class IdentifyOutcome:
    result: Identification
    before: Identification
    doc: dict
    warning: str | None = None  # fit_warning: the intervals cannot be trusted
    determination: str | None = None  # determination_warning: parameters the table does not determine
    chosen: str | None = None  # --extend auto: the cause diagnose chose ("none": the model stays geometric)
    still: str | None = None  # still_warning: joints that never move, their parameters left at nominal


def still_warning(cell: Cell, table: MeasurementTable, params: list[Param]) -> tuple[list[Param], str | None]:
    """(the parameters the table can identify, one line naming the joints that never move in it and the
    parameters left at nominal because of them; None when every joint moves)."""
    still = still_joints(table.q_deg)
    if not still:
        return params, None
    tool = np.array(list(cell.tool_points.values()))
    dropped = unidentifiable_params(cell.chain, params, np.radians(table.q_deg), tool, still)
    names = ", ".join(cell.chain.joints[j].name for j in still)
    verb = "never moves" if len(still) == 1 else "never move"
    left = " ".join(p.name for p in dropped) or "none of the parameters"
    return [p for p in params if p not in dropped], (
        f"joint {names} {verb} in {table.source}: {left} not identifiable from it, left at nominal"
    )


@dataclass(frozen=True)
class Fitted:
    """An identification before its document: the parameters fitted (those of joints that never move left out, `still`
    says which), the nominal robot's "before" fit and the model's fit (`table`: the table it was fitted on)."""

    params: list[Param]
    still: str | None
    before: Identification
    result: Identification
    shift: object  # calib.diagnose's station shift of the fit (None without one)
    table: MeasurementTable


def fit_model(
    cell: Cell, table: MeasurementTable, params: list[Param], weighting: str = DEFAULT_WEIGHTING, extend: str = "none"
) -> Fitted:
    """Fit the geometric model, or the geometric model extended by a cause (`auto`: diagnose's), and the nominal
    robot's "before" fit."""
    if extend not in ("none", "auto") and not set(extend.split("+")) <= set(CAUSES):
        raise OptionError(
            "{0} {extend}: choose none, auto or causes joined by + from {causes}",
            "extend",
            extend=extend,
            causes=", ".join(CAUSES),
        )
    params, still = still_warning(cell, table, params)
    noise = noise_for(weighting, cell.tracker)
    rows = Rows(cell.chain, table, cell.tool_points, noise, None)  # the layout of the table both fits share
    before = identify(cell.chain, table, cell.tool_points, [], noise=noise, covariance=False, rows=rows)  # residuals
    if extend == "auto":
        from trackcal.calib.diagnose.diagnosis import diagnose  # lazy: the search is only for --extend auto (start-up)

        extend = "+".join(
            c["cause"]
            for c in diagnose(
                cell.chain, table, cell.tool_points, params, noise, tracker=TrackerNoise.of(cell.tracker)
            ).causes
        )
        extend = extend or "none"
    geometric = identify(cell.chain, table, cell.tool_points, params, noise=noise, rows=rows)
    fit = fit_cause(cell.chain, table, cell.tool_points, params, noise, extend, geometric)
    if fit is None:
        raise OptionError(
            "{0} {extend}: this table cannot reveal it (too few rows or no variation)", "extend", extend=extend
        )
    return Fitted(params, still, before, fit.result, fit.shift, fit.table)


def identify_outcome(
    cell: Cell, table: MeasurementTable, fitted: Fitted, table_sha256: str | None = None, floor: Floor | None = None
) -> IdentifyOutcome:
    """The model document of a fit and its warnings. `table_sha256`: of the table's file (default: the file it was
    read from); `floor`: the table's noise floor when already found (default: calib.diagnose.noise_floor)."""
    doc = model_doc(cell, table, fitted.result, fitted.before, fitted.shift, table_sha256, floor)
    doc["poorly_determined"] = poorly_determined(fitted.result, fitted.table)
    if fitted.still:
        doc["not_identifiable"] = fitted.still
    missing = left_out(cell, fitted.params)
    advice = (
        determinable(fitted.result, fitted.table, [param_by_name(cell.chain, n) for n in missing])
        if (doc["fit"] == "poor" and missing)
        else missing
    )
    return IdentifyOutcome(
        result=fitted.result,
        before=fitted.before,
        doc=doc,
        warning=fit_warning(doc, advice, missing),
        determination=determination_warning(doc),
        still=fitted.still,
    )


def run_identify(
    cell: Cell,
    table: MeasurementTable,
    params: list[Param],
    weighting: str = DEFAULT_WEIGHTING,
    extend: str = "none",
    table_sha256: str | None = None,
) -> IdentifyOutcome:
    """Identify the geometric model, or the geometric model extended by a cause (`auto`: diagnose's).
    `table_sha256`: of the table's file (default: the file it was read from)."""
    return identify_outcome(cell, table, fit_model(cell, table, params, weighting, extend), table_sha256)


def cell_and_table(cell_ref: str, data: str | Path) -> tuple[Cell, MeasurementTable]:
    """The cell and the table identify and diagnose read. A cell given as a robot file alone has no tool: its
    reference points are the table's, starting where the measurements put them (calib.identify.points)."""
    cell = load_cell(cell_ref)
    table = read_measured(data, cell.chain)
    if not cell.tool_points:
        try:
            points = points_from_table(cell.chain, table)
        except PointsError as exc:
            raise InputError(str(exc)) from None
        cell = replace(cell, tool_points=points, tcp=np.mean(list(points.values()), axis=0))
    return cell, table


def identify_table(opts: IdentifyOptions) -> IdentifyOutcome:
    """`trackcal identify`: the model of the table, written to opts.out (and its summary to opts.json)."""
    cell, table = cell_and_table(opts.cell, opts.data)
    outcome = run_identify(cell, table, choose_params(cell, opts.params), opts.weighting, opts.extend)
    if opts.extend == "auto":
        outcome.chosen = outcome.doc["extension"]["cause"]
    outcome.doc = sealed(outcome.doc)  # its usability judged, its digest
    write_json(opts.out, outcome.doc, InputError)
    if opts.json:
        write_json(opts.json, summary_of(outcome), InputError)
    return outcome


def fit_quality(
    table: MeasurementTable, res: Identification, tracker: Instrument | None = None, floor: Floor | None = None
) -> dict:
    """Does the model reach the noise floor? The residual RMS of one coordinate (over the degrees of freedom)
    against calib.diagnose.noise_floor (repeated measurements, else the tracker noise model: the weighting's, else
    `tracker`'s, the cell's instrument), or `floor` when the caller found it already."""
    found = floor or noise_floor(table, res.noise, None if tracker is None else TrackerNoise.of(tracker))
    rms_dof = float(np.sqrt(np.sum(res.residuals**2) / max(res.dof, 1)))
    ratio = rms_dof / found.sigma_mm
    return {
        "fit": "poor" if ratio > POOR_FIT_RATIO else "good",
        "fit_ratio": ratio,
        "residual_rms_mm": rms_dof,
        "noise_floor_mm": found.sigma_mm,
        "noise_floor_source": found.source,
    }


def left_out(cell: Cell, params: list[Param]) -> list[str]:
    """The irreducible parameters a subset leaves at nominal."""
    chosen = {p.name for p in params}
    return [p.name for p in campaign_params(cell.chain) if p.name not in chosen]


def _fit_r_factor(res: Identification, table: MeasurementTable, params: list[Param]) -> np.ndarray:
    """R of the whitened Jacobian J = QR of `res`'s model at its solution, with `params` as its parameters (those of
    `res` first, any others at nominal): the solver's own when `params` are `res`'s, else accumulated over row
    chunks (`Problem.r_factor`). Never J itself: 3 KB per row, once the memory peak of identify (issue 41)."""
    extra = len(params) - len(res.params)
    if extra == 0 and res.r_factor is not None and len(res.r_factor) == len(res.cov):  # every unknown free
        return res.r_factor
    problem = Problem(
        res.chain,
        table,
        res.points,
        params,
        res.noise,
        np.r_[res.dev, np.zeros(extra)],
        extension=res.extension,
        ext0=res.ext,
    )
    state = State(
        problem.initial.dev,
        [res.stations[s] for s in problem.station_ids],
        np.array([res.points[p] for p in problem.point_ids]),
        np.asarray(res.ext, dtype=float),
    )
    return problem.r_factor(state)


def poorly_determined(res: Identification, table: MeasurementTable) -> dict[str, float]:
    """{name: ratio} of the fitted parameters the table does not determine (calib.identify.determined: moved alone by
    its 95 % interval, one would displace the reflectors by more than POORLY_DETERMINED noise floors)."""
    ratios = noise_floor_ratios(_fit_r_factor(res, table, res.params), np.arange(len(res.params)), 3 * len(table))
    return {
        p.name: float(r) if np.isfinite(r) else None
        for p, r in zip(res.params, ratios, strict=True)
        if not r <= POORLY_DETERMINED
    }


def determinable(res: Identification, table: MeasurementTable, candidates: list[Param]) -> list[str]:
    """The `candidates` (parameters left out) the table would determine if added, in order, each judged with those
    kept before it and the fitted model (calib.identify.determined); advice names only these."""
    try:
        jm = _fit_r_factor(res, table, [*res.params, *candidates])
    except IdentificationError:  # more unknowns than equations with all of them: judge none
        return []
    n_eq = 3 * len(table)
    k, n_all = len(res.params), jm.shape[1]
    rest = list(range(k + len(candidates), n_all))  # the extension, stations and points
    kept: list[int] = []
    for i in range(len(candidates)):
        cols = list(range(k)) + [k + c for c in kept] + [k + i] + rest
        if noise_floor_ratios(jm[:, cols], [k + len(kept)], n_eq)[0] <= POORLY_DETERMINED:
            kept.append(i)
    return [candidates[i].name for i in kept]


def determination_warning(doc: dict) -> str | None:
    """One line naming the fitted parameters the table does not determine; None when it determines them all."""
    bad = doc.get("poorly_determined") or {}
    if not bad:
        return None
    pars = doc["parameters"]
    named = ", ".join(f"{n} ±{pars[n]['ci95']:.3g} {pars[n]['unit']}" for n in bad)
    return (
        f"poorly determined by this table: {named} (moved alone across its 95 % interval, each would displace "
        f"the reflectors by more than {POORLY_DETERMINED:g} times the noise floor; their values are whatever the "
        "noise makes them: add poses, reference points or stations, or leave them out)"
    )


def fit_warning(doc: dict, advice: list[str], missing: list[str] | None = None) -> str | None:
    """One line when the model's intervals cannot be trusted, saying where to look; None for a good fit. `advice`:
    the parameters left out that the table would determine (of `missing`, all those left out)."""
    if doc["fit"] != "poor":
        return None
    missing = advice if missing is None else missing
    where = f"add the parameters left out ({' '.join(advice)}: this table determines them) or run" if advice else "run"
    if len(advice) < len(missing):
        where = (
            f"{len(missing) - len(advice)} parameter(s) left out cannot be determined by this table "
            f"({' '.join(n for n in missing if n not in advice)}); {where}"
        )
    return (
        f"poor fit: the residual RMS {doc['residual_rms_mm'] * 1000:.1f} µm is {doc['fit_ratio']:.1f}x the "
        f"noise floor {doc['noise_floor_mm'] * 1000:.1f} µm ({doc['noise_floor_source']}), so the intervals "
        f"cannot be trusted: {where} `trackcal diagnose` to see what the model misses"
    )


def convergence_warning(doc: dict) -> str | None:
    """One line when the solver stopped without meeting its stopping test (the model document's `converged` and
    `message`); None when it converged."""
    if doc["converged"]:
        return None
    why = doc["message"]
    return "the fit did not converge" + (f": {why}" if why else "") + "; the parameters may not be the best fit"


def model_doc(
    cell: Cell,
    table: MeasurementTable,
    res: Identification,
    before: Identification,
    shift,
    table_sha256: str | None = None,
    floor: Floor | None = None,
) -> dict:
    """model.json; `table_sha256` of the table's file (default: the file the table was read from, None when it
    was not read from a file); `floor`: the table's noise floor when already found (fit_quality)."""
    if table_sha256 is None and Path(table.source).is_file():
        table_sha256 = sha256_of(table.source)
    params = res.params
    extra: dict = {
        "cell": cell.name,
        "nominal": cell.nominal,  # which nominal robot the deviations are from (calib.model.cell.nominal_of)
        "data": table.source,
        "table_sha256": table_sha256,
        "n_measurements": len(table),
        "residuals": {"before": residual_stats(before.residuals), "after": residual_stats(res.residuals)},
        "tracker": cell.tracker.to_doc(),
        **fit_quality(table, res, cell.tracker, floor),
    }
    if cell.test_pose is not None and cell.tcp is not None:
        extra["test_pose_deg"] = np.degrees(cell.test_pose).tolist()
        extra["tcp_mm"] = cell.tcp.tolist()
        extra["significance_mm"] = dict(significance(cell.chain, params, res.dev, cell.test_pose, cell.tcp))
    q_rad = np.radians(table.q_deg)
    extra[MEASURED] = fitted_space(
        Kinematics(res.chain, res.params), res.dev, res.points, q_rad, table.point
    ).to_doc()  # where it was measured (calib.measured_space)
    ranges = None if res.extension is None else Ranges.of(q_rad, table.t_s)
    return identification_to_doc(res, extra, shift, cell.test_pose, ranges)


def summary_of(outcome: IdentifyOutcome) -> dict:
    res = outcome.result
    keys = (
        "cell",
        "nominal",
        "data",
        "table_sha256",
        "n_measurements",
        "weighting",
        "tracker",
        "fit",
        "fit_ratio",
        "residual_rms_mm",
        "noise_floor_mm",
        "noise_floor_source",
        "extension",
        "residuals",
        "significance_mm",
        "poorly_determined",
        "test_pose",
        "usable",
        "unusable_why",
    )
    out = {k: outcome.doc[k] for k in keys if k in outcome.doc}
    out.update(
        {
            "parameters": outcome.doc["parameters"],
            "sigma_mm": outcome.doc["sigma_mm"],
            "iterations": res.iterations,
            "converged": outcome.doc["converged"],
            "message": outcome.doc["message"],
            "dof": res.dof,
            "stations": list(res.stations),
        }
    )
    return out


@dataclass(frozen=True)
class PredictOptions:
    """What `trackcal predict` is asked."""

    model: str  # model.json
    rows: str  # the rows (measurement-table columns, x,y,z optional)
    out: str  # the table to write
    accept_edited: bool = False  # use a model whose digest does not match its content (calib.model_trust)


@dataclass
class Prediction:
    table: MeasurementTable
    warning: str | None  # rows outside the joint range the model was identified on
    model_warnings: list[str] = field(default_factory=list)  # e.g. a model without a digest


def predict(opts: PredictOptions) -> Prediction:
    """`trackcal predict`: reflector positions of the rows predicted by the model, written to opts.out."""
    model, checked = trusted_model(opts.model, opts.accept_edited)
    rows = read_measured(opts.rows, model.chain, require_xyz=False)
    pred = predict_table(model, rows)
    warning = model.range_warning(np.radians(rows.q_deg))
    with writing(opts.out, InputError):
        write_table(pred, opts.out)
    return Prediction(pred, warning, checked)
