"""What a report renders: one campaign's analysis in memory (CampaignAnalysis), made at the end of a run
(campaign.jobs.end_of_run.analyse_session) or read back from its files (`trackcal report`), and where it comes from
(Provenance). It holds every derived result the report shows (the residuals with their "before" fit and noise floor,
the diagnosis, the TCP difference and the test-pose figure), each derived once (campaign.jobs.end_of_run.analysed):
the report renders them and computes nothing."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from trackcal.calib.diagnose import Diagnosis
from trackcal.calib.io.table import MeasurementTable
from trackcal.calib.model.cell import Cell
from trackcal.campaign.report.residuals import Residuals
from trackcal.campaign.report.tcp import TcpDifference
from trackcal.campaign.session.session import SessionFiles


@dataclass
class Provenance:
    """Where the report's inputs come from: the header and the "what next" section."""

    session: str | None = None  # the session directory, None for a report from files
    campaign_started: str | None = None  # UTC, of the first recorded event
    campaign_ended: str | None = None  # UTC, of the last recorded event
    duration_s: float | None = None  # wall-clock seconds from the first to the last recorded event
    model_path: str = "model.json"
    cell_ref: str = ""
    notes: list[str] = field(default_factory=list)  # e.g. which file is the extended and which the geometric model


@dataclass
class CampaignAnalysis:
    """One campaign analysed: the table and its sha256, the model to use (extended by the diagnosed cause when there
    is one) and the geometric one, the verdict, the plan, the cell, the campaign's warnings and the provenance; and
    what was derived from them: the residuals, the diagnosis, the TCP difference and the test-pose figure."""

    cell: Cell
    table: MeasurementTable
    table_sha256: str | None
    model: dict  # model.json
    residuals: Residuals  # of `model` on `table`, the nominal robot's, and the noise floor
    geometric_model: dict | None = None  # the purely geometric model when `model` is extended by a cause
    verdict: dict | None = None  # verdict.json
    plan: dict | None = None  # plan.json
    diagnosis: Diagnosis | None = None  # what the verdict was made from (the report's diagnosis plots)
    tcp: TcpDifference | None = None  # the geometric and the extended model's TCPs at the test pose (with a verdict)
    test_pose_sigma_mm: float | None = None  # how well the campaign determines the model's TCP there (1-sigma 3-D)
    warnings: list[str] | None = None  # the campaign's warnings in order (None: no session, not known)
    provenance: Provenance = field(default_factory=Provenance)
    files: SessionFiles | None = None  # a session's: where the analysis is written
    report: Path | None = None  # report.html, once written

    @property
    def geometric(self) -> dict:
        """The geometric model's document (`model` itself when it is not extended)."""
        return self.geometric_model if self.geometric_model is not None else self.model
