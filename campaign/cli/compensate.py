"""`trackcal compensate`: joint targets corrected with an identified model, as CSV and optionally KRL."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from trackcal.calib.compensate import NEAR_SINGULAR, compensate, pose_error
from trackcal.calib.model_file import load_model
from trackcal.campaign.compensation import read_targets, row_labels, write_output
from trackcal.campaign.errors import InputError, UsageError
from trackcal.campaign.krl import KrlError, check_name, point_names, write_krl


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
    qc, report = compensate(model, np.radians(q_deg), tcp)
    qc_deg = np.degrees(qc)
    # the KRL program carries 1e-4 deg (as the controller reports angles): what rounding costs at the TCP
    krl_deg = np.round(qc_deg, 4)
    rounded_mm, _ = pose_error(model, np.radians(krl_deg), np.radians(q_deg), tcp)
    write_output(args.out, names, q_deg, qc_deg, report, rounded_mm)
    ok = report.ok
    if not ok.any():
        first = report.failures[0]
        raise InputError(f"{args.targets}: no target could be compensated (row 2: {first}; {args.out} has each row's "
                         "reason)")  # fmt: skip
    for label, failure in zip(row_labels(args.targets, names, len(q_deg)), report.failures, strict=True):
        if failure:
            print(f"warning: {label}: not compensated: {failure}", file=sys.stderr)
    for warning in [*report.ignored, *report.warnings]:
        print(f"warning: {warning}", file=sys.stderr)
    for note in report.notes:
        print(f"note: {note}")
    near = np.flatnonzero(ok & (report.conditioning < NEAR_SINGULAR))
    if len(near):
        rows = ", ".join(str(i + 2) for i in near[:10]) + (" ..." if len(near) > 10 else "")
        print(f"warning: {len(near)} target(s) near a singularity (rows {rows}): large joint corrections, "
              "check them before running", file=sys.stderr)  # fmt: skip
    doc = report.to_doc()
    failed = doc["targets"] - doc["compensated"]
    print(
        f"{doc['compensated']} of {doc['targets']} targets compensated"
        + (f" ({failed} not: see their rows)" if failed else "")
        + f" (model extension: {doc['cause']}); TCP error of the identified "
        f"model before compensation up to {doc['max_uncompensated_position_mm']:.3f} mm, after "
        f"{doc['max_position_error_mm']:.1e} mm / {doc['max_orientation_error_deg']:.1e} deg; largest correction "
        f"{doc['max_correction_deg']:.4f} deg, at most {doc['max_iterations']} iterations; rounded to 1e-4 deg "
        f"(KRL) up to {rounded_mm[ok].max():.4f} mm"
    )
    print(f"compensated targets written to {args.out}")
    if args.krl:
        krl_dir = args.krl_dir or str(Path(args.out).parent)
        try:
            points = [p for p, k in zip(point_names(names, len(ok)), ok, strict=True) if k]
            src, dat = write_krl(args.krl, krl_deg[ok], krl_dir, args.speed, points)
        except KrlError as exc:
            raise UsageError(f"--krl: {exc}") from None
        print(f"KRL program written to {src} and {dat}")
    return 0
