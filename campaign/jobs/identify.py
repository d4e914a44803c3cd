"""`identify` and `predict` on typed options: the geometric model of a table, or the model extended by a cause,
its quality against the noise floor, and the model document (model.json) and summary written from it."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from trackcal.calib.diagnose.extensions import CAUSES
from trackcal.calib.diagnose.selection import diagnose, fit_cause, noise_floor
from trackcal.calib.identify.noise import DEFAULT_WEIGHTING, noise_for
from trackcal.calib.identify.solver import Identification, identify, residual_stats, significance
from trackcal.calib.io.files import write_json, writing
from trackcal.calib.io.table import MeasurementTable, read_table, write_table
from trackcal.calib.model.cell import Cell, load_cell
from trackcal.calib.model.chain import ChainError
from trackcal.calib.model.identifiability import still_joints, unidentifiable_params
from trackcal.calib.model.params import Param, irreducible_params, param_by_name
from trackcal.calib.model_file import identification_to_doc, load_model, predict_table
from trackcal.campaign.errors import InputError, OptionError

# Above twice the noise floor three quarters of the residual variance (1 - 1/2^2) is something the model does not
# describe; the intervals assume what is left is tracker noise, so they cannot be trusted (a parameter subset or a
# non-geometric effect then biases the parameters far outside them: issue 15, 5 of 6 true values outside at 30x).
POOR_FIT_RATIO = 2.0


def sha256_of(path: str | Path) -> str:
    """The sha256 of a file's bytes: what model.json and verdict.json name as the table they were made from."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def choose_params(cell: Cell, names: str | None) -> list[Param]:
    kept, _ = irreducible_params(cell.chain)
    if not names:
        return kept
    try:
        return [param_by_name(cell.chain, n.strip()) for n in names.split(",") if n.strip()]
    except ChainError as exc:
        raise OptionError("{0}: {exc}; the irreducible set is {kept}", "params", exc=exc,
                          kept=" ".join(p.name for p in kept)) from None


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
        f"joint {names} {verb} in {table.source}: {left} not identifiable from it, left at nominal")


def run_identify(
    cell: Cell, table: MeasurementTable, params: list[Param], weighting: str = DEFAULT_WEIGHTING,
    extend: str = "none", table_sha256: str | None = None,
) -> IdentifyOutcome:  # fmt: skip
    """Identify the geometric model, or the geometric model extended by a cause (`auto`: diagnose's).
    `table_sha256`: of the table's file (default: the file it was read from)."""
    if extend not in ("none", "auto") and not set(extend.split("+")) <= set(CAUSES):
        raise OptionError("{0} {extend}: choose none, auto or causes joined by + from {causes}", "extend",
                          extend=extend, causes=", ".join(CAUSES))
    params, still = still_warning(cell, table, params)
    noise = noise_for(weighting)
    before = identify(cell.chain, table, cell.tool_points, [], noise=noise)
    if extend == "auto":
        extend = "+".join(c["cause"] for c in diagnose(cell.chain, table, cell.tool_points, params, noise).causes)
        extend = extend or "none"
    fit = fit_cause(cell.chain, table, cell.tool_points, params, noise, extend)
    if fit is None:
        raise OptionError("{0} {extend}: this table cannot reveal it (too few rows or no variation)", "extend",
                          extend=extend)
    doc = model_doc(cell, table, fit.result, before, fit.shift, table_sha256)
    if still:
        doc["not_identifiable"] = still
    return IdentifyOutcome(result=fit.result, before=before, doc=doc, warning=fit_warning(doc, left_out(cell, params)),
                           still=still)  # fmt: skip


def identify_table(opts: IdentifyOptions) -> IdentifyOutcome:
    """`trackcal identify`: the model of the table, written to opts.out (and its summary to opts.json)."""
    cell = load_cell(opts.cell)
    table = read_table(opts.data, chain=cell.chain)
    outcome = run_identify(cell, table, choose_params(cell, opts.params), opts.weighting, opts.extend)
    if opts.extend == "auto":
        outcome.chosen = outcome.doc["extension"]["cause"]
    write_json(opts.out, outcome.doc, InputError)
    if opts.json:
        write_json(opts.json, summary_of(outcome), InputError)
    return outcome


def fit_quality(table: MeasurementTable, res: Identification) -> dict:
    """Does the model reach the noise floor? The residual RMS of one coordinate (over the degrees of freedom)
    against calib.diagnose.noise_floor (repeated measurements, else the tracker noise model)."""
    found = noise_floor(table, res.noise)
    floor, source = found.sigma_mm, found.source
    rms_dof = float(np.sqrt(np.sum(res.residuals**2) / max(res.dof, 1)))
    ratio = rms_dof / floor
    return {"fit": "poor" if ratio > POOR_FIT_RATIO else "good", "fit_ratio": ratio, "residual_rms_mm": rms_dof,
            "noise_floor_mm": floor, "noise_floor_source": source}  # fmt: skip


def left_out(cell: Cell, params: list[Param]) -> list[str]:
    """The irreducible parameters a subset leaves at nominal."""
    chosen = {p.name for p in params}
    return [p.name for p in irreducible_params(cell.chain)[0] if p.name not in chosen]


def fit_warning(doc: dict, missing: list[str]) -> str | None:
    """One line when the model's intervals cannot be trusted, saying where to look; None for a good fit."""
    if doc["fit"] != "poor":
        return None
    where = f"add the parameters left out ({' '.join(missing)}) or run" if missing else "run"
    return (f"poor fit: the residual RMS {doc['residual_rms_mm'] * 1000:.1f} µm is {doc['fit_ratio']:.1f}x the "
            f"noise floor {doc['noise_floor_mm'] * 1000:.1f} µm ({doc['noise_floor_source']}), so the intervals "
            f"cannot be trusted: {where} `trackcal diagnose` to see what the model misses")  # fmt: skip


def convergence_warning(doc: dict) -> str | None:
    """One line when the solver stopped without meeting its stopping test (the model document's `converged` and
    `message`); None when it converged."""
    if doc["converged"]:
        return None
    why = doc["message"]
    return "the fit did not converge" + (f": {why}" if why else "") + "; the parameters may not be the best fit"


def model_doc(cell: Cell, table: MeasurementTable, res: Identification, before: Identification, shift,
              table_sha256: str | None = None) -> dict:  # fmt: skip
    """model.json; `table_sha256` of the table's file (default: the file the table was read from, None when it
    was not read from a file)."""
    if table_sha256 is None and Path(table.source).is_file():
        table_sha256 = sha256_of(table.source)
    params = res.params
    extra: dict = {
        "cell": cell.name,
        "data": table.source,
        "table_sha256": table_sha256,
        "n_measurements": len(table),
        "residuals": {"before": residual_stats(before.residuals), "after": residual_stats(res.residuals)},
        **fit_quality(table, res),
    }
    if cell.test_pose is not None and cell.tcp is not None:
        extra["test_pose_deg"] = np.degrees(cell.test_pose).tolist()
        extra["tcp_mm"] = cell.tcp.tolist()
        extra["significance_mm"] = dict(significance(cell.chain, params, res.dev, cell.test_pose, cell.tcp))
    return identification_to_doc(res, extra, shift)


def summary_of(outcome: IdentifyOutcome) -> dict:
    res = outcome.result
    keys = ("cell", "data", "table_sha256", "n_measurements", "weighting", "fit", "fit_ratio", "residual_rms_mm",
            "noise_floor_mm", "noise_floor_source", "extension", "residuals", "significance_mm")
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


@dataclass
class Prediction:
    table: MeasurementTable
    warning: str | None  # rows outside the joint range the model was identified on


def predict(opts: PredictOptions) -> Prediction:
    """`trackcal predict`: reflector positions of the rows predicted by the model, written to opts.out."""
    model = load_model(opts.model)
    rows = read_table(opts.rows, require_xyz=False, chain=model.chain)
    pred = predict_table(model, rows)
    warning = model.range_warning(np.radians(rows.q_deg))
    with writing(opts.out, InputError):
        write_table(pred, opts.out)
    return Prediction(pred, warning)
