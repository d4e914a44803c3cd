"""`trackcal compensate`: joint targets corrected with an identified model, as CSV and optionally KRL.

    trackcal compensate --model model.json TARGETS.csv --out OUT.csv [--krl NAME --krl-dir DIR] [--tcp X,Y,Z]

TARGETS.csv: columns q1_deg..qn_deg (n = the model's joints), optional `name`, other columns ignored.
OUT.csv: name (if given), q1_deg..qn_deg (nominal), q1_comp_deg..qn_comp_deg (compensated, 1e-6 deg),
dq1_deg..dqn_deg (correction), position_error_mm and orientation_error_deg (the identified model at the
compensated targets against the intended pose), uncompensated_position_mm (the identified model at the
nominal targets), iterations, rounded_position_error_mm (the TCP error of the targets rounded to the 1e-4 deg
the KRL program carries).
"""

from __future__ import annotations

import csv
import sys
from pathlib import Path

import numpy as np

from calib.compensate import NEAR_SINGULAR, CompensationError, compensate, pose_error
from calib.model import load_model

from .jobs import UsageError
from .krl import KrlError, check_name, write_krl

COMP_DECIMALS = 6


def read_targets(path: str, dof: int) -> tuple[np.ndarray, list[str] | None]:
    """Joint targets (N, dof) in degrees and their names (None without a `name` column)."""
    cols = [f"q{j + 1}_deg" for j in range(dof)]
    try:
        with open(path, newline="") as fh:
            reader = csv.reader(fh)
            rows = list(reader)
    except OSError as exc:
        raise UsageError(f"{path}: cannot read ({exc.strerror or exc})") from None
    except (UnicodeDecodeError, csv.Error) as exc:
        raise UsageError(f"{path}: not a CSV text file ({exc})") from None
    if not rows:
        raise UsageError(f"{path}: empty file, expected a header row with {', '.join(cols)}")
    header = [h.strip() for h in rows[0]]
    missing = [c for c in cols if c not in header]
    if missing:
        raise UsageError(f"{path}: row 1: missing column(s) {', '.join(missing)} (the model's robot has {dof} joints)")
    extra_q = f"q{dof + 1}_deg"
    if extra_q in header:
        raise UsageError(f"{path}: row 1: column {extra_q}: the model's robot has only {dof} joints")
    idx = [header.index(c) for c in cols]
    name_idx = header.index("name") if "name" in header else None
    data = [r for r in rows[1:] if any(cell.strip() for cell in r)]
    if not data:
        raise UsageError(f"{path}: no targets")
    q, names = [], []
    for k, row in enumerate(rows[1:]):
        if not any(cell.strip() for cell in row):
            continue
        r = k + 2
        if len(row) != len(header):
            raise UsageError(f"{path}: row {r}: {len(row)} fields, the header has {len(header)}")
        values = []
        for c, i in zip(cols, idx, strict=True):
            try:
                v = float(row[i])
            except ValueError:
                raise UsageError(f"{path}: row {r}: column {c}: not a number: {row[i]!r}") from None
            if not np.isfinite(v):
                raise UsageError(f"{path}: row {r}: column {c}: not a finite number: {row[i]!r}")
            values.append(v)
        q.append(values)
        names.append(row[name_idx].strip() if name_idx is not None else f"row {r}")
    return np.array(q), (names if name_idx is not None else None)


def parse_tcp(text: str | None, model) -> np.ndarray:
    if text is None:
        if not model.points:
            raise UsageError("the model has no tool points: give --tcp X,Y,Z (mm, last joint frame)")
        return np.mean(list(model.points.values()), axis=0)
    try:
        tcp = np.array([float(v) for v in text.split(",")])
    except ValueError:
        raise UsageError(f"--tcp {text}: expected X,Y,Z in mm") from None
    if tcp.shape != (3,) or not np.all(np.isfinite(tcp)):
        raise UsageError(f"--tcp {text}: expected 3 finite numbers X,Y,Z in mm")
    return tcp


def _row_labels(path: str, names: list[str] | None, n: int) -> list[str]:
    """Labels for messages: the CSV row (header = row 1) and the target's name when it has one."""
    return [f"{path}: row {i + 2}" + (f" ({names[i]})" if names and names[i] else "") for i in range(n)]


def write_output(path: str, names, q_deg: np.ndarray, qc_deg: np.ndarray, report, rounded_mm: np.ndarray) -> None:
    n = q_deg.shape[1]
    header = (["name"] if names is not None else []) + [f"q{j + 1}_deg" for j in range(n)]
    header += [f"q{j + 1}_comp_deg" for j in range(n)] + [f"dq{j + 1}_deg" for j in range(n)]
    header += ["position_error_mm", "orientation_error_deg", "uncompensated_position_mm", "iterations"]
    header += ["rounded_position_error_mm"]
    try:
        with open(path, "w", newline="") as fh:
            w = csv.writer(fh, lineterminator="\n")
            w.writerow(header)
            for i in range(len(q_deg)):
                row = [names[i]] if names is not None else []
                row += [f"{v:.4f}" for v in q_deg[i]] + [f"{v:.{COMP_DECIMALS}f}" for v in qc_deg[i]]
                row += [f"{v:.6f}" for v in qc_deg[i] - q_deg[i]]
                row += [f"{report.position_error_mm[i]:.3e}", f"{report.orientation_error_deg[i]:.3e}",
                        f"{report.uncompensated_position_mm[i]:.4f}", str(int(report.iterations[i])),
                        f"{rounded_mm[i]:.4f}"]  # fmt: skip
                w.writerow(row)
    except OSError as exc:
        raise UsageError(f"{path}: cannot write ({exc.strerror or exc})") from None


def cmd_compensate(args) -> int:
    model = load_model(args.model)
    q_deg, names = read_targets(args.targets, model.chain.dof)
    tcp = parse_tcp(args.tcp, model)
    if args.krl_dir and not args.krl:
        raise UsageError("--krl-dir needs --krl NAME")
    if args.krl:  # refuse before anything is written
        try:
            check_name(args.krl)
        except KrlError as exc:
            raise UsageError(f"--krl: {exc}") from None
        if model.chain.dof != 6:
            raise UsageError(f"--krl: a KR C2 program needs a 6-axis robot, the model's has {model.chain.dof}")
        if not 1 <= args.speed <= 100:
            raise UsageError(f"--speed {args.speed}: the axis speed override is a percentage 1..100")
    try:
        qc, report = compensate(model, np.radians(q_deg), tcp, labels=_row_labels(args.targets, names, len(q_deg)))
    except CompensationError as exc:
        raise UsageError(str(exc)) from None
    qc_deg = np.degrees(qc)
    # the KRL program carries 1e-4 deg (as the controller reports angles): what rounding costs at the TCP
    krl_deg = np.round(qc_deg, 4)
    rounded_mm, _ = pose_error(model, np.radians(krl_deg), np.radians(q_deg), tcp)
    write_output(args.out, names, q_deg, qc_deg, report, rounded_mm)
    for warning in report.ignored:
        print(f"warning: {warning}", file=sys.stderr)
    for note in report.notes:
        print(f"note: {note}")
    near = np.flatnonzero(report.conditioning < NEAR_SINGULAR)
    if len(near):
        rows = ", ".join(str(i + 2) for i in near[:10]) + (" ..." if len(near) > 10 else "")
        print(f"warning: {len(near)} target(s) near a singularity (rows {rows}): large joint corrections, "
              "check them before running", file=sys.stderr)  # fmt: skip
    doc = report.to_doc()
    print(
        f"{doc['targets']} targets compensated (model extension: {doc['cause']}); TCP error of the identified "
        f"model before compensation up to {doc['max_uncompensated_position_mm']:.3f} mm, after "
        f"{doc['max_position_error_mm']:.1e} mm / {doc['max_orientation_error_deg']:.1e} deg; largest correction "
        f"{doc['max_correction_deg']:.4f} deg, at most {doc['max_iterations']} iterations; rounded to 1e-4 deg "
        f"(KRL) up to {rounded_mm.max():.4f} mm"
    )
    print(f"compensated targets written to {args.out}")
    if args.krl:
        krl_dir = args.krl_dir or str(Path(args.out).parent)
        try:
            src, dat = write_krl(args.krl, krl_deg, krl_dir, args.speed)
        except KrlError as exc:
            raise UsageError(f"--krl: {exc}") from None
        print(f"KRL program written to {src} and {dat}")
    return 0


def register_compensate(subparsers) -> None:
    p = subparsers.add_parser("compensate", help="joint targets corrected with an identified model (CSV, KRL)")
    p.add_argument("targets", help="CSV of nominal joint targets: q1_deg..qn_deg, optional name")
    p.add_argument("--model", required=True, help="model.json from identify or diagnose")
    p.add_argument("--out", required=True, help="CSV to write: the targets plus compensated angles and errors")
    p.add_argument("--tcp", help="X,Y,Z of the TCP in the last joint frame, mm (default: tool points centroid)")
    p.add_argument("--krl", metavar="NAME", help="also write a KR C2 program NAME.src / NAME.dat")
    p.add_argument("--krl-dir", help="directory of the KRL program (default: the directory of --out)")
    p.add_argument("--speed", type=int, default=10, help="PTP axis speed and acceleration override, %% (1-100)")
    p.set_defaults(func=cmd_compensate)
