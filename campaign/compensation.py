"""Compensated joint targets as files: the targets CSV in, the compensated CSV out (KRL: campaign.krl).

    trackcal compensate --model model.json TARGETS.csv --out OUT.csv [--krl NAME --krl-dir DIR] [--tcp X,Y,Z]

TARGETS.csv: columns q1_deg..qn_deg (n = the model's joints), optional `name`, other columns ignored.
OUT.csv: name (if given), status (`ok`, or why the target could not be compensated: outside the joint limits,
a singular pose such as the KUKA HOME 0,-90,90,0,0,0), q1_deg..qn_deg (nominal), q1_comp_deg..qn_comp_deg
(compensated, 1e-6 deg), dq1_deg..dqn_deg (correction), position_error_mm and orientation_error_deg (the identified
model at the compensated targets against the intended pose), uncompensated_position_mm (the identified model at the
nominal targets), iterations, rounded_position_error_mm (the TCP error of the targets rounded to the 1e-4 deg the
KRL program carries). A target that was not compensated keeps its row, the compensated columns empty, and is left
out of the KRL program, whose E6AXIS points carry the targets' names (campaign.krl.point_names).
"""

from __future__ import annotations

import csv

import numpy as np

from trackcal.calib.io.table import joint_columns, read_joint_rows
from trackcal.campaign.output import output_file

COMP_DECIMALS = 6


def read_targets(path: str, dof: int) -> tuple[np.ndarray, list[str] | None]:
    """Joint targets (N, dof) in degrees and their names (None without a `name` column)."""
    q, others = read_joint_rows(path, dof, what="targets")
    return q, others.get("name")


def row_labels(path: str, names: list[str] | None, n: int) -> list[str]:
    """Labels for messages: the CSV row (header = row 1) and the target's name when it has one."""
    return [f"{path}: row {i + 2}" + (f" ({names[i]})" if names and names[i] else "") for i in range(n)]


def write_output(path: str, names, q_deg: np.ndarray, qc_deg: np.ndarray, report, rounded_mm: np.ndarray) -> None:
    n = q_deg.shape[1]
    header = (["name"] if names is not None else []) + ["status"] + joint_columns(n)
    header += [f"q{j + 1}_comp_deg" for j in range(n)] + [f"dq{j + 1}_deg" for j in range(n)]
    header += ["position_error_mm", "orientation_error_deg", "uncompensated_position_mm", "iterations"]
    header += ["rounded_position_error_mm"]
    with output_file(path, newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(header)
        for i in range(len(q_deg)):
            row = ([names[i]] if names is not None else []) + [report.failures[i] or "ok"]
            row += [f"{v:.4f}" for v in q_deg[i]]
            if report.failures[i]:  # nothing to run: the compensated columns stay empty
                row += [""] * (2 * n + 2) + [f"{report.uncompensated_position_mm[i]:.4f}", "", ""]
            else:
                row += [f"{v:.{COMP_DECIMALS}f}" for v in qc_deg[i]] + [f"{v:.6f}" for v in qc_deg[i] - q_deg[i]]
                row += [f"{report.position_error_mm[i]:.3e}", f"{report.orientation_error_deg[i]:.3e}",
                        f"{report.uncompensated_position_mm[i]:.4f}", str(int(report.iterations[i])),
                        f"{rounded_mm[i]:.4f}"]  # fmt: skip
            w.writerow(row)
