"""`trackcal report`: the HTML report of a session, or of a table, a model, a plan and a verdict."""

from __future__ import annotations

from pathlib import Path

from calib import fields
from calib.cell import load_cell
from calib.files import read_json
from calib.model import load_model
from calib.table import read_table
from campaign.errors import InputError, UsageError
from campaign.report.html import write_report


def _numbers(doc: dict, keys: tuple[str, ...], where: str) -> None:
    """The report prints these keys as numbers: each must be a number or null (`where` ends in ": " or ".")."""
    for key in keys:
        if doc.get(key) is not None:
            fields.number(doc[key], f"{where}{key}", InputError)


def read_plan(path: str | None, dof: int) -> dict | None:
    """plan.json with the fields the report shows, each of the right type."""
    if path is None:
        return None
    doc = read_json(path, InputError)
    poses = doc.get("poses_deg") or []
    rows = len(fields.sequence(poses, f"{path}: poses_deg", InputError))
    fields.matrix(poses, f"{path}: poses_deg", InputError, (rows, dof))
    if doc.get("test_pose_deg") is not None:
        fields.vector(doc["test_pose_deg"], f"{path}: test_pose_deg", InputError, dof)
    for k, name in enumerate(fields.sequence(doc.get("params", []), f"{path}: params", InputError)):
        fields.text(name, f"{path}: params[{k}]", InputError)
    _numbers(doc, ("rho0_mm",), f"{path}: ")
    return doc


def read_verdict(path: str | None) -> dict | None:
    """verdict.json with the fields the report shows, each of the right type."""
    if path is None:
        return None
    doc = read_json(path, InputError)
    _numbers(doc, ("noise_floor_mm",), f"{path}: ")
    for part, keys in (("geometric", ("rms_mm",)), ("extended", ("rms_mm",)), ("test_pose", ("tcp_difference_mm",)),
                       ("holdout", ("rms_geometric_mm", "rms_extended_mm"))):  # fmt: skip
        _numbers(fields.mapping(doc.get(part, {}), f"{path}: {part}", InputError), keys, f"{path}: {part}.")
    for k, c in enumerate(fields.sequence(doc.get("candidates", []), f"{path}: candidates", InputError)):
        where = f"{path}: candidates[{k}]"
        keys = ("holdout_rms_mm", "rms_mm", "f_pvalue", "delta_bic")
        _numbers(fields.mapping(c, where, InputError), keys, f"{where}.")
    return doc


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
    path = write_report(Path(args.out), cell, table, model_doc, read_plan(args.plan, cell.chain.dof),
                        read_verdict(args.verdict), title, extra_images=images)  # fmt: skip
    print(f"report written to {path}")
    return 0
