"""The end of a campaign, analysed once: the table exported from the session's events, identification, diagnosis,
the model and verdict documents, all in one CampaignAnalysis in memory, written once through the session's
SessionFiles and handed to the report. And the one reader of a campaign's files (`trackcal report`), which builds
the same CampaignAnalysis from them, refusing files of different campaigns, so both give the same page."""

from __future__ import annotations

import hashlib
import json
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from trackcal.calib.diagnose import Diagnosis, diagnose
from trackcal.calib.diagnose.extensions import CAUSES
from trackcal.calib.diagnose.noise_floor import Floor
from trackcal.calib.identify.noise import DEFAULT_WEIGHTING, TrackerNoise, model_noise
from trackcal.calib.identify.solver import Identification
from trackcal.calib.identify.units import read_measured
from trackcal.calib.io import fields
from trackcal.calib.io.files import dumps_json, read_json, write_bytes, write_text
from trackcal.calib.io.table import MeasurementTable, as_written, table_csv
from trackcal.calib.model.cell import Cell, load_cell, resolve
from trackcal.calib.model.params import param_by_name
from trackcal.calib.model_file import load_model
from trackcal.calib.model_trust import sealed, unusable_why
from trackcal.calib.tcp_figure import figure_at_test_pose
from trackcal.campaign.errors import InputError, OptionError
from trackcal.campaign.jobs.campaign import Campaign
from trackcal.campaign.jobs.diagnose import diagnosis_threads, verdict_doc
from trackcal.campaign.jobs.identify import choose_params, fit_model, identify_outcome, model_doc, sha256_of
from trackcal.campaign.report.analysis import CampaignAnalysis, Provenance
from trackcal.campaign.report.html import write_report
from trackcal.campaign.report.residuals import residuals_of
from trackcal.campaign.report.tcp import NOT_DERIVED, NotDerived, TcpDifference, tcp_difference
from trackcal.campaign.session.session import (
    SessionFiles,
    campaign_warnings,
    export_table,
    session_cell,
    session_plan,
)
from trackcal.campaign.session.store import DB_NAME, SessionStore


class NotAnalysedError(InputError):
    """A session whose campaign has not been analysed yet: `missing` is the file it lacks."""

    def __init__(self, directory: Path, missing: str) -> None:
        super().__init__(f"{directory}: no {missing} yet (the campaign has not been analysed)")
        self.directory, self.missing = directory, missing


def written(path: Path, doc: dict) -> dict:
    """Write `doc` as strict JSON to `path`; returns the document as its file holds it (what a reader gets)."""
    text = dumps_json(doc)
    write_text(path, text, InputError)
    return json.loads(text)


def analyse_session(store: SessionStore, campaign: Campaign | None = None) -> CampaignAnalysis:
    """End of a campaign: export, identification, diagnosis and report, into the session directory; `campaign`: the
    one just run (its cell and plan), else the session's stored one. When the diagnosis names a cause, the model is
    the one extended by it and the geometric model is written beside it. Each result is derived once (the geometric
    fit feeds the diagnosis, whose noise floor the models' documents and the report use). An IdentificationError (too
    few measurements yet) comes after the table is written."""
    files = SessionFiles(store.directory)
    cell, plan = (campaign.cell, campaign.plan) if campaign is not None else (session_cell(store), session_plan(store))
    exported = export_table(store, str(files.table))
    data = table_csv(exported).encode()
    write_bytes(files.table, data, InputError)
    table, digest = as_written(exported), hashlib.sha256(data).hexdigest()
    fitted = fit_model(cell, table, choose_params(cell, None), DEFAULT_WEIGHTING)
    with diagnosis_threads() as ex:
        dg = diagnose(
            cell.chain,
            table,
            cell.tool_points,
            fitted.params,
            fitted.result.noise,
            geometric=fitted.result,
            tracker=TrackerNoise.of(cell.tracker),
            executor=ex,
        )
    floor = diagnosis_floor(dg)
    outcome = identify_outcome(cell, table, fitted, digest, floor)
    tcp = tcp_difference(cell, dg.geometric, dg.extended)
    verdict = written(files.verdict, verdict_doc(cell, dg, digest, tcp))
    geometric = None
    if dg.extended is not None:  # fitted on the diagnosis' table (corrected by a joint map): its own floor then
        model = sealed(
            model_doc(
                cell, dg.table, dg.extended, outcome.before, dg.shift, digest, floor if dg.table is table else None
            )
        )
        geometric = written(files.geometric_model, sealed(outcome.doc))
    else:
        model = sealed(outcome.doc)
        files.geometric_model.unlink(missing_ok=True)
    analysis = analysed(
        cell,
        table,
        written(files.model, model),
        table_sha256=digest,
        plan=plan,
        verdict=verdict,
        diagnosis=dg,
        before=outcome.before,
        tcp=tcp,
        geometric_model=geometric,
        warnings=campaign_warnings(store),
        provenance=session_provenance(store, files, cell.name),
        files=files,
    )
    analysis.report = write_report(analysis, files.report)
    return analysis


def diagnosis_floor(d: Diagnosis) -> Floor:
    """The noise floor a diagnosis judged its table against (its figure and source: what the documents show)."""
    return Floor(d.noise_floor_mm, d.floor_source, None)


def analysed(
    cell: Cell,
    table: MeasurementTable,
    model: dict,
    *,
    table_sha256: str | None = None,
    plan: dict | None = None,
    verdict: dict | None = None,
    diagnosis: Diagnosis | None = None,
    before: Identification | None = None,
    tcp: TcpDifference | None | NotDerived = NOT_DERIVED,
    **more,
) -> CampaignAnalysis:
    """The CampaignAnalysis of one campaign's documents with every result the report shows, each derived once: what
    the caller holds (the nominal robot's "before" fit, the TCP difference) is used as it is, the noise floor is the
    diagnosis' when there is one, and the rest is derived here. `more`: CampaignAnalysis' other fields."""
    floor = diagnosis_floor(diagnosis) if diagnosis is not None else None
    residuals = residuals_of(cell, table, model, before, floor)
    if isinstance(tcp, NotDerived):
        tcp = tcp_difference(cell, diagnosis.geometric, diagnosis.extended) if verdict and diagnosis else None
    sigma = (model.get("test_pose") or {}).get("sigma_mm")  # calib.tcp_figure, as identify wrote it
    if sigma is None and diagnosis is not None and cell.test_pose is not None:  # an older model
        sigma = figure_at_test_pose(diagnosis.extended or diagnosis.geometric, cell.test_pose).sigma_mm
    return CampaignAnalysis(
        cell=cell,
        table=table,
        table_sha256=table_sha256,
        model=model,
        residuals=residuals,
        plan=plan,
        verdict=verdict,
        diagnosis=diagnosis,
        tcp=tcp,
        test_pose_sigma_mm=sigma,
        **more,
    )


def utc_text(t_wall: float) -> str:
    return datetime.fromtimestamp(t_wall, UTC).strftime("%Y-%m-%d %H:%M UTC")


def session_cell_ref(store: SessionStore, files: SessionFiles, cell_name: str) -> str:
    """How a command names the session's cell: its name when configs/cells/NAME.yaml exists, else the copy the
    session keeps (SESSION/config/cell.yaml)."""
    ref = store.meta().get("cell_ref") or cell_name
    return ref if resolve("cells", ref).is_file() else str(files.cell)


def session_provenance(store: SessionStore, files: SessionFiles, cell_name: str) -> Provenance:
    """The header facts of a session's report."""
    events = store.events()
    started = utc_text(events[0].t_wall) if events else None
    ended = utc_text(events[-1].t_wall) if events else None
    duration = events[-1].t_wall - events[0].t_wall if events else None
    notes = []
    if files.geometric_model.exists():
        why = unusable_why(read_json(files.geometric_model, InputError))
        notes.append(
            f"{files.model} is the model extended by the diagnosed cause; the purely geometric "
            f"model is {files.geometric_model}" + (f" (UNUSABLE: {why})." if why else ".")
        )
    return Provenance(
        session=str(files.directory),
        campaign_started=started,
        campaign_ended=ended,
        duration_s=duration,
        model_path=str(files.model),
        cell_ref=session_cell_ref(store, files, cell_name),
        notes=notes,
    )


# ------------------------------------------------------------------------------------ reading a campaign's files
def report_session(directory: Path, out: Path | None = None, extra_images: list[Path] | None = None) -> Path:
    """`trackcal report SESSION`: the report of a session from its own files, into `out` (default: the session's
    report folder): the page the end of the run wrote."""
    analysis = read_session(directory)
    return write_report(analysis, out or analysis.files.report, extra_images)


def report_files(
    table: str,
    model: str,
    out: str,
    plan: str | None = None,
    verdict: str | None = None,
    cell: str | None = None,
    extra_images: list[Path] | None = None,
) -> Path:
    """`trackcal report --table ... --model ...`: the report of a campaign's files, into `out`; the cell is the one
    the model names unless `cell` is given."""
    cell_ref = cell or read_json(model, InputError).get("cell")
    if not cell_ref:
        raise OptionError("{model}: the model names no cell: give {0} NAME", "cell", model=model)
    analysis = read_campaign(
        load_cell(cell_ref), table, model, plan, verdict, Provenance(model_path=model, cell_ref=cell_ref)
    )
    return write_report(analysis, Path(out), extra_images)


def read_session(directory: Path) -> CampaignAnalysis:
    """A session's analysis from its own files (what `trackcal run` wrote at its end)."""
    files = SessionFiles(Path(directory))
    d = files.directory
    if not (d / DB_NAME).exists():
        raise InputError(f"{d}: not a trackcal session")
    if not files.model.exists():
        raise NotAnalysedError(d, files.model.name)
    cell = load_cell(str(files.cell))
    store = SessionStore.open(d, readonly=True)
    try:
        prov, warnings = session_provenance(store, files, cell.name), campaign_warnings(store)
    finally:
        store.close()
    verdict = files.verdict if files.verdict.exists() else None
    analysis = read_campaign(cell, files.table, files.model, files.plan, verdict, prov)
    analysis.warnings, analysis.files = warnings, files
    if files.geometric_model.exists():
        analysis.geometric_model = load_model(files.geometric_model).doc
    return analysis


def read_campaign(cell: Cell, table_path, model_path, plan_path, verdict_path, prov: Provenance) -> CampaignAnalysis:
    """The analysis of one campaign from its files, checked to belong to one campaign; with a verdict, the table is
    diagnosed again with the model's parameters and weighting (deterministic: the diagnosis the verdict was made
    from, for the report's plots)."""
    model = load_model(model_path).doc  # validated with the model's own messages
    table = read_measured(table_path, cell.chain)
    plan, verdict = read_plan(plan_path, cell.chain.dof), read_verdict(verdict_path)
    digest = sha256_of(table.source)
    check_one_campaign(
        table, digest, cell, [(str(model_path), model), (str(verdict_path), verdict), (str(plan_path), plan)]
    )
    return analysed(
        cell,
        table,
        model,
        table_sha256=digest,
        plan=plan,
        verdict=verdict,
        diagnosis=diagnosis_of(cell, table, model) if verdict else None,
        provenance=prov,
    )


def diagnosis_of(cell: Cell, table: MeasurementTable, model: dict) -> Diagnosis:
    """The table diagnosed with the model's parameters and weighting."""
    params = [param_by_name(cell.chain, n) for n in model.get("covariance_order", [])]
    with diagnosis_threads() as ex:
        return diagnose(
            cell.chain,
            table,
            cell.tool_points,
            params,
            model_noise(model),
            tracker=TrackerNoise.of(cell.tracker),
            executor=ex,
        )


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
    if doc.get("poses_deg"):
        poses = fields.rows(doc["poses_deg"], f"{path}: poses_deg", InputError)
        if poses.shape[1] != dof:
            raise InputError(f"{path}: poses_deg: expected joint vectors of {dof} numbers, got {poses.shape[1]}")
    if doc.get("repeat") is not None:
        fields.integer(doc["repeat"], f"{path}: repeat", InputError)
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
    for part, keys in (
        ("geometric", ("rms_mm",)),
        ("extended", ("rms_mm",)),
        ("test_pose", ("tcp_difference_mm", "sigma_mm")),
        ("holdout", ("rms_geometric_mm", "rms_extended_mm")),
    ):
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


def check_one_campaign(table: MeasurementTable, digest: str, cell: Cell, inputs: list[tuple[str, dict | None]]) -> None:
    """Refuse inputs of different campaigns: model and verdict name the sha256 of the table they were made from
    (`digest`: of the table as read) and their cell, and every configuration of the table must be a pose of the
    plan. `inputs`: (path, doc) of the model, verdict and plan (doc None when not given)."""
    for path, doc in inputs:
        if not doc:
            continue
        made_from = doc.get("table_sha256")
        if made_from and made_from != digest:
            raise InputError(
                f"{path}: made from another table (sha256 {made_from[:12]}), not from {table.source} "
                f"({digest[:12]}): give the files of one campaign"
            )
        if doc.get("cell") not in (None, cell.name):
            raise InputError(f"{path}: made for cell {doc['cell']}, not for {cell.name}")
        if "poses_deg" in doc:
            poses = fields.rows(doc["poses_deg"], f"{path}: poses_deg", InputError)
            if poses.shape[1] != table.q_deg.shape[1]:
                raise InputError(f"{path}: its poses have not the table's {table.q_deg.shape[1]} joints")
            gap = np.abs(table.q_deg[:, None, :] - poses[None]).max(axis=2).min(axis=1)
            far = np.flatnonzero(gap > PLAN_MATCH_DEG)
            if len(far):
                k = far[0]
                raise InputError(
                    f"{path}: {table.source} seq {table.seq[k]} (pose {table.pose[k]}) is no pose of this "
                    "plan: give the files of one campaign"
                )
