"""`trackcal compensate`: joint targets corrected with an identified model, as CSV and optionally the controller's
program (campaign.jobs.compensate on typed options)."""

from __future__ import annotations

import sys

from trackcal.calib.compensate import OUTSIDE_RANGES
from trackcal.campaign.jobs.compensate import CompensateOptions, run_compensate


def cmd_compensate(args) -> int:
    done = run_compensate(
        CompensateOptions(
            targets=args.targets,
            model=args.model,
            out=args.out,
            tcp=args.tcp,
            krl=args.krl,
            krl_dir=args.krl_dir,
            speed=args.speed,
            program=args.program,
            strict=args.strict,
            accept_edited=args.accept_edited,
            accept_poor=args.accept_poor,
            allow_outside=args.allow_outside,
        )
    )
    report, ok = done.report, done.report.ok
    for warning in done.model_warnings:
        print(f"warning: {warning}", file=sys.stderr)
    for label, failure in zip(done.labels, report.failures, strict=True):
        if failure:
            kept = " (its nominal target in the program, commented)" if done.krl_files or done.program_files else ""
            print(f"warning: {label}: not compensated{kept}: {failure}", file=sys.stderr)
    if any(f.startswith(OUTSIDE_RANGES) for f in report.failures):
        print(
            "note: --allow-outside compensates the targets outside the fitted joint ranges (the model's extension "
            "held at the nearest fitted angle)"
        )
    for warning in [*report.ignored, *report.warnings]:
        print(f"warning: {warning}", file=sys.stderr)
    for note in report.notes:
        print(f"note: {note}")
    near = done.near_singular
    if len(near):
        rows = ", ".join(str(i + 2) for i in near[:10]) + (" ..." if len(near) > 10 else "")
        print(
            f"warning: {len(near)} target(s) near a singularity (rows {rows}): large joint corrections, "
            "check them before running",
            file=sys.stderr,
        )
    doc = done.doc
    failed = doc["targets"] - doc["compensated"]
    print(
        f"{doc['compensated']} of {doc['targets']} targets compensated"
        + (f" ({failed} not: see their rows)" if failed else "")
        + f" (model extension: {' + '.join(doc['causes'] or [doc['cause']])}); TCP error of the identified "
        f"model before compensation up to {doc['max_uncompensated_position_mm']:.3f} mm, after "
        f"{doc['max_position_error_mm']:.1e} mm / {doc['max_orientation_error_deg']:.1e} deg; largest correction "
        f"{doc['max_correction_deg']:.4f} deg, at most {doc['max_iterations']} iterations; rounded to 1e-4 deg "
        f"(KRL) up to {done.rounded_mm[ok].max():.4f} mm"
    )
    print(f"compensated targets written to {args.out}")
    if done.krl_files is not None:
        src, dat = done.krl_files
        print(f"KRL program written to {src} and {dat}")
    if done.program_files:
        print(f"program written to {', '.join(str(p) for p in done.program_files)}")
    return 0
