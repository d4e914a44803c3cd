"""`trackcal run | resume | replay`: campaigns on the shop floor or on the simulated cell."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

from trackcal.calib.errors import CalibError
from trackcal.calib.io.files import read_json, read_text
from trackcal.campaign.analysis import analyse_session, parse_effects
from trackcal.campaign.cells.hardware import connect_hardware, load_hardware
from trackcal.campaign.cells.sim import SimCell
from trackcal.campaign.console import console
from trackcal.campaign.engine.engine import CampaignStopped
from trackcal.campaign.engine.engine import Progress as CampaignProgress
from trackcal.campaign.engine.recording import ReplayDivergence
from trackcal.campaign.engine.runner import replay_session, run_campaign
from trackcal.campaign.errors import CampaignError, InputError, UsageError
from trackcal.campaign.session.session import (
    HARDWARE_COPY,
    changed_copies,
    create_session,
    session_cell,
    session_hardware,
    write_export,
)
from trackcal.campaign.session.store import SessionStore


def _progress():
    """The campaign's bar: planned measurements done (measured or skipped), how many skipped, the next action."""
    bar = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                   TextColumn("({task.fields[skipped]} skipped)"), TimeRemainingColumn(),
                   TextColumn("next: {task.fields[next]}"), console=console, transient=False)  # fmt: skip
    task = bar.add_task("measurements", total=None, next="", skipped=0)

    def update(p: CampaignProgress) -> None:
        bar.update(task, completed=p.measured + p.skipped, total=p.planned, skipped=p.skipped,
                   next=p.next_action or "-")  # fmt: skip

    return bar, update


def _warn_operator(message: str) -> None:
    """A campaign warning on the console as it happens (above the progress bar)."""
    console.print(f"[yellow]warning[/]: {escape(message)}", highlight=False)


def _live_for(store: SessionStore):
    meta = store.meta()
    cell = session_cell(store)
    if meta["mode"] == "sim":
        effects = json.loads(meta.get("effects", "{}") or "{}")
        speed = float(meta["sim_speed"]) if meta.get("sim_speed") else None
        return SimCell(cell, int(meta["seed"] or 0), store, effects, speed).live
    if meta["mode"] == "hardware":
        hw = load_hardware(store.directory / HARDWARE_COPY, session_hardware(store))
        try:
            return connect_hardware(hw, cell)
        except CampaignError as exc:
            raise InputError(f"{exc} (the session uses the hardware config stored at its creation, copied in "
                             f"{store.directory / HARDWARE_COPY}: make the devices reachable there, then "
                             f"`trackcal resume {store.directory}`)") from None
    raise InputError(f"{store.directory}: a {meta['mode']} session cannot be run live")


def drive(store: SessionStore) -> None:
    bar, update = _progress()
    try:
        with bar:
            run_campaign(store, _live_for(store), progress=update, notify=_warn_operator)
    except CampaignStopped as exc:
        raise CampaignError(f"{exc}. Fix the cause, then: trackcal resume {store.directory}") from None


def cmd_run(args) -> int:
    if bool(args.sim) == bool(args.hardware):
        raise UsageError("give exactly one of --sim or --hardware FILE")
    plan_doc = read_json(args.plan, InputError)
    if args.hardware and (args.effect or args.sim_speed is not None):
        raise UsageError("--effect and --sim-speed are for --sim only (with hardware: `trackcal mock`)")
    effects = parse_effects(args.effect) if args.sim else {}
    mode, seed = ("sim", args.seed) if args.sim else ("hardware", None)
    if args.sim_speed is not None and not args.sim_speed > 0:
        raise UsageError("--sim-speed must be positive (simulated seconds per real second)")
    extra = {"sim_speed": str(args.sim_speed)} if args.sim and args.sim_speed else {}
    if args.hardware:
        return _campaign(lambda: _hardware_session(Path(args.session), args.cell, plan_doc, args.hardware),
                         args.no_analysis)  # fmt: skip
    return _campaign(lambda: create_session(Path(args.session), args.cell, plan_doc, mode, seed, effects=effects,
                                            extra=extra), args.no_analysis)  # fmt: skip


def _hardware_session(directory: Path, cell_ref: str, plan_doc: dict, hardware: str) -> SessionStore:
    """A new session that stores the hardware config (validated first: a broken file makes no session)."""
    text = read_text(hardware, InputError)
    load_hardware(hardware, text)
    source = str(Path(hardware).resolve())
    return create_session(directory, cell_ref, plan_doc, "hardware", None, hardware=(text, source))


def cmd_resume(args) -> int:
    def open_store() -> SessionStore:
        store = SessionStore.open(args.session)
        changed = changed_copies(store)
        if changed:
            console.print(f"[yellow]note[/]: {', '.join(changed)} in {store.directory} differ from the copies stored "
                          "at the session's creation: resume uses the stored copies", soft_wrap=True)  # fmt: skip
        return store

    return _campaign(open_store, args.no_analysis, args.analyse)


def _campaign(open_store, no_analysis: bool, reanalyse: bool = False) -> int:
    """Drive the campaign to its end and analyse it; a campaign already complete is analysed again only on request."""
    store = open_store()
    if store.events("campaign_done"):
        console.print(f"{store.directory}: the campaign is already complete"
                      + ("" if reanalyse else " (`trackcal resume --analyse` analyses it again)"))  # fmt: skip
        if not reanalyse:
            return 0
    else:
        drive(store)
    if not no_analysis:
        analyse_session(store)
    return 0


def cmd_replay(args) -> int:
    into = Path(args.into)
    fresh = not into.exists()
    try:
        plan_doc = read_json(args.plan, InputError) if args.plan else None
        recording = SessionStore.open(args.session, readonly=True)
        store = replay_session(recording, into, args.cell, plan_doc)
    except (CalibError, CampaignError, OSError, ValueError) as exc:
        if fresh:  # a failed replay leaves no directory that resume or a second replay would stumble over
            shutil.rmtree(into, ignore_errors=True)
        if isinstance(exc, ReplayDivergence):
            raise InputError(f"replay diverges from the recording at {exc} ({into} not kept)") from None
        if isinstance(exc, CampaignError):
            raise
        raise InputError(str(exc)) from None
    n = write_export(store, Path(args.into) / "table.csv")
    console.print(f"replayed {n} measurements into {args.into} (the recording is unchanged)")
    return 0
