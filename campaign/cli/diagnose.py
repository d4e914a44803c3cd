"""`trackcal diagnose`: the options in, calib.diagnose's search (campaign.jobs.diagnose), its verdict printed.

A module of its own so that `identify`, `predict` and `locate` (campaign.cli.analysis) do not import the search at
start-up (issue 41)."""

from __future__ import annotations

import sys

from rich.table import Table

from trackcal.calib.identify.noise import model_instrument
from trackcal.campaign.cli.analysis import um
from trackcal.campaign.cli.console import console, print_table
from trackcal.campaign.jobs.diagnose import DiagnoseOptions, run_diagnose


def cmd_diagnose(args) -> int:
    opts = DiagnoseOptions(
        data=args.data,
        cell=args.cell,
        json=args.json,
        params=args.params,
        weighting=args.weighting,
        folds=args.folds,
        seed=args.seed,
        plots=args.plots,
        out=args.out,
    )
    with console.status("fitting the geometric model and selecting causes (F test, BIC, cross-validation)"):
        done = run_diagnose(opts)
    if done.still:
        print(f"warning: {done.still}", file=sys.stderr)
    d, doc = done.diagnosis, done.verdict
    t = Table(
        title=f"Diagnosis: {d.cause}"
        + (f" (causes: {', '.join(c['cause'] for c in d.causes)})" if len(d.causes) > 1 else "")
    )
    for col in (
        "step",
        "candidate",
        "params",
        "held-out RMS µm",
        "gain µm",
        "fit RMS µm",
        "F-test p",
        "dBIC",
        "significant",
    ):
        t.add_column(col, justify="right")
    t.add_row("-", "geometric", "-", um(d.holdout_geometric_mm), "-", um(doc["geometric"]["rms_mm"]), "-", "-", "-")
    for c in doc["candidates"]:
        t.add_row(
            str(c["step"]),
            c["cause"],
            str(c["n_params"]),
            um(c["holdout_rms_mm"]),
            um(c["gain_mm"]),
            um(c["rms_mm"]),
            f"{c['f_pvalue']:.2g}",
            f"{c['delta_bic']:.0f}",
            "yes" if c["significant"] else "no",
        )
    print_table(t)
    console.print(f"tracker {model_instrument(doc).describe()}")
    console.print(
        f"noise floor {d.noise_floor_mm * 1000:.1f} µm ({d.floor_source}); {doc['noise_note']}; held-out "
        f"RMS {um(d.holdout_geometric_mm)} -> {um(d.holdout_extended_mm)} µm" + (f" ({d.cv_note})" if d.cv_note else "")
    )
    for p in done.plots:
        console.print(f"plot written to {p}")
    console.print(f"verdict written to {args.json}")
    return 0
