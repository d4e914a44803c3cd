"""The console lines of a campaign's end-of-run analysis (campaign.jobs.end_of_run): what `trackcal run`, `resume`
and `demo` print once the campaign is complete. Its own module: it imports the analysis (identification, diagnosis:
scipy), which `run --no-analysis`, `replay`, `report` and `export` do not need at start-up."""

from __future__ import annotations

from rich.text import Text

from trackcal.calib.identify.solver import IdentificationError
from trackcal.calib.model_trust import unusable_why
from trackcal.campaign.cli.console import console, labelled
from trackcal.campaign.jobs.campaign import Campaign
from trackcal.campaign.jobs.end_of_run import analyse_session
from trackcal.campaign.report.analysis import CampaignAnalysis
from trackcal.campaign.report.html import summarise_warnings
from trackcal.campaign.session.store import SessionStore


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
