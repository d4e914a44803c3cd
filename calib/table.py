"""The measurement table of DESIGN.md: read, validate, write.

seq,t_s,pose,station,point,q1_deg..qn_deg,x_mm,y_mm,z_mm[,extra columns ignored by readers]
Every bad input is reported as one line naming the file, the row (1-based, header = row 1) and the column.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import CalibError

XYZ = ("x_mm", "y_mm", "z_mm")


class TableError(CalibError):
    """A measurement table that cannot be used; the message names file, row and column."""


@dataclass
class MeasurementTable:
    seq: np.ndarray  # (N,) int
    t_s: np.ndarray  # (N,)
    pose: list[str]
    station: list[str]
    point: list[str]
    q_deg: np.ndarray  # (N, n)
    xyz: np.ndarray | None  # (N, 3) or None when the table has no measurements (predict input)
    extra: dict[str, list[str]] = field(default_factory=dict)
    source: str = "table"

    def __len__(self) -> int:
        return len(self.seq)

    @property
    def n_joints(self) -> int:
        return self.q_deg.shape[1]

    def subset(self, rows: np.ndarray) -> MeasurementTable:
        rows = np.asarray(rows)
        return MeasurementTable(
            seq=self.seq[rows],
            t_s=self.t_s[rows],
            pose=[self.pose[i] for i in rows],
            station=[self.station[i] for i in rows],
            point=[self.point[i] for i in rows],
            q_deg=self.q_deg[rows],
            xyz=None if self.xyz is None else self.xyz[rows],
            extra={k: [v[i] for i in rows] for k, v in self.extra.items()},
            source=self.source,
        )


def joint_columns(n: int) -> list[str]:
    return [f"q{j + 1}_deg" for j in range(n)]


def read_csv(path: Path, delimiter: str = ",", error: type[TableError] = TableError) -> list[list[str]]:
    """The rows of a delimited text file whose first row is a header of distinct names (stripped); every
    failure is `error` naming the file (and row 1 for the header)."""
    try:
        with path.open(newline="", encoding="utf-8") as fh:
            rows = list(csv.reader(fh, delimiter=delimiter))
    except OSError as exc:
        raise error(f"{path}: cannot read ({exc.strerror or exc})") from None
    except (UnicodeDecodeError, csv.Error) as exc:
        raise error(f"{path}: not a {delimiter!r}-separated text file ({exc})") from None
    if not rows:
        raise error(f"{path}: empty file, expected a header row")
    rows[0] = [h.strip() for h in rows[0]]
    if len(set(rows[0])) != len(rows[0]):
        raise error(f"{path}: row 1: duplicate column names")
    return rows


def read_table(path: str | Path, require_xyz: bool = True, n_joints: int | None = None) -> MeasurementTable:
    path = Path(path)
    rows = read_csv(path)
    header = rows[0]
    qcols = []
    while f"q{len(qcols) + 1}_deg" in header:
        qcols.append(f"q{len(qcols) + 1}_deg")
    if n_joints is not None and len(qcols) != n_joints:
        raise TableError(f"{path}: row 1: expected joint columns q1_deg..q{n_joints}_deg, found {len(qcols)}")
    required = ["seq", "t_s", "pose", "station", "point", *qcols] + (list(XYZ) if require_xyz else [])
    missing = [c for c in required if c not in header]
    if not qcols:
        missing.append("q1_deg")
    if missing:
        raise TableError(f"{path}: row 1: missing column(s) {', '.join(missing)}")
    has_xyz = all(c in header for c in XYZ)
    col = {h: i for i, h in enumerate(header)}
    data = rows[1:]
    while data and not any(cell.strip() for cell in data[-1]):
        data.pop()
    if not data:
        raise TableError(f"{path}: no data rows")

    def number(r: int, row: list[str], name: str) -> float:
        text = row[col[name]].strip()
        try:
            v = float(text)
        except ValueError:
            raise TableError(f"{path}: row {r}: column {name}: not a number: {text!r}") from None
        if not math.isfinite(v):
            raise TableError(f"{path}: row {r}: column {name}: not a finite number: {text!r}")
        return v

    seq, t, pose, station, point, q, xyz = [], [], [], [], [], [], []
    extra_cols = [h for h in header if h not in required and h not in XYZ]
    extra: dict[str, list[str]] = {h: [] for h in extra_cols}
    for k, row in enumerate(data):
        r = k + 2
        if len(row) != len(header):
            raise TableError(f"{path}: row {r}: {len(row)} fields, the header has {len(header)}")
        s = number(r, row, "seq")
        if s != int(s):
            raise TableError(f"{path}: row {r}: column seq: not an integer: {row[col['seq']]!r}")
        seq.append(int(s))
        t.append(number(r, row, "t_s"))
        for name, dst in (("pose", pose), ("station", station), ("point", point)):
            v = row[col[name]].strip()
            if not v:
                raise TableError(f"{path}: row {r}: column {name}: empty id")
            dst.append(v)
        q.append([number(r, row, c) for c in qcols])
        if has_xyz:
            xyz.append([number(r, row, c) for c in XYZ])
        for h in extra_cols:
            extra[h].append(row[col[h]])
    return MeasurementTable(
        seq=np.array(seq, dtype=int),
        t_s=np.array(t),
        pose=pose,
        station=station,
        point=point,
        q_deg=np.array(q, dtype=float),
        xyz=np.array(xyz, dtype=float) if has_xyz else None,
        extra=extra,
        source=str(path),
    )


def _fmt(v: float, digits: int) -> str:
    return f"{v:.{digits}f}"


def write_table(table: MeasurementTable, path: str | Path) -> None:
    """Write in the DESIGN.md layout (q to 1e-4 deg as the controller reports, xyz to 1e-4 mm)."""
    path = Path(path)
    header = ["seq", "t_s", "pose", "station", "point", *joint_columns(table.n_joints)]
    if table.xyz is not None:
        header += list(XYZ)
    header += list(table.extra)
    with path.open("w", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(header)
        for i in range(len(table)):
            row = [str(int(table.seq[i])), _fmt(table.t_s[i], 3), table.pose[i], table.station[i], table.point[i]]
            row += [_fmt(v, 4) for v in table.q_deg[i]]
            if table.xyz is not None:
                row += [_fmt(v, 4) for v in table.xyz[i]]
            row += [table.extra[h][i] for h in table.extra]
            w.writerow(row)


def read_joint_rows(path: str | Path, dof: int, what: str = "rows") -> tuple[np.ndarray, dict[str, list[str]]]:
    """Joint rows (N, dof) in degrees from a CSV with columns q1_deg..q{dof}_deg (a plan's poses, compensation
    targets), and its other columns as text; blank lines are skipped. A q{dof+1}_deg column is refused: the
    file was written for another robot."""
    path = Path(path)
    rows = read_csv(path)
    header, cols = rows[0], joint_columns(dof)
    missing = [c for c in cols if c not in header]
    if missing:
        raise TableError(f"{path}: row 1: missing column(s) {', '.join(missing)} (the robot has {dof} joints)")
    if f"q{dof + 1}_deg" in header:
        raise TableError(f"{path}: row 1: column q{dof + 1}_deg: the robot has only {dof} joints")
    idx = [header.index(c) for c in cols]
    others = {h: [] for h in header if h not in cols}
    q = []
    for k, row in enumerate(rows[1:]):
        if not any(cell.strip() for cell in row):
            continue
        r = k + 2
        if len(row) != len(header):
            raise TableError(f"{path}: row {r}: {len(row)} fields, the header has {len(header)}")
        values = []
        for c, i in zip(cols, idx, strict=True):
            try:
                v = float(row[i])
            except ValueError:
                raise TableError(f"{path}: row {r}: column {c}: not a number: {row[i]!r}") from None
            if not math.isfinite(v):
                raise TableError(f"{path}: row {r}: column {c}: not a finite number: {row[i]!r}")
            values.append(v)
        q.append(values)
        for h in others:
            others[h].append(row[header.index(h)].strip())
    if not q:
        raise TableError(f"{path}: no {what}")
    return np.array(q), others
