"""`trackcal demo`: plan, simulated campaign, identification and diagnosis on embedded defaults (its own module:
it drives a campaign, whose imports the analysis commands do not need)."""

from __future__ import annotations

import shutil
from pathlib import Path

from trackcal.calib.identify.noise import DEFAULT_WEIGHTING
from trackcal.calib.io.table import read_table
from trackcal.calib.model.cell import load_cell
from trackcal.campaign.analysis import analyse_session, choose_params, run_identify, twin_truth
from trackcal.campaign.cli.analysis import print_identification, um
from trackcal.campaign.cli.campaign import drive
from trackcal.campaign.cli.console import console
from trackcal.campaign.jobs.campaign import new_session
from trackcal.campaign.output import write_json
from trackcal.campaign.planning import PlanOptions, build_design, search_doc


def cmd_demo(args) -> int:
    """Plan + simulated campaign (2 stations, 3 points, operator prompts) + identification + diagnosis."""
    out = Path(args.out)
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    cell = load_cell(args.cell)
    console.rule(f"trackcal demo: cell {cell.name} on the digital twin")
    options = PlanOptions(configs=6, repeat=3, seed=args.seed)
    with console.status("planning: test-pose optimal poses (paper section 6)"):
        plan = search_doc(build_design(cell, options), options)
    write_json(str(out / "plan.json"), plan)
    console.print(f"plan: 6 configurations x 3, rho0 at the test pose {um(plan['rho0_mm'], 2)} µm "
                  f"({out / 'plan.json'})")  # fmt: skip
    store, _ = new_session(out / "session", args.cell, plan, "sim", args.seed)
    drive(store)
    analyse_session(store, console.print)
    table = read_table(out / "session" / "table.csv", chain=cell.chain)
    print_identification(run_identify(cell, table, choose_params(cell, None), DEFAULT_WEIGHTING),
                         twin_truth(cell, args.seed))  # fmt: skip
    return 0
