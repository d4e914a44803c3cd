"""A campaign on typed arguments: run a new session, resume one, replay one (`trackcal run | resume | replay`
are these functions with argparse and printing around them).

The flow goes one way: the cell is loaded once, the plan checked and its steps built once (the visibility
with them: engine/steps.py), then the session is created from those documents (session/), the cell's devices
are opened (cells/), wrapped in recorders, and the engine walks the steps, emitting documents to its
subscribers: the session store first (each document committed before the engine goes on), then the caller's
(the console's progress, ...). Replay is the same engine fed by players of a recorded session instead of live
devices, run by run; resume is the engine continuing a session from what it already holds (`history`).
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from rich.text import Text

from trackcal.calib.identify.drift import DriftTest
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.io.files import read_text
from trackcal.calib.model.cell import Cell, load_cell
from trackcal.campaign.cells.checks import names_told_apart
from trackcal.campaign.cells.hardware import CellClients, claim_cell, connect_hardware, load_hardware
from trackcal.campaign.cells.identity import IdentityCheck, stated_tracker
from trackcal.campaign.cells.sim import SimCell
from trackcal.campaign.engine.documents import measurement
from trackcal.campaign.engine.engine import Devices, Engine, History, Live, RunContext, RunResult, Subscriber
from trackcal.campaign.engine.expected import expected_position, measurement_tolerance
from trackcal.campaign.engine.recording import Playback, Recorder
from trackcal.campaign.engine.station_fit import StationFits
from trackcal.campaign.engine.steps import Step, plan_steps
from trackcal.campaign.errors import CampaignError, InputError
from trackcal.campaign.jobs.simulate import write_truth
from trackcal.campaign.session.session import (
    CELL_DOC,
    SessionFiles,
    SessionLog,
    create_session,
    session_approached,
    session_cell,
    session_hardware,
    session_plan,
    stored_config,
)
from trackcal.campaign.session.store import Event, SessionLock, SessionStore, StoreError
from trackcal.campaign.web.server import WebPage
from trackcal.drivers.interfaces import Operator


@dataclass(frozen=True)
class Campaign:
    """A campaign ready to run: its cell, its plan (the document) and the plan's steps, checked."""

    cell: Cell
    plan: dict
    steps: list[Step]


@dataclass(frozen=True)
class SimOptions:
    """The digital twin's cell: its seed, hidden effects (cause -> magnitude, mm) and simulated seconds per real
    second (None: flat out)."""

    seed: int = 1
    effects: dict[str, float] = field(default_factory=dict)
    speed: float | None = None
    truth: str | None = None  # the twin's truth to write (campaign.jobs.simulate.write_truth); None: not written


@dataclass(frozen=True)
class HardwareOptions:
    """The real cell described by a hardware config (configs/hardware/README.md), stored in the session."""

    config: Path


@dataclass(frozen=True)
class OperatorConsole:
    """Whoever runs the campaign: `say` shows a line to them as it is (a rich Text for colour), `operator` answers
    the prompts in a cell without a PLC."""

    say: Callable[[str | Text], None]
    operator: Operator


def stored_campaign(store: SessionStore) -> Campaign:
    """The campaign a session holds, from its stored cell and plan (never the files beside the database)."""
    cell, plan = session_cell(store), session_plan(store)
    return Campaign(cell, plan, plan_steps(cell, plan, session_approached(store)))


def new_session(
    directory: Path,
    cell_ref: str,
    plan_doc: dict,
    mode: str,
    seed: int | None,
    hardware: tuple[str, str] | None = None,
    effects: dict[str, float] | None = None,
    extra: dict[str, str] | None = None,
    approached: bool = True,
    cell: Cell | None = None,
    config: dict[str, str] | None = None,
) -> tuple[SessionStore, Campaign]:
    """A new session (session.create_session) and its campaign: the cell and the plan are checked before the
    session exists (a cell or plan that cannot run makes no session). `cell`: `cell_ref` already loaded; `config`:
    its documents when they come from another session (create_session)."""
    cell = cell or load_cell(cell_ref)
    names_told_apart(cell)
    campaign = Campaign(cell, plan_doc, plan_steps(cell, plan_doc, approached))
    store = create_session(
        directory, cell_ref, cell.nominal, plan_doc, mode, seed, hardware, effects, extra, approached, config
    )
    return store, campaign


def history(store: SessionStore) -> History:
    """What the session holds when a run starts: the engine continues from there."""
    events = store.events()
    return History(
        done=frozenset(store.done_steps()),
        resumed=any(e.kind == "campaign_started" for e in events),
        t_last=events[-1].t_campaign if events else 0.0,
        measurements=tuple(measurement(e.data) for e in events if e.kind == "measurement"),
    )


def run_context(store: SessionStore, campaign: Campaign, subscribers: Iterable[Subscriber]) -> RunContext:
    """The documents of a run go to the store first, then `subscribers` in order, then the station fits (which
    emit each station block's residuals into the same run: engine/station_fit.py)."""
    context = RunContext([SessionLog(store), *subscribers])
    events = store.events()
    measured = [(e.step, measurement(e.data)) for e in events if e.kind == "measurement"]
    fitted = [e.data["block"] for e in events if e.kind == "station_fit"]
    context.subscribers.append(
        StationFits(campaign.cell, campaign.steps, context.emit, measured, fitted, store.done_steps())
    )
    return context


def devices(live: Live, context: RunContext, cell: Cell) -> Devices:
    """The live devices wrapped in recorders (each call a `call` document), with the cell's expectations."""

    def rec(name: str, dev):
        return None if dev is None else Recorder(name, dev, context)

    return Devices(
        tracker=rec("tracker", live.tracker),
        robot=rec("robot", live.robot),
        operator=rec("operator", live.operator),
        clock=rec("clock", live.clock),
        cellio=rec("cellio", live.cellio),
        meteo=rec("meteo", live.meteo),
        expected=expected_position(cell),
        tolerance=measurement_tolerance(cell),
        drift=DriftTest(TrackerNoise.of(cell.tracker), repeatability_mm=cell.repeatability_mm),
    )


def run_session(
    store: SessionStore,
    campaign: Campaign,
    live: Live,
    subscribers: Iterable[Subscriber] = (),
    page: WebPage | None = None,
) -> RunResult:
    """Run (or continue) the session's campaign on `live` until it is complete or stops safely; the store hears
    every document first, then `subscribers` in order, then the operator's page (`page`, attached by open_cell).
    The devices are closed at the end."""
    try:
        hub = [] if page is None or page.hub is None else [page.hub]
        context = run_context(store, campaign, [*subscribers, *hub])
        context.subscribers.append(IdentityCheck(live, context.emit, stated_tracker(store)))
        return Engine(devices(live, context, campaign.cell), context, history(store)).run(campaign.steps)
    finally:
        live.close()


def run_stored(store: SessionStore, live: Live, subscribers: Iterable[Subscriber] = ()) -> RunResult:
    """run_session of the campaign the session holds (its stored cell and plan)."""
    return run_session(store, stored_campaign(store), live, subscribers)


def open_cell(
    store: SessionStore,
    campaign: Campaign,
    console: OperatorConsole,
    claimed: CellClients | None = None,
    page: WebPage | None = None,
) -> Live:
    """The devices of the session's cell: the digital twin's (sim) or the real one (hardware, from the hardware
    config stored at the session's creation; `claimed`: its clients when run_new claimed them already). With the
    operator's `page`, it serves the session and each prompt is shared by the cell's operator, the console and the
    page (the twin's simulated person then does the work but leaves the acknowledgement to them)."""
    live = _open_cell(store, campaign.cell, console, claimed, page is None)
    if page is not None:
        page.attach(store, campaign.cell, campaign.steps)
        live.operator = page.operator(live.operator, console.operator, live.cellio)
    return live


def _open_cell(
    store: SessionStore, cell: Cell, console: OperatorConsole, claimed: CellClients | None, human_acknowledges: bool
) -> Live:
    meta = store.meta()
    if meta["mode"] == "sim":
        effects = json.loads(meta.get("effects", "{}") or "{}")
        speed = float(meta["sim_speed"]) if meta.get("sim_speed") else None
        return SimCell(
            cell, int(meta["seed"] or 0), store, effects, speed, say=console.say, human_acknowledges=human_acknowledges
        ).live
    if meta["mode"] == "hardware":
        copy = SessionFiles(store.directory).hardware
        clients = claimed or claim_cell(load_hardware(copy, session_hardware(store)), cell)
        if clients.hw.family.native_output is not None:  # the robot library's own console lines: to the session
            clients.hw.family.native_output(SessionFiles(store.directory).robot_log)
        try:
            return connect_hardware(clients, console.say, console.operator)
        except CampaignError as exc:
            raise InputError(
                f"{exc} (the session uses the hardware config stored at its creation, copied in "
                f"{copy}: make the devices reachable there, then `trackcal resume "
                f"{store.directory}`)"
            ) from None
    if meta["mode"] == "replay":
        source = meta.get("replay_of") or "RECORDING"
        raise InputError(
            f"{store.directory}: a replay is not resumed but made again: `trackcal replay {source} --into "
            f"DIR` (it replaces what a killed replay left)"
        )
    raise InputError(f"{store.directory}: a {meta['mode']} session cannot be run live")


def run_new(
    directory: Path,
    cell_ref: str,
    plan_doc: dict,
    cell: SimOptions | HardwareOptions,
    console: OperatorConsole,
    subscribers: Sequence[Subscriber] = (),
    page: WebPage | None = None,
) -> tuple[SessionStore, Campaign, RunResult]:
    """`trackcal run`: a new session of the plan in the cell (simulated or real), run to its end or to a safe
    stop; returns the session, its campaign (the cell loaded once, for the analysis after) and the run's result. A
    hardware config is checked before the session exists, then the cell and the plan; then the cell is claimed
    (cells.hardware.claim_cell): a cell another campaign is running on makes no session. A device that cannot be
    reached leaves the session, with its copy of the hardware config, for `trackcal resume`."""
    if isinstance(cell, HardwareOptions):
        text = read_text(cell.config, InputError)
        loaded = load_cell(cell_ref)
        clients = claim_cell(load_hardware(cell.config, text), loaded)
        try:
            store, campaign = new_session(
                directory,
                cell_ref,
                plan_doc,
                "hardware",
                None,
                hardware=(text, str(Path(cell.config).resolve())),
                cell=loaded,
            )
        except BaseException:
            clients.robot.close()
            raise
        live = open_cell(store, campaign, console, clients, page)
        return store, campaign, run_session(store, campaign, live, subscribers, page)
    extra = {"sim_speed": str(cell.speed)} if cell.speed else {}
    store, campaign = new_session(directory, cell_ref, plan_doc, "sim", cell.seed, effects=cell.effects, extra=extra)
    if cell.truth:  # the twin SimCell serves is a pure function of the cell, the seed and the effects
        write_truth(cell.truth, campaign.cell, cell.seed, cell.effects)
    live = open_cell(store, campaign, console, page=page)
    return store, campaign, run_session(store, campaign, live, subscribers, page)


def resume(
    store: SessionStore,
    campaign: Campaign,
    console: OperatorConsole,
    subscribers: Sequence[Subscriber] = (),
    page: WebPage | None = None,
) -> RunResult:
    """`trackcal resume`: continue the session's campaign (`campaign`: its stored cell and plan, stored_campaign) on
    its cell."""
    return run_session(store, campaign, open_cell(store, campaign, console, page=page), subscribers, page)


def segments(events: list[Event]) -> list[tuple[list[Event], bool]]:
    """The recorded runs of a session (split at each campaign start) and whether each ended abruptly."""
    runs: list[list[Event]] = []
    for e in events:
        if e.kind == "campaign_started" or not runs:
            runs.append([])
        runs[-1].append(e)
    return [(run, not any(e.kind in ("campaign_done", "error") for e in run)) for run in runs]


REPLAYING = ".replaying"  # the folder a replay is made in, beside its destination, until it is complete


def replay_staging(into: Path) -> Path:
    return into.with_name(into.name + REPLAYING)


def replay(
    recording: SessionStore,
    into: Path,
    cell_ref: str | None = None,
    plan_doc: dict | None = None,
    subscribers: Sequence[Subscriber] = (),
    page: WebPage | None = None,
) -> SessionStore:
    """`trackcal replay`: re-run the campaign with players of the recording instead of devices, into a new
    session, run by run: a recorded run that stopped (device fault) or was killed stops the replay's run at the
    same call, and the next run resumes exactly as the recorded one did. `cell_ref` / `plan_doc` replace the
    recorded ones (a changed config): the replay then stops at the first step whose device calls differ
    (ReplayDivergence).

    The replay is made in INTO.replaying and renamed to INTO once complete: a replay that was killed leaves no
    session at INTO, only its staging folder, which the next replay into INTO removes (a replay is a pure function
    of the recording: made again, it is the same). Returns the finished session, opened read-only. `page`: the
    operator's page watches the replay (its answers are the recording's)."""
    into = Path(into)
    if into.exists() and (not into.is_dir() or any(into.iterdir())):
        raise StoreError(f"{into}: already exists and is not empty: replay into a new folder")
    staging = replay_staging(into)
    if staging.exists():  # what a killed replay left (a replay still running there holds its lock: refused)
        SessionLock.acquire(staging).release()
        shutil.rmtree(staging)
    meta = recording.meta()
    plan_doc = plan_doc or session_plan(recording)
    seed = int(meta["seed"]) if meta["seed"] else None
    extra, approached = {"replay_of": str(recording.directory)}, session_approached(recording)
    if cell_ref is not None:
        store, campaign = new_session(staging, cell_ref, plan_doc, "replay", seed, extra=extra, approached=approached)
    else:  # the recording's own cell, from its stored documents
        store, campaign = new_session(
            staging,
            CELL_DOC,
            plan_doc,
            "replay",
            seed,
            extra=extra,
            approached=approached,
            cell=session_cell(recording),
            config=stored_config(recording),
        )
    try:
        hub = [] if page is None else [page.attach(store, campaign.cell, campaign.steps)]  # watching only
        for run, abrupt in segments(recording.events()):
            context = run_context(store, campaign, [*subscribers, *hub])
            playback = Playback(run, context.where, ends_abruptly=abrupt)
            players = Live(
                *(playback.device(n) for n in ("tracker", "robot", "operator", "clock")),
                cellio=playback.device("cellio") if "cellio" in playback.calls else None,
                meteo=playback.device("meteo") if "meteo" in playback.calls else None,
            )
            Engine(devices(players, context, campaign.cell), context, history(store)).run(campaign.steps)
    except BaseException:
        store.close()
        shutil.rmtree(staging, ignore_errors=True)  # a failed replay leaves nothing behind
        raise
    store.close()
    if into.exists():
        into.rmdir()  # empty (checked above): the finished replay takes its place
    staging.rename(into)
    return SessionStore.open(into, readonly=True)
