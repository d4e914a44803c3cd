"""`trackcal run | resume | replay`: campaigns on the shop floor or on the simulated cell."""

from __future__ import annotations

import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from pathlib import Path

from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

from trackcal.calib.errors import CalibError
from trackcal.calib.io.files import read_json
from trackcal.campaign.cells.checks import DOOR_OPEN, ESTOP_PRESSED, PLC_SILENT
from trackcal.campaign.cli.console import ConsoleOperator, console, labelled
from trackcal.campaign.cli.report import analyse_and_print
from trackcal.campaign.engine.engine import TARGET_MISMATCH, Document, RunResult
from trackcal.campaign.engine.recording import ReplayDivergence
from trackcal.campaign.errors import CampaignError, InputError, UsageError
from trackcal.campaign.jobs.campaign import (
    Campaign,
    HardwareOptions,
    OperatorConsole,
    SimOptions,
    replay,
    resume,
    run_new,
    stored_campaign,
)
from trackcal.campaign.jobs.completeness import Completeness, completeness, run_completeness
from trackcal.campaign.jobs.simulate import parse_effects
from trackcal.campaign.session.session import changed_copies, write_export
from trackcal.campaign.session.store import SessionStore
from trackcal.campaign.web.server import DEFAULT_PORT, LOOPBACK, WebPage
from trackcal.drivers.kuka.client import CHANNELS_DISAGREE, RSI_STALE


class ConsoleProgress:
    """A subscriber of the engine: the campaign's bar (planned measurements done, measured or skipped; how many
    skipped; the next action), shown from the run's start to its stop, and each warning as it happens (above
    the bar). Used as a context manager, so that a run ended by an error takes the bar down too."""

    def __init__(self) -> None:
        self.bar = Progress(
            TextColumn("{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("({task.fields[skipped]} skipped)"),
            TimeRemainingColumn(),
            TextColumn("next: {task.fields[next]}", markup=False),
            console=console,
            transient=False,
        )
        self.task = self.bar.add_task("measurements", total=None, next="", skipped=0)
        self.shown = False

    def __call__(self, doc: Document) -> None:
        if doc.name == "start" and not self.shown:
            self.bar.start()
            self.shown = True
        elif doc.name == "progress":
            p = doc.data
            self.bar.update(
                self.task,
                completed=p["measured"] + p["skipped"],
                total=p["planned"],
                skipped=p["skipped"],
                next=p["next_action"] or "-",
            )
        elif doc.name == "warning":
            console.print(labelled("warning", "yellow", doc.data["message"]))
        elif doc.name == "stop":
            self.close()

    def close(self) -> None:
        if self.shown:
            self.bar.stop()
            self.shown = False

    def __enter__(self) -> ConsoleProgress:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@contextmanager
def operator_page(args) -> Iterator[WebPage | None]:
    """`--operator web`: the operator's page, listening from now until the command ends (None: console only)."""
    if getattr(args, "operator", "console") != "web":
        yield None
        return
    page = WebPage(
        args.web_host or LOOPBACK,
        DEFAULT_PORT if args.web_port is None else args.web_port,
        say=console.print,
        out=console.file.write,
    )
    try:
        yield page
    finally:
        page.close()


def analyse_for(store: SessionStore, campaign: Campaign | None, page: WebPage | None, linger_s: float = 0.0) -> None:
    """The end-of-run analysis of the session's `campaign` (None: its stored one) on the console, and its outcome on
    the page (kept up `linger_s` seconds, or until Ctrl-C, so that the operator can open the report on the tablet)."""
    analysis = analyse_and_print(store, campaign)
    if page is None:
        return
    if analysis is None:
        page.finish(None, "The campaign is complete but cannot be identified yet (the console says why): no report.")
    else:
        page.finish(analysis.report)
    linger(page, linger_s, "the outcome and the report")


def linger(page: WebPage | None, linger_s: float, what: str) -> None:
    """Keep the operator's page up `linger_s` seconds (or until Ctrl-C) once trackcal is done, showing `what`."""
    if page is not None and linger_s > 0:
        console.print(f"the operator's page shows {what} for {linger_s:g} s (Ctrl-C ends it)")
        with suppress(KeyboardInterrupt):
            time.sleep(linger_s)


def at_console() -> OperatorConsole:
    return OperatorConsole(say=console.print, operator=ConsoleOperator(console))


# What to do before `trackcal resume`, by the stop's code (README, "Safe stops name their cause")
ADVICE = {
    DOOR_OPEN: "Close the cell door, then",
    PLC_SILENT: "Check the cell PLC's power and its network to this PC (the plc section of the hardware file), then",
    ESTOP_PRESSED: "Release the emergency stop once the cell is safe, then",
    RSI_STALE: "Check that the controller's RSI program runs and its network to this PC, then",
    CHANNELS_DISAGREE: "Make sure nothing but the controller sends RSI frames to this PC (the log names every sender "
    "ignored), then",
    TARGET_MISMATCH: "Check the robot program and the controller's messages (it stood elsewhere than its target), then",
}


def stopped_safely(store: SessionStore, result: RunResult) -> None:
    """A run that did not complete is one line naming the step and the cause, and what to do before continuing."""
    if result.exit_status != "success":
        advice = ADVICE.get(result.code, "Fix the cause, then")  # type: ignore[arg-type]
        raise CampaignError(f"{result.message}. {advice}: trackcal resume {store.directory}")


def campaign_exit(store: SessionStore, done: Completeness) -> int:
    """The exit code of a campaign that reached its end: 0, or 3 when it measured nothing or skipped more of its
    planned measurements than the cell's max_skipped_share (the plan's promise is not kept: README, exit codes).
    `done`: after a run, its result's (run_completeness); else the session's (completeness)."""
    if not done.failed:
        return 0
    why = (
        "it measured nothing"
        if done.measured == 0
        else (f"more than the cell's max_skipped_share {done.max_skipped_share:.0%} skipped")
    )
    print(
        f"error: {store.directory}: {done.sentence()}: {why}, so the plan's accuracy is not reached (exit code 3)",
        file=sys.stderr,
    )
    return 3


def drive(store: SessionStore, campaign: Campaign, page: WebPage | None = None) -> RunResult:
    """Continue the session's `campaign` on its cell, with the console's progress (and the operator's page)."""
    with ConsoleProgress() as progress:
        result = resume(store, campaign, at_console(), [progress], page)
    stopped_safely(store, result)
    return result


def cmd_run(args) -> int:
    if bool(args.sim) == bool(args.hardware):
        raise UsageError("give exactly one of --sim or --hardware FILE")
    plan_doc = read_json(args.plan, InputError)
    if args.hardware and (args.effect or args.sim_speed is not None):
        raise UsageError("--effect and --sim-speed are for --sim only (with hardware: `trackcal mock`)")
    if args.hardware and args.truth:
        raise UsageError("--truth is for --sim only: the twin's truth (a real robot's is what you measure)")
    effects = parse_effects(args.effect) if args.sim else {}
    if args.operator != "web" and (args.web_host or args.web_port is not None or args.web_linger):
        raise UsageError("--web-host, --web-port and --web-linger are for --operator web")
    if args.sim_speed is not None and not args.sim_speed > 0:
        raise UsageError("--sim-speed must be positive (simulated seconds per real second)")
    cell = (
        HardwareOptions(Path(args.hardware))
        if args.hardware
        else SimOptions(args.seed, effects, args.sim_speed, args.truth)
    )
    with operator_page(args) as page:
        with ConsoleProgress() as progress:
            store, campaign, result = run_new(
                Path(args.session), args.cell, plan_doc, cell, at_console(), [progress], page
            )
        stopped_safely(store, result)
        if not args.no_analysis:
            analyse_for(store, campaign, page, args.web_linger)
        return campaign_exit(store, run_completeness(result, campaign.cell))


def cmd_resume(args) -> int:
    """Drive the session's campaign to its end and analyse it; a campaign already complete is analysed again only
    on request."""
    store = SessionStore.open(args.session)
    try:  # the lock goes with the store, also when the campaign cannot go on (a caller in the same process resumes)
        with operator_page(args) as page:
            return resume_and_analyse(store, args, page)
    finally:
        store.close()


def resume_and_analyse(store: SessionStore, args, page: WebPage | None = None) -> int:
    changed = changed_copies(store)
    if changed:
        console.print(
            labelled(
                "note",
                "yellow",
                f"{', '.join(changed)} in {store.directory} differ from the "
                "copies stored at the session's creation: resume uses the stored copies",
            ),
            soft_wrap=True,
        )
    if store.events("campaign_done"):
        console.print(
            f"{store.directory}: the campaign is already complete"
            + ("" if args.analyse else " (`trackcal resume --analyse` analyses it again)")
        )
        campaign, done = None, completeness(store)
        if not args.analyse:
            return campaign_exit(store, done)
    else:
        campaign = stored_campaign(store)
        done = run_completeness(drive(store, campaign, page), campaign.cell)
    if not args.no_analysis:
        analyse_for(store, campaign, page, getattr(args, "web_linger", 0.0))
    return campaign_exit(store, done)


def cmd_replay(args) -> int:
    into = Path(args.into)
    try:
        plan_doc = read_json(args.plan, InputError) if args.plan else None
        recording = SessionStore.open(args.session, readonly=True)
        with operator_page(args) as page:
            store = replay(recording, into, args.cell, plan_doc, page=page)  # a failed one leaves nothing at `into`
            replayed(store, into, page, args.web_linger)
    except (CalibError, CampaignError, OSError, ValueError) as exc:
        if isinstance(exc, ReplayDivergence):
            raise InputError(f"replay diverges from the recording at {exc} ({into} not kept)") from None
        if isinstance(exc, CampaignError):
            raise
        raise InputError(str(exc)) from None
    return 0


def replayed(store: SessionStore, into: Path, page: WebPage | None, linger_s: float) -> None:
    """The replay's table exported, then (`--operator web`) the page kept up `linger_s` seconds."""
    n = write_export(store, into / "table.csv")
    console.print(f"replayed {n} measurements into {into} (the recording is unchanged)")
    if page is not None:
        page.finish(None, f"Replayed into {into}; a replay is not analysed, so there is no report.")
        linger(page, linger_s, "the replayed campaign")
