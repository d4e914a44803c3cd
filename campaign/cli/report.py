"""`trackcal report`: the HTML report of a session, or of a table, a model, a plan and a verdict."""

from __future__ import annotations

from pathlib import Path

from trackcal.calib.io.files import read_json
from trackcal.calib.model.cell import load_cell
from trackcal.campaign.errors import InputError, UsageError
from trackcal.campaign.report.html import Provenance
from trackcal.campaign.report.inputs import report_files, report_session


def cmd_report(args) -> int:
    images = []
    if args.plots:
        d = Path(args.plots)
        if not d.is_dir():
            raise UsageError(f"--plots {args.plots}: not a directory")
        images = sorted(d.glob("*.png"))
    if args.session is not None:
        if args.table or args.model or args.plan or args.verdict or args.cell:
            raise UsageError("give a SESSION directory or --table, --model, --plan, --verdict, --cell; not both")
        if not (Path(args.session) / "session.sqlite").exists():
            raise InputError(f"{args.session}: not a trackcal session")
        path = report_session(Path(args.session), Path(args.out) if args.out else None, extra_images=images)
    else:
        if not (args.table and args.model and args.out):
            raise UsageError("give a SESSION directory, or --table, --model and --out")
        cell_ref = args.cell or read_json(args.model, InputError).get("cell")
        if not cell_ref:
            raise InputError(f"{args.model}: the model names no cell: give --cell NAME")
        prov = Provenance(model_path=args.model, cell_ref=cell_ref)
        path = report_files(load_cell(cell_ref), args.table, args.model, args.plan, args.verdict, args.out, prov,
                            images)  # fmt: skip
    print(f"report written to {path}")
    return 0
