"""Import the IPA UR10 laser-tracker series (christianlandgraf/ipa-robot-accuracy, MIT) as measurement tables.

Data set of Landgraf, Ernst, Schleth, Fabritius, Huber, "A Hybrid Neural Network Approach for Increasing
the Absolute Accuracy of Industrial Robots", IEEE CASE 2021, pp. 468-474: a UR10 carrying a Leica T-Mac
6-DoF probe, measured by a Leica laser tracker. One CSV row per pose, semicolon-separated, decimal commas:
joint angles in rad (`shoulder_pan_joint` .. `wrist_3_joint`), the T-Mac position in mm and orientation in
deg in the tracker frame (`measurement_x/y/z`, `measurement_rx/ry/rz`), each with a `measurement_std_*`,
and `measurement_temperature` in deg C.

The converter writes the DESIGN.md table: one station ("T1" by default), the T-Mac position as reference
point "TMAC", pose ids P0001.. (P0001 = the first data row, CSV line 2), q in degrees. The `Timestamp`
column was mangled into scientific notation by a spreadsheet (2,02011E+13: no usable time), so `t_s` is
NOT a measured time: it is the data-row index times a nominal period (`period_s`, 10 s by default).
Extra columns: temp_c, std_x_mm, std_y_mm, std_z_mm, rx_deg, ry_deg, rz_deg, std_rx_deg, std_ry_deg,
std_rz_deg (the probe orientation and its standard deviations, needed by the virtual points' noise model).

Virtual reference points (option `virtual_points=K`): the paper's enhanced partial-pose idea (Wu et al.
2015, several reference points per pose) applied to the probe's measured orientation. K points rigidly
attached to the probe at +-`lever_mm` along its axes (order +X, +Y, +Z, -X, -Y, -Z, first K taken) are
computed as p + R v_k, R = Rx(rx) Ry(ry) Rz(rz) (Euler 'XYZ', intrinsic; checked on the data, see
docs/ur10-real-data.md). They are not independent measurements: `pose_covariance` gives their joint
covariance with the T-Mac point, from the position and angle standard deviations of the row. It has rank
6 at most (three positions and three angles make every point), 5 with one virtual point (a rotation about
the lever moves nothing): beyond K = 2 the points repeat what the first two already say.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from trackcal.calib.io.table import MeasurementTable, TableError, read_csv
from trackcal.calib.model.rigid import rot_axis, skew

JOINTS = ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint")
POSITION = ("measurement_x", "measurement_y", "measurement_z")
ANGLES = ("measurement_rx", "measurement_ry", "measurement_rz")
STD_POSITION = ("measurement_std_x", "measurement_std_y", "measurement_std_z")
STD_ANGLES = ("measurement_std_rx", "measurement_std_ry", "measurement_std_rz")
TEMPERATURE = "measurement_temperature"
# optional source columns -> extra table columns (copied when present)
EXTRAS = {
    TEMPERATURE: "temp_c",
    **dict(zip(STD_POSITION, ("std_x_mm", "std_y_mm", "std_z_mm"), strict=True)),
    **dict(zip(ANGLES, ("rx_deg", "ry_deg", "rz_deg"), strict=True)),
    **dict(zip(STD_ANGLES, ("std_rx_deg", "std_ry_deg", "std_rz_deg"), strict=True)),
}
# directions of the virtual points in the T-Mac frame, in the order they are taken
VIRTUAL_DIRECTIONS = (
    ("X+", (1, 0, 0)),
    ("Y+", (0, 1, 0)),
    ("Z+", (0, 0, 1)),
    ("X-", (-1, 0, 0)),
    ("Y-", (0, -1, 0)),
    ("Z-", (0, 0, -1)),
)
POINT = "TMAC"
DEFAULT_PERIOD_S = 10.0


class IpaFormatError(TableError):
    """A malformed IPA series file; the message names the file, the row (header = row 1) and the column."""


def euler_xyz_matrix(angles_deg: np.ndarray) -> np.ndarray:
    """R = Rx(a) Ry(b) Rz(c) (intrinsic X-Y-Z, scipy's 'XYZ') for angles (..., 3) in degrees."""
    a = np.radians(np.asarray(angles_deg, dtype=float))
    return rot_axis(0, a[..., 0]) @ rot_axis(1, a[..., 1]) @ rot_axis(2, a[..., 2])


def euler_xyz_rates(angles_deg: np.ndarray) -> np.ndarray:
    """E with omega = E d(angles): the small rotation (tracker frame, rad) caused by small Euler-angle changes.

    For R = Rx(a) Ry(b) Rz(c):  dR R^T = [omega]x with omega = da e_x + db Rx(a) e_y + dc Rx(a) Ry(b) e_z.
    """
    a = np.radians(np.asarray(angles_deg, dtype=float))
    rx, ry = rot_axis(0, a[..., 0]), rot_axis(1, a[..., 1])
    e = np.zeros(a.shape[:-1] + (3, 3))
    e[..., :, 0] = [1.0, 0.0, 0.0]
    e[..., :, 1] = rx[..., :, 1]
    e[..., :, 2] = (rx @ ry)[..., :, 2]
    return e


def virtual_offsets(k: int, lever_mm: float = 100.0) -> list[tuple[str, np.ndarray]]:
    """The first k virtual points: (point id, offset in the T-Mac frame, mm)."""
    if not 0 <= k <= len(VIRTUAL_DIRECTIONS):
        raise ValueError(f"virtual points: choose 0 to {len(VIRTUAL_DIRECTIONS)}, got {k}")
    return [(f"{POINT}_{name}", lever_mm * np.array(d, dtype=float)) for name, d in VIRTUAL_DIRECTIONS[:k]]


def pose_covariance(
    angles_deg: np.ndarray, std_xyz_mm: np.ndarray, std_angles_deg: np.ndarray, offsets_mm: list[np.ndarray]
) -> np.ndarray:
    """Joint covariance (3(K+1), 3(K+1)) of [T-Mac point, virtual point 1..K] of one pose, tracker frame, mm^2.

    Point k is P_k = p + R v_k, so  dP_k = dp + omega x (R v_k) = dp - [R v_k]x E d(angles)  (E from
    `euler_xyz_rates`). The position noise (std columns, per tracker axis) is common to every point: the
    virtual points are strongly correlated with the T-Mac point and only their orientation part (lever x
    angle noise, ~100 mm x 0.002 deg = 3.5 um for the typical std columns) is new. Position and angle noise
    are taken as independent (the file gives no cross terms). Six noise sources drive all 3(K+1)
    coordinates, so the matrix is singular for K >= 1 (rank 5 for K = 1, 6 beyond).
    """
    sp2 = np.asarray(std_xyz_mm, dtype=float) ** 2
    sa2 = np.radians(np.asarray(std_angles_deg, dtype=float)) ** 2
    r = euler_xyz_matrix(angles_deg)
    e = euler_xyz_rates(angles_deg)
    # d[p, P_1..P_K] / d[position, angles]: every point moves with the position; P_k also turns with R
    a = np.tile(np.hstack([np.eye(3), np.zeros((3, 3))]), (len(offsets_mm) + 1, 1))
    for k, v in enumerate(offsets_mm, start=1):
        a[3 * k : 3 * k + 3, 3:] = -skew(r @ v) @ e
    return a @ np.diag(np.concatenate([sp2, sa2])) @ a.T


def _cells(path: Path) -> tuple[list[str], list[tuple[int, list[str]]]]:
    """Header and (row number, cells) of the data rows, trailing blank rows dropped."""
    rows = read_csv(path, delimiter=";", error=IpaFormatError)
    data = [(k + 2, r) for k, r in enumerate(rows[1:])]
    while data and not any(c.strip() for c in data[-1][1]):
        data.pop()
    return rows[0], data


def read_columns(path: str | Path, required: list[str], optional: list[str] = ()) -> dict[str, np.ndarray]:
    """The named columns of an IPA series CSV as numbers (decimal commas); `optional` ones only if present.
    Errors name the file, the row (header = row 1) and the column."""
    path = Path(path)
    header, data = _cells(path)
    missing = [c for c in required if c not in header]
    if missing:
        raise IpaFormatError(f"{path}: row 1: missing column(s) {', '.join(missing)}")
    if not data:
        raise IpaFormatError(f"{path}: no data rows")
    col = {h: i for i, h in enumerate(header)}
    names = list(required) + [c for c in optional if c in col and c not in required]
    out = {c: np.empty(len(data)) for c in names}
    for k, (r, row) in enumerate(data):
        if len(row) != len(header):
            raise IpaFormatError(f"{path}: row {r}: {len(row)} fields, the header has {len(header)}")
        for c in names:
            text = row[col[c]].strip()
            try:
                v = float(text.replace(",", "."))
            except ValueError:
                raise IpaFormatError(f"{path}: row {r}: column {c}: not a number: {text!r}") from None
            if not math.isfinite(v):
                raise IpaFormatError(f"{path}: row {r}: column {c}: not a finite number: {text!r}")
            out[c][k] = v
    return out


def read_ipa_series(
    path: str | Path,
    station: str = "T1",
    period_s: float = DEFAULT_PERIOD_S,
    virtual_points: int = 0,
    lever_mm: float = 100.0,
) -> MeasurementTable:
    """Read one IPA UR10 series CSV into a measurement table (mm, deg); see the module docstring."""
    offsets = virtual_offsets(virtual_points, lever_mm)
    required = list(JOINTS) + list(POSITION) + (list(ANGLES) if virtual_points else [])
    cols = read_columns(path, required, list(EXTRAS))
    n = len(cols[JOINTS[0]])
    q_deg = np.degrees(np.column_stack([cols[c] for c in JOINTS]))  # rad in the file
    xyz = np.column_stack([cols[c] for c in POSITION])
    pts = [xyz] + [xyz + euler_xyz_matrix(np.column_stack([cols[c] for c in ANGLES])) @ v for _, v in offsets]
    n_pts = len(pts)
    rows = np.arange(n)
    return MeasurementTable(
        seq=np.arange(n * n_pts),
        t_s=np.repeat(rows * float(period_s), n_pts),
        pose=[f"P{k + 1:04d}" for k in rows for _ in range(n_pts)],
        station=[station] * (n * n_pts),
        point=[pid for _ in rows for pid in [POINT] + [o[0] for o in offsets]],
        q_deg=np.repeat(q_deg, n_pts, axis=0),
        xyz=np.stack(pts, axis=1).reshape(-1, 3),
        extra={EXTRAS[c]: [format(v, ".10g") for v in np.repeat(cols[c], n_pts)] for c in EXTRAS if c in cols},
        source=str(path),
    )


def table_covariances(table: MeasurementTable) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per pose of an imported table: (row indices, joint covariance of those rows) from its extra columns.
    The virtual points' offsets are read back from the table (R^T (P_k - p)), whatever lever it was made with."""
    need = ["rx_deg", "ry_deg", "rz_deg", "std_x_mm", "std_y_mm", "std_z_mm", "std_rx_deg", "std_ry_deg", "std_rz_deg"]
    missing = [c for c in need if c not in table.extra]
    if missing:
        raise IpaFormatError(f"{table.source}: missing column(s) {', '.join(missing)} for the noise model")
    out = []
    order: dict[str, list[int]] = {}
    for i, pid in enumerate(table.pose):
        order.setdefault(pid, []).append(i)
    for rows in order.values():
        i0 = rows[0]
        if table.point[i0] != POINT:
            raise IpaFormatError(f"{table.source}: row {i0 + 2}: column point: a pose must start with {POINT}")

        def f(c: str, i0: int = i0) -> float:
            return float(table.extra[c][i0])

        angles = [f("rx_deg"), f("ry_deg"), f("rz_deg")]
        offs = [euler_xyz_matrix(angles).T @ (table.xyz[i] - table.xyz[i0]) for i in rows[1:]]
        std_xyz = [f("std_x_mm"), f("std_y_mm"), f("std_z_mm")]
        std_ang = [f("std_rx_deg"), f("std_ry_deg"), f("std_rz_deg")]
        cov = pose_covariance(angles, std_xyz, std_ang, offs)
        out.append((np.array(rows), cov))
    return out
