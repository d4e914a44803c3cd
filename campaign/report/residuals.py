"""The residuals a report shows (paper Table 9, Figs. 10 and 11): "after" is the table minus the model's prediction
(`trackcal predict`, extension honoured), so a report on a validation table (poses not used for identification) shows
how the model predicts; "before" is the purely nominal robot with the stations and reference points fitted to the same
table (what `trackcal identify` reports as before); the noise floor is the table's (calib.diagnose.noise_floor).
Derived once per analysis (campaign.jobs.end_of_run): a fit or floor the analysis already holds is not made again."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trackcal.calib.diagnose.noise_floor import Floor, noise_floor
from trackcal.calib.identify.noise import TrackerNoise, model_noise
from trackcal.calib.identify.solver import Identification, identify, residual_stats
from trackcal.calib.io.table import MeasurementTable
from trackcal.calib.model.cell import Cell
from trackcal.calib.model_file import model_from_doc, predict_table
from trackcal.campaign.errors import InputError


@dataclass(frozen=True)
class Residuals:
    before: np.ndarray  # (N, 3) mm, station frames: nominal robot, stations and points fitted
    after: np.ndarray  # (N, 3) mm: measured - predicted by the model
    stats_before: dict[str, float]
    stats_after: dict[str, float]
    floor_mm: float  # expected RMS of one coordinate from the tracker alone (calib.diagnose.noise_floor)
    floor_source: str


def residuals_of(
    cell: Cell,
    table: MeasurementTable,
    model_doc: dict,
    before: Identification | None = None,
    floor: Floor | None = None,
) -> Residuals:
    """The residuals of `model_doc` on `table`; `before`: the nominal robot's fit of this table and `floor` its noise
    floor, when the caller has them (else they are found here, with the model's weighting)."""
    if table.xyz is None:
        raise InputError(f"{table.source}: the table has no x_mm, y_mm, z_mm: nothing to report residuals of")
    model = model_from_doc(model_doc)
    after = table.xyz - predict_table(model, table).xyz
    noise = model_noise(model_doc)
    if before is None:
        before = identify(model.chain, table, cell.tool_points, [], noise=noise, covariance=False)
    found = floor or noise_floor(table, noise, TrackerNoise.of(cell.tracker))
    return Residuals(
        before.residuals, after, residual_stats(before.residuals), residual_stats(after), found.sigma_mm, found.source
    )


def pose_order(table: MeasurementTable) -> list[str]:
    return list(dict.fromkeys(table.pose))


def per_pose_rms(table: MeasurementTable, residuals: np.ndarray) -> np.ndarray:
    """RMS residual distance (mm) of every configuration (pose id), in order of first measurement."""
    dist = np.linalg.norm(residuals, axis=1)
    pose = np.array(table.pose)
    return np.array([np.sqrt(np.mean(dist[pose == p] ** 2)) for p in pose_order(table)])
