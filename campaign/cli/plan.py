"""`trackcal plan`: search or evaluate a measurement plan (campaign.planning on typed options)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from rich.progress import Progress

from trackcal.calib.model.cell import load_cell
from trackcal.campaign.cli.console import console
from trackcal.campaign.output import write_json
from trackcal.campaign.planning import (
    PlanOptions,
    build_design,
    evaluate_doc,
    read_plan_csv,
    search_doc,
    write_plan_csv,
)


def options_of(args) -> PlanOptions:
    return PlanOptions(params=args.params, test_pose=args.test_pose, sigma_mm=args.sigma_mm, noise=args.noise,
                       visibility=not args.no_visibility, configs=args.configs, repeat=args.repeat,
                       criterion=args.criterion, starts=args.starts, refined=args.refined, seed=args.seed,
                       scheduler=args.scheduler)  # fmt: skip


def cmd_plan(args) -> int:
    cell = load_cell(args.cell)
    opts = options_of(args)
    design = build_design(cell, opts)
    if args.evaluate:
        doc = evaluate_doc(design, read_plan_csv(args.evaluate, cell.chain.dof))
        if doc["infeasible_rows"]:
            console.print(f"warning: rows {doc['infeasible_rows']} leave the cell box or are not visible")
    else:
        with Progress(console=console, transient=True) as bar:
            task = bar.add_task(f"searching {opts.configs} configurations ({opts.criterion})", total=opts.refined)
            doc = search_doc(design, opts, lambda done, total: bar.update(task, completed=done, total=total))
        if args.csv:
            write_plan_csv(Path(args.csv), np.radians(np.array(doc["poses_deg"])), doc["repeat"])
        for q in doc["poses_deg"]:
            console.print("  " + "  ".join(f"{v:8.2f}" for v in q))
    rho0 = f"{doc['rho0_mm'] * 1000:.2f} µm" if doc["rho0_mm"] is not None else doc["rho0_why"]
    console.print(f"rho0 at the test pose: {rho0}  (parameters: {' '.join(doc['params'])})")
    write_json(args.json, doc)
    console.print(f"plan written to {args.json}")
    return 0
