"""The trackcal command line. Every user mistake ends in one clear line and exit code 2."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
from rich.table import Table

from calib.cell import CellError, load_cell
from calib.chain import ChainError
from calib.identify import IdentificationError
from calib.model import ModelError, load_model
from calib.poses import random_poses
from calib.table import TableError, read_table, write_table

from .console import console
from .jobs import IdentifyOutcome, UsageError, choose_params, parse_effects, run_identify, run_predict, summary_of

USER_ERRORS = (UsageError, TableError, CellError, ChainError, IdentificationError, ModelError)  # one line, exit 2


def _write_json(path: str, doc: dict) -> None:
    try:
        Path(path).write_text(json.dumps(doc, indent=2) + "\n")
    except OSError as exc:
        raise UsageError(f"{path}: cannot write ({exc.strerror})") from None


def print_identification(outcome: IdentifyOutcome, truth: dict[str, float] | None = None) -> None:
    doc = outcome.doc
    t = Table(title=f"Identified parameters ({doc['n_measurements']} measurements, {doc['iterations']} iterations)")
    for col in ("parameter", "unit", "nominal", "deviation", "95 % CI"):
        t.add_column(col, justify="right")
    if truth is not None:
        t.add_column("truth (twin)", justify="right")
        t.add_column("inside CI", justify="center")
    for name, p in doc["parameters"].items():
        row = [name, p["unit"], f"{p['nominal']:.1f}", f"{p['value']:+.4f}", f"±{p['ci95']:.4f}"]
        if truth is not None:
            tv = truth.get(name, 0.0)
            row += [f"{tv:+.4f}", "yes" if abs(tv - p["value"]) <= p["ci95"] else "NO"]
        t.add_row(*row)
    console.print(t)
    r = doc["residuals"]
    rt = Table(title="Residuals (paper Table 9 style), mm")
    for col in ("", "before", "after", "factor"):
        rt.add_column(col, justify="right")
    for key, label in (("coord_max_mm", "coordinate max"), ("coord_rms_mm", "coordinate RMS"),
                       ("dist_max_mm", "distance max"), ("dist_rms_mm", "distance RMS")):
        b, a = r["before"][key], r["after"][key]
        rt.add_row(label, f"{b:.4f}", f"{a:.4f}", f"{b / a:.1f}" if a > 0 else "-")
    console.print(rt)
    if "significance_mm" in doc:
        sig = sorted(doc["significance_mm"].items(), key=lambda kv: -kv[1])
        console.print(
            "TCP error at the test pose when one parameter is left at nominal (section 7.3): "
            + ", ".join(f"{k} {v * 1000:.0f} um" for k, v in sig)
        )
    for sid, s in doc["stations"].items():
        ci = s["ci95_translation_mm"]
        console.print(f"station {sid}: translation ±({ci[0]:.3f}, {ci[1]:.3f}, {ci[2]:.3f}) mm (95 %)")


def cmd_identify(args) -> int:
    cell = load_cell(args.cell)
    table = read_table(args.data, n_joints=cell.chain.dof)
    outcome = run_identify(cell, table, choose_params(cell, args.params), args.weighting, args.extend)
    print_identification(outcome)
    _write_json(args.out, outcome.doc)
    if args.json:
        _write_json(args.json, summary_of(outcome))
    console.print(f"model written to {args.out}")
    return 0


def cmd_predict(args) -> int:
    model = load_model(args.model)
    rows = read_table(args.rows, require_xyz=False)
    pred = run_predict(model, rows)
    try:
        write_table(pred, args.out)
    except OSError as exc:
        raise UsageError(f"{args.out}: cannot write ({exc.strerror})") from None
    console.print(f"{len(pred)} predictions written to {args.out}")
    return 0


def simulate(cell_ref: str, n_poses: int, seed: int, repeat: int = 1, noise_free: bool = False,
             effects: dict[str, float] | None = None):  # fmt: skip
    from mocks.synth import simulate_campaign
    from mocks.twin import Twin

    cell = load_cell(cell_ref)
    if n_poses < 1 or repeat < 1:
        raise UsageError("--poses and --repeat must be at least 1")
    try:
        poses = np.degrees(random_poses(cell, n_poses, np.random.default_rng(seed)))
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    twin = Twin(cell, seed=seed, effects=effects or {})
    return cell, twin, simulate_campaign(twin, poses, repeat=repeat, noise_free=noise_free)


def cmd_simulate(args) -> int:
    _, _, table = simulate(args.cell, args.poses, args.seed, args.repeat, args.noise_free, parse_effects(args.effect))
    write_table(table, args.out)
    console.print(f"{len(table)} simulated measurements written to {args.out}")
    return 0


def cmd_demo(args) -> int:
    """Plan + simulated campaign (2 stations, 3 points, operator prompts) + identification + diagnosis."""
    import shutil
    from types import SimpleNamespace

    from mocks.twin import Twin

    from .planning import build_design, search_doc
    from .run_cmd import analyse, drive
    from .session import create_session

    out = Path(args.out)
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    cell = load_cell(args.cell)
    console.rule(f"trackcal demo: cell {cell.name} on the digital twin")
    plan_args = SimpleNamespace(params=None, test_pose=None, sigma_mm=None, noise="iid", no_visibility=False,
                                configs=6, repeat=3, criterion="rho0", starts=1000, refined=16, seed=args.seed,
                                scheduler=None)  # fmt: skip
    with console.status("planning: test-pose optimal poses (paper section 6)"):
        plan = search_doc(build_design(cell, plan_args), plan_args)
    _write_json(str(out / "plan.json"), plan)
    console.print(f"plan: 6 configurations x 3, rho0 at the test pose {plan['rho0_mm'] * 1000:.2f} um "
                  f"({out / 'plan.json'})")  # fmt: skip
    store = create_session(out / "session", args.cell, plan, "sim", args.seed)
    drive(store)
    analyse(store)
    twin = Twin(cell, seed=args.seed)
    truth = {p.name: (v if p.is_length else float(np.degrees(v))) for p, v in zip(twin.params, twin.true_dev,
                                                                                  strict=True)}  # fmt: skip
    table = read_table(out / "session" / "table.csv", n_joints=cell.chain.dof)
    print_identification(run_identify(cell, table, choose_params(cell, None), "tracker"), truth)
    return 0


def cmd_plan(args) -> int:
    from rich.progress import Progress

    from .planning import build_design, evaluate_doc, read_plan_csv, search_doc, write_plan_csv

    cell = load_cell(args.cell)
    design = build_design(cell, args)
    if args.evaluate:
        doc = evaluate_doc(design, read_plan_csv(args.evaluate, cell.chain.dof))
        if doc["infeasible_rows"]:
            console.print(f"warning: rows {doc['infeasible_rows']} leave the cell box or are not visible")
    else:
        with Progress(console=console, transient=True) as bar:
            task = bar.add_task(f"searching {args.configs} configurations ({args.criterion})", total=args.refined)
            doc = search_doc(design, args, lambda done, total: bar.update(task, completed=done, total=total))
        if args.csv:
            write_plan_csv(Path(args.csv), np.radians(np.array(doc["poses_deg"])), doc["repeat"])
        for q in doc["poses_deg"]:
            console.print("  " + "  ".join(f"{v:8.2f}" for v in q))
    console.print(f"rho0 at the test pose: {doc['rho0_mm'] * 1000:.2f} um  (parameters: {' '.join(doc['params'])})")
    _write_json(args.json, doc)
    return 0


def cmd_diagnose(args) -> int:
    from calib.diagnose import diagnose
    from calib.noise import TrackerNoise

    from .diagnose_report import plots, verdict_doc
    from .jobs import model_doc

    cell = load_cell(args.cell)
    table = read_table(args.data, n_joints=cell.chain.dof)
    params = choose_params(cell, args.params)
    noise = TrackerNoise() if args.weighting == "tracker" else None
    with console.status("fitting the geometric model and every candidate cause (cross-validated by pose)"):
        d = diagnose(cell.chain, table, cell.tool_points, params, noise, folds=args.folds, seed=args.seed)
    doc = verdict_doc(cell, d)
    t = Table(title=f"Diagnosis: {d.cause}")
    for col in ("candidate", "params", "held-out RMS um", "fit RMS um", "F-test p", "dBIC", "significant"):
        t.add_column(col, justify="right")
    t.add_row("geometric", "-", f"{d.holdout_geometric_mm * 1000:.1f}", f"{doc['geometric']['rms_mm'] * 1000:.1f}",
              "-", "-", "-")  # fmt: skip
    for c in doc["candidates"]:
        t.add_row(c["cause"], str(c["n_params"]), f"{c['holdout_rms_mm'] * 1000:.1f}", f"{c['rms_mm'] * 1000:.1f}",
                  f"{c['f_pvalue']:.2g}", f"{c['delta_bic']:.0f}", "yes" if c["significant"] else "no")  # fmt: skip
    console.print(t)
    console.print(f"noise floor {d.noise_floor_mm * 1000:.1f} um ({d.floor_source}); held-out RMS "
                  f"{d.holdout_geometric_mm * 1000:.1f} -> {d.holdout_extended_mm * 1000:.1f} um")  # fmt: skip
    if args.plots:
        for p in plots(cell, d, Path(args.plots)):
            console.print(f"plot written to {p}")
    _write_json(args.json, doc)
    if args.out:
        _write_json(args.out, model_doc(cell, d.table, d.extended or d.geometric, d.geometric, d.shift))
    console.print(f"verdict written to {args.json}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="trackcal", description="Robot calibration with a laser tracker.")
    sub = ap.add_subparsers(dest="command", required=True)

    p = sub.add_parser("identify", help="identify robot parameters, stations and points from a measurement table")
    p.add_argument("data", help="measurement table (CSV, see DESIGN.md)")
    p.add_argument("--cell", required=True, help="cell name (configs/cells/NAME.yaml) or path")
    p.add_argument("--params", help="comma-separated parameter names (default: the irreducible set)")
    p.add_argument("--weighting", choices=("iid", "tracker"), default="iid",
                   help="i.i.d. least squares, or the AT901 radial/transverse noise model")
    p.add_argument("--extend", default="none",
                   help="none (purely geometric), auto (diagnose's choice) or a cause: joint_compliance, "
                        "backlash, encoder_scale, cyclic_error, thermal_drift, station_shift")  # fmt: skip
    p.add_argument("--out", required=True, help="model.json to write")
    p.add_argument("--json", help="summary JSON to write")
    p.set_defaults(func=cmd_identify)

    p = sub.add_parser("diagnose", help="what the geometric model gets wrong: the physical cause and the gain")
    p.add_argument("data", help="measurement table (CSV, see DESIGN.md)")
    p.add_argument("--cell", required=True)
    p.add_argument("--params", help="geometric parameters (default: the irreducible set)")
    p.add_argument("--weighting", choices=("iid", "tracker"), default="tracker")
    p.add_argument("--folds", type=int, default=5, help="cross-validation folds (whole poses held out)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--plots", help="directory for the residual plots")
    p.add_argument("--json", required=True, help="verdict JSON to write")
    p.add_argument("--out", help="model.json of the chosen model (usable by predict)")
    p.set_defaults(func=cmd_diagnose)

    p = sub.add_parser("predict", help="predict reflector positions with a model")
    p.add_argument("rows", help="CSV with the measurement-table columns (x,y,z optional, ignored)")
    p.add_argument("--model", required=True)
    p.add_argument("--out", required=True)
    p.set_defaults(func=cmd_predict)

    p = sub.add_parser("plan", help="optimal measurement poses for the cell's test pose (or evaluate a plan)")
    p.add_argument("--cell", required=True)
    p.add_argument("--test-pose", help="Q1,..,Qn in degrees (default: the cell's test pose)")
    p.add_argument("--configs", type=int, default=6, help="number of distinct configurations M")
    p.add_argument("--repeat", type=int, default=1, help="each configuration measured K times")
    p.add_argument("--sigma-mm", type=float, help="tracker noise, one coordinate (default 0.01)")
    p.add_argument("--noise", choices=("iid", "tracker"), default="iid", help="i.i.d. or the AT901 model")
    p.add_argument("--params", help="parameters targeted (default: the cell's plan_params)")
    p.add_argument("--criterion", default="rho0", help="rho0 (paper eq. 34) or D, A, E for comparison")
    p.add_argument("--no-visibility", action="store_true", help="ignore tracker stations and reflector cones")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--starts", type=int, default=1000, help="random feasible starting plans scored")
    p.add_argument("--refined", type=int, default=16, help="best starts refined by L-BFGS-B")
    p.add_argument("--scheduler", help="Dask scheduler address (default: local process pool)")
    p.add_argument("--evaluate", help="CSV of poses (q1_deg..qn_deg, one row per measurement) to evaluate")
    p.add_argument("--csv", help="also write the plan as a CSV of rows (repetitions included)")
    p.add_argument("--json", required=True)
    p.set_defaults(func=cmd_plan)

    p = sub.add_parser("simulate", help="simulate a campaign of random feasible poses on the digital twin")
    p.add_argument("--cell", default="kr270")
    p.add_argument("--poses", type=int, default=30)
    p.add_argument("--repeat", type=int, default=1)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--noise-free", action="store_true")
    p.add_argument("--effect", action="append", help="hidden effect NAME:MAGNITUDE_MM (repeatable)")
    p.add_argument("--out", required=True)
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("demo", help="plan, simulated campaign, identification, diagnosis on the embedded defaults")
    p.add_argument("--cell", default="kr270")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--out", default="out/demo")
    p.set_defaults(func=cmd_demo)
    from .compensate_cmd import register_compensate
    from .import_ipa import register_import_ipa
    from .mock_cmd import register_mock
    from .report import register_report
    from .run_cmd import register as register_campaign

    register_campaign(sub)
    register_mock(sub)
    register_compensate(sub)
    register_report(sub)
    register_import_ipa(sub)
    return ap


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except USER_ERRORS as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
