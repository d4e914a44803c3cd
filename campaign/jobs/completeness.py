"""How much of its plan a session holds: complete or not, measurements planned, stored and skipped (what `trackcal
check` says, what `export` and `report` of an incomplete session say first, and what ends a campaign with exit 3).
Light: the stored cell and plan and the events, no device and no analysis; after a run, the run's result says it
(`run_completeness`)."""

from __future__ import annotations

from dataclasses import dataclass

from trackcal.calib.model.cell import Cell
from trackcal.campaign.engine.engine import RunResult
from trackcal.campaign.engine.steps import StepKind, plan_steps
from trackcal.campaign.session.session import session_approached, session_cell, session_plan
from trackcal.campaign.session.store import SessionStore


@dataclass(frozen=True)
class Completeness:
    complete: bool  # the campaign reached its end (campaign_done)
    planned: int  # measure steps of the stored plan in the stored cell
    measured: int  # measurements stored
    skipped: int  # measure steps done without a measurement (the point not visible from the station there)
    max_skipped_share: float  # the cell's

    @property
    def missing(self) -> int:
        """Planned measurements neither stored nor skipped: not reached yet."""
        return self.planned - self.measured - self.skipped

    @property
    def failed(self) -> bool:
        """A complete campaign that measured nothing or skipped more than the cell allows (exit code 3)."""
        return self.complete and (self.measured == 0 or self.skipped > self.max_skipped_share * self.planned)

    def sentence(self) -> str:
        counts = f"{self.measured} of {self.planned} planned measurements stored, {self.skipped} skipped"
        if not self.complete:
            return f"campaign incomplete (it has not reached its end): {counts}, {self.missing} not measured yet"
        return f"campaign complete: {counts}"


def completeness(store: SessionStore) -> Completeness:
    """What a session holds of its plan, from its stored cell, plan and events (`check`, `export`, `report`, and
    `resume` of a campaign already complete)."""
    cell = session_cell(store)
    steps = plan_steps(cell, session_plan(store), session_approached(store))
    measure = {i for i, s in enumerate(steps) if s.kind == StepKind.MEASURE}
    measured = len(store.events("measurement"))
    skipped = max(0, len(measure & store.done_steps()) - measured)
    return Completeness(bool(store.events("campaign_done")), len(measure), measured, skipped, cell.max_skipped_share)


def run_completeness(result: RunResult, cell: Cell) -> Completeness:
    """What a session holds of its plan after a run, as the run's result counts it (the session's measurements,
    skips and planned measurements: nothing to load or build again)."""
    return Completeness(
        result.exit_status == "success", result.planned, result.measured, result.skipped, cell.max_skipped_share
    )
