"""The analysis pipeline on typed options: identify a table against a cell, diagnose it, predict with a model,
simulate a table on the twin, and the end-of-campaign analysis of a session (export, model, verdict, report)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trackcal.calib.diagnose.extensions import CAUSES, rebuild
from trackcal.calib.diagnose.selection import Diagnosis, diagnose, fit_cause, noise_floor, rms
from trackcal.calib.doe.design import DesignError
from trackcal.calib.doe.poses import random_poses
from trackcal.calib.identify.noise import DEFAULT_WEIGHTING, noise_for
from trackcal.calib.identify.solver import Identification, IdentificationError, identify, residual_stats, significance
from trackcal.calib.io.table import MeasurementTable, read_table
from trackcal.calib.model.cell import Cell, load_cell
from trackcal.calib.model.chain import ChainError
from trackcal.calib.model.kinematics import Kinematics
from trackcal.calib.model.params import Param, irreducible_params, param_by_name
from trackcal.calib.model_file import identification_to_doc
from trackcal.campaign.console import console
from trackcal.campaign.errors import InputError
from trackcal.campaign.output import write_json
from trackcal.campaign.report.inputs import GEOMETRIC_MODEL, report_session, table_sha256
from trackcal.campaign.session.session import campaign_warnings, session_cell, write_export
from trackcal.campaign.session.store import SessionStore
from trackcal.mocks.twin import Twin, simulate_campaign

# Above twice the noise floor three quarters of the residual variance (1 - 1/2^2) is something the model does not
# describe; the intervals assume what is left is tracker noise, so they cannot be trusted (a parameter subset or a
# non-geometric effect then biases the parameters far outside them: issue 15, 5 of 6 true values outside at 30x).
POOR_FIT_RATIO = 2.0


def choose_params(cell: Cell, names: str | None) -> list[Param]:
    kept, _ = irreducible_params(cell.chain)
    if not names:
        return kept
    try:
        return [param_by_name(cell.chain, n.strip()) for n in names.split(",") if n.strip()]
    except ChainError as exc:
        raise InputError(f"--params: {exc}; the irreducible set is {' '.join(p.name for p in kept)}") from None


@dataclass
class IdentifyOutcome:
    result: Identification
    before: Identification
    doc: dict


def run_identify(
    cell: Cell, table: MeasurementTable, params: list[Param], weighting: str = DEFAULT_WEIGHTING,
    extend: str = "none",
) -> IdentifyOutcome:  # fmt: skip
    """Identify the geometric model, or the geometric model extended by a cause (`auto`: diagnose's)."""
    if extend not in ("none", "auto") and not set(extend.split("+")) <= set(CAUSES):
        raise InputError(f"--extend {extend}: choose none, auto or causes joined by + from {', '.join(CAUSES)}")
    noise = noise_for(weighting)
    before = identify(cell.chain, table, cell.tool_points, [], noise=noise)
    if extend == "auto":
        extend = "+".join(c["cause"] for c in diagnose(cell.chain, table, cell.tool_points, params, noise).causes)
        extend = extend or "none"
    fit = fit_cause(cell.chain, table, cell.tool_points, params, noise, extend)
    if fit is None:
        raise InputError(f"--extend {extend}: this table cannot reveal it (too few rows or no variation)")
    return IdentifyOutcome(result=fit.result, before=before, doc=model_doc(cell, table, fit.result, before, fit.shift))


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


def model_doc(cell: Cell, table: MeasurementTable, res: Identification, before: Identification, shift) -> dict:
    params = res.params
    extra: dict = {
        "cell": cell.name,
        "data": table.source,
        "table_sha256": table_sha256(table),
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
            "dof": res.dof,
            "stations": list(res.stations),
        }
    )
    return out


def parse_effects(items: list[str] | None) -> dict[str, float]:
    out = {}
    for item in items or []:
        name, _, mag = item.partition(":")
        if name not in CAUSES:
            raise InputError(f"--effect {item}: unknown effect; choose from {', '.join(CAUSES)}")
        try:
            out[name] = float(mag) if mag else 0.05
        except ValueError:
            raise InputError(f"--effect {item}: the magnitude must be a number of mm") from None
        if not out[name] > 0:
            raise InputError(f"--effect {item}: the magnitude must be positive")
    return out


def simulate(cell_ref: str, n_poses: int, seed: int, repeat: int = 1, noise_free: bool = False,
             effects: dict[str, float] | None = None) -> tuple[Cell, Twin, MeasurementTable]:  # fmt: skip
    """A table of `n_poses` random feasible poses measured by the twin of `seed`."""
    cell = load_cell(cell_ref)
    if n_poses < 1 or repeat < 1:
        raise InputError("--poses and --repeat must be at least 1")
    try:
        poses = np.degrees(random_poses(cell, n_poses, np.random.default_rng(seed)))
    except DesignError as exc:
        raise InputError(str(exc)) from None
    twin = Twin(cell, seed=seed, effects=effects or {})
    return cell, twin, simulate_campaign(twin, poses, repeat=repeat, noise_free=noise_free)


def twin_truth(cell: Cell, seed: int) -> dict[str, float]:
    """The twin's true parameter deviations in boundary units (mm, deg)."""
    twin = Twin(cell, seed=seed)
    return {p.name: (v if p.is_length else float(np.degrees(v))) for p, v in zip(twin.params, twin.true_dev,
                                                                                strict=True)}  # fmt: skip


def tcp_at_test_pose(cell: Cell, res: Identification) -> np.ndarray | None:
    """TCP at the cell's test pose with a fitted model (extension at its neutral context: no approach
    history, campaign start)."""
    if cell.test_pose is None:
        return None
    q0 = cell.test_pose[None]
    ext = res.extension
    if ext is not None and ext.joint_features is not None:
        row = MeasurementTable(np.array([1]), np.zeros(1), ["q0"], ["-"], ["-"], np.degrees(q0), None)
        q0 = q0 + rebuild(ext, cell.chain, row).joint_offsets(res.ext)
    return Kinematics(cell.chain, res.params).points(q0, cell.tcp, res.dev)[0]


def verdict_doc(cell: Cell, d: Diagnosis) -> dict:
    """verdict.json: the causes, every candidate of every selection step with its evidence, the residuals,
    their structure and the gain; the cell and the sha256 of the table it was made from (a report refuses files of
    different campaigns). A figure that cannot be computed is null, with a note saying why."""
    geo = d.geometric
    doc = {
        "cause": d.cause,
        "causes": d.causes,
        "cell": cell.name,
        "table_sha256": table_sha256(d.table),
        "candidates": [
            {
                "cause": c.cause, "step": c.step, "score": c.holdout_rms_mm, "holdout_rms_mm": c.holdout_rms_mm,
                "holdout_base_mm": c.holdout_base_mm, "gain_mm": c.gain_mm, "cv_scheme": c.cv_scheme,
                "cv_note": c.cv_note, "rms_mm": c.rms_mm, "f_pvalue": c.f_pvalue, "delta_bic": c.delta_bic,
                "n_params": c.n_params, "significant": c.significant, **c.detail,
            }
            for c in sorted(d.candidates, key=lambda c: (c.step, c.holdout_rms_mm is None, c.score()))
        ],
        "geometric": {"rms_mm": rms(geo.residuals), "variance_factor": geo.variance_factor,
                      "p_at_noise_floor": d.variance_factor_pvalue},
        "noise_floor_mm": d.noise_floor_mm,
        "noise_floor_source": d.floor_source,
        "noise_scale": d.noise_scale,
        "noise_note": noise_note(d),
        "structure": d.structure,
        "not_identifiable": d.not_identifiable,
        "holdout": {"rms_geometric_mm": d.holdout_geometric_mm, "rms_extended_mm": d.holdout_extended_mm,
                    "folds": d.cv_scheme, "note": d.cv_note},
    }  # fmt: skip
    ext = d.extended or geo
    doc["extended"] = {"rms_mm": rms(ext.residuals)}
    if d.extended is not None:
        tcp_g, tcp_e = tcp_at_test_pose(cell, geo), tcp_at_test_pose(cell, d.extended)
        if tcp_g is not None:
            doc["test_pose"] = {
                "tcp_difference_mm": float(np.linalg.norm(tcp_e - tcp_g)),
                "note": "how far the geometric model's TCP at the test pose is from the extended model's",
            }
    return doc


def noise_note(d: Diagnosis) -> str:
    """How far the chosen model's residuals sit from the noise floor: a scale, not a cause."""
    pct = 100.0 * (d.noise_scale - 1.0)
    model = "extended" if d.extended is not None else "geometric"
    return (f"the {model} model's residuals are {abs(pct):.0f} % {'above' if pct >= 0 else 'below'} the noise "
            f"floor ({d.floor_source})")  # fmt: skip


def analyse_session(store: SessionStore) -> None:
    """End of a campaign: export, identification, diagnosis and report, into the session directory. When the
    diagnosis names a cause, model.json is the model extended by it and model-geometric.json the geometric one."""
    d = store.directory
    n = write_export(store, d / "table.csv")
    cell = session_cell(store)
    table = read_table(d / "table.csv", chain=cell.chain)
    params = choose_params(cell, None)
    try:
        outcome = run_identify(cell, table, params, DEFAULT_WEIGHTING)
        dg = diagnose(cell.chain, table, cell.tool_points, params, outcome.result.noise, geometric=outcome.result)
    except IdentificationError as exc:
        console.print(f"[yellow]identification not possible yet[/]: {exc}")
        return
    write_json(d / "verdict.json", verdict_doc(cell, dg))
    geometric = d / GEOMETRIC_MODEL
    if dg.extended is not None:
        model = model_doc(cell, dg.table, dg.extended, outcome.before, dg.shift)
        write_json(geometric, outcome.doc)
        what = f"model {d / 'model.json'} extended by {dg.cause} (the geometric one: {geometric})"
    else:
        model = outcome.doc
        geometric.unlink(missing_ok=True)
        what = f"model {d / 'model.json'} (geometric)"
    write_json(d / "model.json", model)
    report = report_session(d, diagnosis=dg)
    console.print(f"{n} measurements -> {d / 'table.csv'}; {what}: coordinate RMS "
                  f"{model['residuals']['after']['coord_rms_mm'] * 1000:.1f} µm, fit {model['fit']}; diagnosis: "
                  f"{dg.cause} ({d / 'verdict.json'}); report {report}")  # fmt: skip
    warnings = campaign_warnings(store)
    if warnings:
        console.print(f"[yellow]{len(warnings)} campaign warning(s)[/] (also in the report):", highlight=False)
        for w in warnings:
            console.print(f"  {w}", markup=False, highlight=False)
