"""`trackcal plan`: search or evaluate a measurement plan (campaign.jobs.plan on typed options)."""

from __future__ import annotations

from rich.progress import Progress

from trackcal.calib.identify.noise import model_instrument
from trackcal.campaign.cli.console import console
from trackcal.campaign.jobs.plan import PlanOptions, plan


def options_of(args) -> PlanOptions:
    return PlanOptions(
        params=args.params,
        test_pose=args.test_pose,
        sigma_mm=args.sigma_mm,
        noise=args.noise,
        visibility=not args.no_visibility,
        configs=args.configs,
        repeat=args.repeat,
        criterion=args.criterion,
        starts=args.starts,
        refined=args.refined,
        seed=args.seed,
        scheduler=args.scheduler,
    )


def cmd_plan(args) -> int:
    opts = options_of(args)
    if args.evaluate:
        doc = plan(args.cell, opts, args.json, evaluate=args.evaluate).doc
        if doc["infeasible_rows"]:
            console.print(f"warning: rows {doc['infeasible_rows']} leave the cell box or are not visible")
    else:
        with Progress(console=console, transient=True) as bar:
            task = bar.add_task(f"searching a plan ({opts.criterion})", total=opts.refined)
            doc = plan(
                args.cell,
                opts,
                args.json,
                csv_out=args.csv,
                progress=lambda done, total: bar.update(task, completed=done, total=total),
            ).doc
        for q in doc["poses_deg"]:
            console.print("  " + "  ".join(f"{v:8.2f}" for v in q))
        if doc["why"] != "as asked":
            console.print(f"plan size: {doc['why']}")
    rho0 = f"{doc['rho0_mm'] * 1000:.2f} µm" if doc["rho0_mm"] is not None else doc["rho0_why"]
    noise = f"tracker model of the {model_instrument(doc).describe()}" if "tracker" in doc else "i.i.d."
    u = doc["unknowns"]
    console.print(
        f"rho0 at the test pose: {rho0}  (the predicted 1-sigma uncertainty of the reference points' "
        f"centroid there; unknowns: {u['robot_params']} robot parameters, {u['stations']} stations, "
        f"{u['points']} points; noise: {noise})"
    )
    console.print(f"plan written to {args.json}")
    return 0
