"""`trackcal report`: the HTML report of a session, or of a table, a model, a plan and a verdict."""

from __future__ import annotations

from pathlib import Path

from calib.cell import load_cell
from calib.files import read_json
from calib.model import load_model
from calib.table import read_table
from campaign.errors import InputError, UsageError
from campaign.report.html import write_report


def _read_json(path: str | None) -> dict | None:
    return None if path is None else read_json(path, InputError)


def _session_defaults(args) -> None:
    """`trackcal report SESSION`: the session's table, model, plan, verdict, cell and a report/ folder."""
    if args.session is None:
        if not (args.table and args.model and args.out):
            raise UsageError("give a SESSION directory, or --table, --model and --out")
        return
    d = Path(args.session)
    if not (d / "session.sqlite").exists():
        raise InputError(f"{d}: not a trackcal session")
    if not (d / "model.json").exists():
        raise InputError(f"{d}: no model.json yet (the campaign has not been analysed: trackcal resume {d})")
    args.table = args.table or str(d / "table.csv")
    args.model = args.model or str(d / "model.json")
    args.plan = args.plan or str(d / "plan.json")
    args.verdict = args.verdict or (str(d / "verdict.json") if (d / "verdict.json").exists() else None)
    args.cell = args.cell or str(d / "config" / "cell.yaml")
    args.out = args.out or str(d / "report")


def cmd_report(args) -> int:
    _session_defaults(args)
    model_doc = load_model(args.model).doc
    cell_ref = args.cell or model_doc.get("cell")
    if not cell_ref:
        raise InputError(f"{args.model}: the model names no cell: give --cell NAME")
    cell = load_cell(cell_ref)
    table = read_table(args.table, chain=cell.chain)
    images = []
    if args.plots:
        d = Path(args.plots)
        if not d.is_dir():
            raise UsageError(f"--plots {args.plots}: not a directory")
        images = sorted(d.glob("*.png"))
    title = args.title or f"trackcal calibration report: {cell.name}, {Path(args.table).name}"
    path = write_report(Path(args.out), cell, table, model_doc, _read_json(args.plan),
                        _read_json(args.verdict), title, extra_images=images)  # fmt: skip
    print(f"report written to {path}")
    return 0
