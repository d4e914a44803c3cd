"""The analysis jobs behind the CLI: identify a table against a cell, predict with a model."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.cell import Cell
from calib.diagnose import diagnose, fit_cause, relabel_shift
from calib.extensions import CAUSES, build_extension
from calib.identify import Identification, identify, predict_points, residual_stats, significance
from calib.model import Model, identification_to_doc
from calib.noise import TrackerNoise
from calib.params import Param, irreducible_params, param_by_name
from calib.table import MeasurementTable


class UsageError(ValueError):
    """A user mistake on the command line."""


def choose_params(cell: Cell, names: str | None) -> list[Param]:
    kept, _ = irreducible_params(cell.chain)
    if not names:
        return kept
    try:
        return [param_by_name(cell.chain, n.strip()) for n in names.split(",") if n.strip()]
    except ValueError as exc:
        raise UsageError(f"--params: {exc}; the irreducible set is {' '.join(p.name for p in kept)}") from None


@dataclass
class IdentifyOutcome:
    result: Identification
    before: Identification
    doc: dict


def run_identify(
    cell: Cell, table: MeasurementTable, params: list[Param], weighting: str = "iid", extend: str = "none"
) -> IdentifyOutcome:
    """Identify the geometric model, or the geometric model extended by a cause (`auto`: diagnose's)."""
    if extend not in ("none", "auto", *CAUSES):
        raise UsageError(f"--extend {extend}: choose none, auto or one of {', '.join(CAUSES)}")
    noise = None if weighting == "iid" else TrackerNoise()
    before = identify(cell.chain, table, cell.tool_points, [], noise=noise)
    if extend == "auto":
        extend = diagnose(cell.chain, table, cell.tool_points, params, noise).cause
        extend = "none" if extend == "unexplained" else extend
    fit = fit_cause(cell.chain, table, cell.tool_points, params, noise, extend)
    if fit is None:
        raise UsageError(f"--extend {extend}: this table cannot reveal it (too few rows or no variation)")
    res, _, _, shift, _ = fit
    return IdentifyOutcome(result=res, before=before, doc=model_doc(cell, table, res, before, shift))


def model_doc(cell: Cell, table: MeasurementTable, res: Identification, before: Identification, shift) -> dict:
    params = res.params
    extra: dict = {
        "cell": cell.name,
        "data": table.source,
        "n_measurements": len(table),
        "residuals": {"before": residual_stats(before.residuals), "after": residual_stats(res.residuals)},
    }
    if cell.test_pose is not None and cell.tcp is not None:
        extra["test_pose_deg"] = np.degrees(cell.test_pose).tolist()
        extra["tcp_mm"] = cell.tcp.tolist()
        extra["significance_mm"] = dict(significance(cell.chain, params, res.dev, cell.test_pose, cell.tcp))
    return identification_to_doc(res, extra, shift)


def summary_of(outcome: IdentifyOutcome) -> dict:
    res = outcome.result
    keys = ("cell", "data", "n_measurements", "residuals", "significance_mm")
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


def run_predict(model: Model, rows: MeasurementTable) -> MeasurementTable:
    if rows.n_joints != model.chain.dof:
        raise UsageError(
            f"{rows.source}: {rows.n_joints} joint columns, the model's robot has {model.chain.dof} joints"
        )
    ext, theta, labelled = None, None, rows
    if model.cause == "station_shift":
        info = model.doc["extension"]
        labelled = relabel_shift(rows, info["station"], float(info["after_t_s"]))
    elif model.cause != "none":
        names, theta = model.extension_values()
        ext = build_extension(model.cause, model.chain, rows, names=names)
    xyz = predict_points(model.chain, model.params, model.dev, model.stations, model.points, labelled, ext, theta)
    out = rows.subset(np.arange(len(rows)))
    out.xyz = xyz
    return out


def parse_effects(items: list[str] | None) -> dict[str, float]:
    out = {}
    for item in items or []:
        name, _, mag = item.partition(":")
        if name not in CAUSES:
            raise UsageError(f"--effect {item}: unknown effect; choose from {', '.join(CAUSES)}")
        try:
            out[name] = float(mag) if mag else 0.05
        except ValueError:
            raise UsageError(f"--effect {item}: the magnitude must be a number of mm") from None
        if not out[name] > 0:
            raise UsageError(f"--effect {item}: the magnitude must be positive")
    return out
