"""Orientation residuals on the real UR10: the T-Mac's measured orientation against the models fitted on positions.

No model here is fitted on orientation: the robot parameters, the joint offsets of the extensions (gravity
compliance, joint error map) and the station come from the T-Mac positions alone. The T-Mac measures its
orientation too (`measurement_rx/ry/rz`, intrinsic X-Y-Z Euler angles in degrees, tracker frame; the importer
keeps them as rx_deg, ry_deg, rz_deg). The model's prediction of it is

    R_tracker<-T-Mac = R_station  R_flange(q + dq)  R_mount,

R_flange the model's flange rotation at the reported angles q plus the extension's joint offsets dq, R_station
the station of the position fit. R_mount, the T-Mac's mounting rotation in the flange, is the one orientation
estimated from orientations, a constant (3 numbers) per model: the rotation mean of R_flange^T R_station^T R_meas
over the model's training rows. It also takes up the joint zero of wrist_3, which positions cannot see (the
T-Mac centre lies on that axis). The residual of a row is the angle of R_pred^T R_meas.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from trackcal.calib.diagnose.extensions import rebuild
from trackcal.calib.identify.solver import Identification
from trackcal.calib.io.table import MeasurementTable
from trackcal.calib.model.kinematics import Kinematics
from trackcal.campaign.importers.ipa_ur10 import euler_xyz_matrix

ANGLE_COLUMNS = ("rx_deg", "ry_deg", "rz_deg")


def measured_rotations(table: MeasurementTable) -> np.ndarray:
    """(N, 3, 3) the T-Mac's measured rotation, T-Mac frame -> tracker frame."""
    return euler_xyz_matrix(np.column_stack([np.array(table.extra[c], dtype=float) for c in ANGLE_COLUMNS]))


def model_rotations(res: Identification, table: MeasurementTable) -> np.ndarray:
    """(N, 3, 3) R_station R_flange(q + dq) of `res` at the rows of `table` (its extension rebuilt for them)."""
    q = np.radians(table.q_deg)
    if res.extension is not None:
        off = rebuild(res.extension, res.chain, table).joint_offsets(res.ext)
        if off is not None:
            q = q + off
    r_fl, _ = Kinematics(res.chain, res.params).end_frames(q, res.dev)
    r_st = np.array([res.stations[s].rotation for s in table.station])
    return r_st @ r_fl


def mount_rotation(res: Identification, table: MeasurementTable) -> np.ndarray:
    """R_mount: the rotation mean of (R_station R_flange)^T R_meas over the rows `res` was fitted on."""
    m = np.transpose(model_rotations(res, table), (0, 2, 1)) @ measured_rotations(table)
    return Rotation.from_matrix(m).mean().as_matrix()


def angular_rms_mrad(
    fit: Identification, fit_table: MeasurementTable, res: Identification, table: MeasurementTable
) -> float:
    """RMS angle (mrad) between the measured and the predicted T-Mac orientation on `table`: the robot model and
    station of `res` (fitted on `table`'s positions, or on another table with the same station), the mount of
    `fit` on its training rows `fit_table`."""
    pred = model_rotations(res, table) @ mount_rotation(fit, fit_table)
    err = Rotation.from_matrix(np.transpose(pred, (0, 2, 1)) @ measured_rotations(table)).magnitude()
    return float(1000.0 * np.sqrt(np.mean(err**2)))


def orientation_check(
    series: dict[str, tuple[Identification, Identification]],
    b: MeasurementTable,
    d: MeasurementTable,
    training: dict[str, Identification],
    train: MeasurementTable,
    hold: MeasurementTable,
) -> dict[str, dict[str, float]]:
    """Per model, the RMS angular residual (mrad): `b_held`, fitted on `train` (B's training poses) and predicting
    `hold` (B's held-out poses, same station); `d`, fitted on all of `b` and predicting D with D's station from
    D's positions (`series`: model -> (fit on B, that fit on D)), the mount from B; `d_own_mount`, the same with
    the mount estimated on D's orientations (the probe may have been remounted in the four months between the
    series); `mount_shift`, the angle (mrad) between the two mounts."""
    out = {}
    for name, (fit_b, on_d) in series.items():
        shift = Rotation.from_matrix(mount_rotation(fit_b, b).T @ mount_rotation(on_d, d)).magnitude()
        out[name] = {
            "b_held": angular_rms_mrad(training[name], train, training[name], hold),
            "d": angular_rms_mrad(fit_b, b, on_d, d),
            "d_own_mount": angular_rms_mrad(on_d, d, on_d, d),
            "mount_shift": float(1000.0 * shift),
        }
    return out
