"""`trackcal demo`: plan, simulated campaign, identification and diagnosis on embedded defaults (its own module:
it drives a campaign, whose imports the analysis commands do not need)."""

from __future__ import annotations

import shutil
from pathlib import Path

from trackcal.calib.model.cell import load_cell
from trackcal.campaign.cli.analysis import print_identification, um
from trackcal.campaign.cli.campaign import drive
from trackcal.campaign.cli.console import console
from trackcal.campaign.cli.report import analyse_and_print
from trackcal.campaign.jobs.campaign import new_session
from trackcal.campaign.jobs.plan import PlanOptions, plan
from trackcal.campaign.jobs.simulate import test_pose_miss_mm, twin_truth


def cmd_demo(args) -> int:
    """Plan + simulated campaign (2 stations, 3 points, operator prompts) + identification + diagnosis."""
    out = Path(args.out)
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    cell = load_cell(args.cell)
    console.rule(f"trackcal demo: cell {cell.name} on the digital twin")
    with console.status("planning: test-pose optimal poses (paper section 6)"):
        # the default plan (`trackcal plan --cell C`): its size from the cell's unknowns
        plan_doc = plan(args.cell, PlanOptions(seed=args.seed), str(out / "plan.json")).doc
    console.print(
        f"plan: {len(plan_doc['poses_deg'])} configurations x {plan_doc['repeat']}, rho0 at the test pose "
        f"{um(plan_doc['rho0_mm'], 2)} µm ({out / 'plan.json'})"
    )
    console.print(f"plan size: {plan_doc['why']}")
    store, campaign = new_session(out / "session", args.cell, plan_doc, "sim", args.seed, cell=cell)
    drive(store, campaign)
    analysis = analyse_and_print(store, campaign)
    if analysis is not None:  # the geometric model's parameters against the twin's truth
        print_identification(analysis.geometric, twin_truth(cell, args.seed))
        figure = analysis.geometric.get("test_pose")
        miss = test_pose_miss_mm(cell, args.seed, figure)
        if miss is not None:  # stated against delivered: the twin's truth, which no fit computed
            console.print(
                f"against the twin's truth: the model puts the TCP at the test pose {um(miss, 1)} µm from "
                f"where the twin has it; stated ±{um(figure['sigma_mm'], 1)} µm (1σ 3-D), planned "
                f"{um(plan_doc['rho0_mm'], 1)} µm"
            )
    return 0
