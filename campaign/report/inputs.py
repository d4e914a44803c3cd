"""What goes into a report: the files of one campaign (refused when they are not) and, for a session, its header
facts and warnings. `report_session` is the one way a session's report is written: at the end of `trackcal run`
and by `trackcal report SESSION`, so both give the same page."""

from __future__ import annotations

import hashlib
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from trackcal.calib.diagnose.extensions import CAUSES
from trackcal.calib.io import fields
from trackcal.calib.io.files import read_json
from trackcal.calib.io.table import MeasurementTable, read_table
from trackcal.calib.model.cell import Cell, load_cell
from trackcal.calib.model_file import load_model
from trackcal.campaign.errors import InputError
from trackcal.campaign.report.html import Provenance, write_report
from trackcal.campaign.session.session import campaign_warnings
from trackcal.campaign.session.store import SessionStore

GEOMETRIC_MODEL = "model-geometric.json"  # beside a session's model.json when that one is extended by a cause


def sha256_of(path: str | Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def table_sha256(table: MeasurementTable) -> str | None:
    """The sha256 of the file a table was read from (read_table keeps its path as the source), which model.json
    and verdict.json name; None for a table that was not read from a file."""
    return sha256_of(table.source) if Path(table.source).is_file() else None


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


VERDICT_NAMES = (*CAUSES, "none", "unexplained")


def _cause(value, where: str) -> str:
    name = fields.text(value, where, InputError)
    if name not in VERDICT_NAMES:
        raise InputError(f"{where}: expected one of {', '.join(VERDICT_NAMES)}, got {name!r}")
    return name


def read_verdict(path: str | None) -> dict | None:
    """verdict.json with the fields the report shows, each of the right type; a cause names the numbers the
    report's sentence quotes (the geometric RMS, and the extended one for a named cause)."""
    if path is None:
        return None
    doc = read_json(path, InputError)
    _numbers(doc, ("noise_floor_mm",), f"{path}: ")
    for key in ("noise_note", "noise_floor_source"):
        if doc.get(key) is not None:
            fields.text(doc[key], f"{path}: {key}", InputError)
    for part, keys in (("geometric", ("rms_mm",)), ("extended", ("rms_mm",)), ("test_pose", ("tcp_difference_mm",)),
                       ("holdout", ("rms_geometric_mm", "rms_extended_mm"))):  # fmt: skip
        _numbers(fields.mapping(doc.get(part, {}), f"{path}: {part}", InputError), keys, f"{path}: {part}.")
    if doc.get("holdout", {}).get("note") is not None:
        fields.text(doc["holdout"]["note"], f"{path}: holdout.note", InputError)
    cause = doc.get("cause")
    if cause is not None:
        _cause(cause, f"{path}: cause")
        needs = () if cause == "none" else ("geometric",) if cause == "unexplained" else ("geometric", "extended")
        for part in needs:
            if doc.get(part, {}).get("rms_mm") is None:
                raise InputError(f"{path}: cause {cause} without {part}.rms_mm")
    lists = (("causes", ("gain_mm",)), ("candidates", ("holdout_rms_mm", "rms_mm", "f_pvalue", "delta_bic")))
    for key, numbers in lists:
        for k, c in enumerate(fields.sequence(doc.get(key, []), f"{path}: {key}", InputError)):
            where = f"{path}: {key}[{k}]"
            _numbers(fields.mapping(c, where, InputError), numbers, f"{where}.")
            if c.get("cause") is not None:
                _cause(c["cause"], f"{where}.cause")
            if c.get("n_params") is not None:
                fields.integer(c["n_params"], f"{where}.n_params", InputError)
    return doc


# the campaign commands the plan's poses rounded to 1e-4 deg and the robot settles within 0.001 deg
# (engine Settings.settle_tolerance_deg): a table row further than 10x that from every plan pose was not
# measured with this plan
PLAN_MATCH_DEG = 0.01


def check_one_campaign(table: MeasurementTable, cell: Cell, inputs: list[tuple[str, dict | None]]) -> None:
    """Refuse inputs of different campaigns: model and verdict name the sha256 of the table they were made from
    and their cell, and every configuration of the table must be a pose of the plan. `inputs`: (path, doc) of the
    model, verdict and plan (doc None when not given)."""
    digest = sha256_of(table.source)  # the table as read (read_table keeps its path as the source)
    for path, doc in inputs:
        if not doc:
            continue
        made_from = doc.get("table_sha256")
        if made_from and made_from != digest:
            raise InputError(f"{path}: made from another table (sha256 {made_from[:12]}), not from {table.source} "
                             f"({digest[:12]}): give the files of one campaign")  # fmt: skip
        if doc.get("cell") not in (None, cell.name):
            raise InputError(f"{path}: made for cell {doc['cell']}, not for {cell.name}")
        if "poses_deg" in doc:
            poses = np.asarray(doc["poses_deg"], dtype=float)
            if poses.ndim != 2 or poses.shape[1] != table.q_deg.shape[1]:
                raise InputError(f"{path}: its poses have not the table's {table.q_deg.shape[1]} joints")
            gap = np.abs(table.q_deg[:, None, :] - poses[None]).max(axis=2).min(axis=1)
            far = np.flatnonzero(gap > PLAN_MATCH_DEG)
            if len(far):
                k = far[0]
                raise InputError(f"{path}: {table.source} seq {table.seq[k]} (pose {table.pose[k]}) is no pose of this "
                                 "plan: give the files of one campaign")  # fmt: skip


def session_provenance(directory: Path) -> Provenance:
    """The header facts and the warnings of a session (read-only)."""
    store = SessionStore.open(directory, readonly=True)
    try:
        meta, first = store.meta(), store.events()[:1]
        warnings = campaign_warnings(store)
    finally:
        store.close()
    started = datetime.fromtimestamp(first[0].t_wall, UTC).strftime("%Y-%m-%d %H:%M UTC") if first else None
    notes = []
    if (directory / GEOMETRIC_MODEL).exists():
        notes.append(f"{directory / 'model.json'} is the model extended by the diagnosed cause; the purely geometric "
                     f"model is {directory / GEOMETRIC_MODEL}.")  # fmt: skip
    return Provenance(session=str(directory), campaign_started=started, model_path=str(directory / "model.json"),
                      cell_ref=meta.get("cell_ref", ""), warnings=warnings, notes=notes)  # fmt: skip


def report_session(directory: Path, out: Path | None = None, diagnosis=None, extra_images=None) -> Path:
    """The report of a session from its own files: what `trackcal run` writes at the end and `trackcal report
    SESSION` writes again (the same page: one function)."""
    d = Path(directory)
    if not (d / "model.json").exists():
        raise InputError(f"{d}: no model.json yet (the campaign has not been analysed: trackcal resume {d} --analyse)")
    prov = session_provenance(d)
    cell = load_cell(str(d / "config" / "cell.yaml"))
    verdict = d / "verdict.json" if (d / "verdict.json").exists() else None
    return report_files(cell, d / "table.csv", d / "model.json", d / "plan.json", verdict, out or d / "report", prov,
                        extra_images, diagnosis)


def report_files(cell: Cell, table_path, model_path, plan_path, verdict_path, out, prov: Provenance,
                 extra_images=None, diagnosis=None) -> Path:  # fmt: skip
    """Check that the files belong to one campaign, then write the report into `out`."""
    model_doc = load_model(model_path).doc  # validated with the model's own messages
    table = read_table(table_path, chain=cell.chain)
    plan_doc, verdict_doc = read_plan(plan_path, cell.chain.dof), read_verdict(verdict_path)
    prov.table_sha256 = sha256_of(table.source)
    check_one_campaign(table, cell, [(str(model_path), model_doc), (str(verdict_path), verdict_doc),
                                     (str(plan_path), plan_doc)])  # fmt: skip
    return write_report(Path(out), cell, table, model_doc, plan_doc, verdict_doc, prov, extra_images, diagnosis)
