"""`trackcal report`: the HTML report of a session, or of a table, a model, a plan and a verdict; and the console
lines of a campaign's end-of-run analysis (`print_analysis`)."""

from __future__ import annotations

from pathlib import Path

from rich.text import Text

from trackcal.calib.identify.solver import IdentificationError
from trackcal.calib.model_trust import unusable_why
from trackcal.campaign.cli.console import console, labelled
from trackcal.campaign.cli.session import incomplete_note
from trackcal.campaign.errors import InputError, UsageError
from trackcal.campaign.jobs.campaign import Campaign
from trackcal.campaign.jobs.end_of_run import NotAnalysedError, analyse_session, report_files, report_session
from trackcal.campaign.report.analysis import CampaignAnalysis
from trackcal.campaign.report.html import summarise_warnings
from trackcal.campaign.session.store import SessionStore


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
        store = SessionStore.open(args.session, readonly=True)
        incomplete_note(store)
        store.close()
        try:
            path = report_session(Path(args.session), Path(args.out) if args.out else None, images)
        except NotAnalysedError as exc:
            raise InputError(
                f"{exc.directory}: no {exc.missing} yet (the campaign has not been analysed: "
                f"trackcal resume {exc.directory} --analyse)"
            ) from None
    else:
        if not (args.table and args.model and args.out):
            raise UsageError("give a SESSION directory, or --table, --model and --out")
        path = report_files(args.table, args.model, args.out, args.plan, args.verdict, args.cell, images)
    print(f"report written to {path}")
    return 0


def print_analysis(analysis: CampaignAnalysis) -> None:
    """The end of a campaign on the console: where the table, model, verdict and report went, the fit, the
    diagnosis, and the campaign's warnings."""
    files, model, cause = analysis.files, analysis.model, analysis.verdict["cause"]
    if analysis.geometric_model is not None:
        what = f"model {files.model} extended by {cause} (the geometric one: {files.geometric_model})"
    else:
        what = f"model {files.model} (geometric)"
    console.print(
        f"{len(analysis.table)} measurements -> {files.table}; {what}: coordinate RMS "
        f"{model['residuals']['after']['coord_rms_mm'] * 1000:.1f} µm, fit {model['fit']}; diagnosis: "
        f"{cause} ({files.verdict}); report {analysis.report}"
    )
    for path, doc in ((files.model, model), (files.geometric_model, analysis.geometric_model)):
        why = None if doc is None else unusable_why(doc)
        if why:
            console.print(
                f"warning: {path} is UNUSABLE: {why} (compensate refuses it without --accept-poor)",
                markup=False,
                highlight=False,
            )
    warnings = analysis.warnings
    if warnings:
        console.print(
            Text.assemble(
                (f"{len(warnings)} campaign warning(s)", "yellow"), ", in short (each as raised: in the report):"
            )
        )
        for line in summarise_warnings(warnings, len(analysis.table)):
            console.print(f"  {line}")


def analyse_and_print(store: SessionStore, campaign: Campaign | None = None) -> CampaignAnalysis | None:
    """The end-of-run analysis of a session (campaign.jobs.end_of_run.analyse_session; `campaign`: the one just run)
    on the console; None, with one line saying why, when the session cannot be identified yet."""
    try:
        analysis = analyse_session(store, campaign)
    except IdentificationError as exc:
        console.print(labelled("identification not possible yet", "yellow", str(exc)))
        return None
    print_analysis(analysis)
    return analysis
