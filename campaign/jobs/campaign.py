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
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from trackcal.calib.io import fields
from trackcal.calib.io.files import read_text
from trackcal.calib.model.cell import Cell, load_cell
from trackcal.campaign.cells.hardware import connect_hardware, load_hardware
from trackcal.campaign.cells.sim import SimCell
from trackcal.campaign.engine.engine import Devices, Engine, History, Live, RunContext, RunResult, Subscriber
from trackcal.campaign.engine.expected import expected_position, measurement_tolerance
from trackcal.campaign.engine.recording import Playback, Recorder
from trackcal.campaign.engine.steps import Step, campaign_steps
from trackcal.campaign.errors import CampaignError, InputError
from trackcal.campaign.session.session import (
    SessionFiles,
    SessionLog,
    create_session,
    session_cell,
    session_hardware,
    session_plan,
    stored_config,
)
from trackcal.campaign.session.store import Event, SessionStore, StoreError
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


@dataclass(frozen=True)
class HardwareOptions:
    """The real cell described by a hardware config (configs/hardware/README.md), stored in the session."""

    config: Path


@dataclass(frozen=True)
class OperatorConsole:
    """Whoever runs the campaign: `say` shows a line (rich markup) to them, `operator` answers the prompts in a
    cell without a PLC."""

    say: Callable[[str], None]
    operator: Operator


def plan_arrays(plan_doc: dict) -> tuple[np.ndarray, int]:
    """The poses (a list of joint vectors of JSON numbers) and the passes (an integer >= 1) of a plan."""
    poses = fields.rows(plan_doc.get("poses_deg"), "plan: poses_deg", StoreError)
    repeat = fields.integer(plan_doc.get("repeat", 1), "plan: repeat", StoreError)
    if repeat < 1:
        raise StoreError(f"plan: repeat: expected an integer >= 1, got {repeat}")
    return poses, repeat


def plan_steps(cell: Cell, plan_doc: dict) -> list[Step]:
    """The steps of a plan in a cell; the whole plan is checked first (PlanError, StoreError)."""
    poses, repeat = plan_arrays(plan_doc)
    if poses.shape[1] != cell.chain.dof:
        raise StoreError(f"plan: poses have {poses.shape[1]} joints, robot {cell.chain.name} has {cell.chain.dof}")
    return list(campaign_steps(cell, poses, repeat))


def stored_campaign(store: SessionStore) -> Campaign:
    """The campaign a session holds, from its stored cell and plan (never the files beside the database)."""
    cell, plan = session_cell(store), session_plan(store)
    return Campaign(cell, plan, plan_steps(cell, plan))


def new_session(directory: Path, cell_ref: str, plan_doc: dict, mode: str, seed: int | None,
                hardware: tuple[str, str] | None = None, effects: dict[str, float] | None = None,
                extra: dict[str, str] | None = None) -> tuple[SessionStore, Campaign]:  # fmt: skip
    """A new session (session.create_session) and its campaign: the cell and the plan are checked before the
    session exists (a cell or plan that cannot run makes no session)."""
    cell = load_cell(cell_ref)
    campaign = Campaign(cell, plan_doc, plan_steps(cell, plan_doc))
    store = create_session(directory, cell_ref, plan_doc, mode, seed, hardware, effects, extra)
    return store, campaign


def history(store: SessionStore) -> History:
    """What the session holds when a run starts: the engine continues from there."""
    events = store.events()
    return History(done=frozenset(store.done_steps()), resumed=any(e.kind == "campaign_started" for e in events),
                   t_last=events[-1].t_campaign if events else 0.0,
                   measurements=tuple(e.data for e in events if e.kind == "measurement"))  # fmt: skip


def devices(live: Live, context: RunContext, cell: Cell) -> Devices:
    """The live devices wrapped in recorders (each call a `call` document), with the cell's expectations."""

    def rec(name: str, dev):
        return None if dev is None else Recorder(name, dev, context)

    return Devices(tracker=rec("tracker", live.tracker), robot=rec("robot", live.robot),
                   operator=rec("operator", live.operator), clock=rec("clock", live.clock),
                   cellio=rec("cellio", live.cellio), meteo=rec("meteo", live.meteo),
                   expected=expected_position(cell), tolerance=measurement_tolerance(cell))  # fmt: skip


def run_session(store: SessionStore, campaign: Campaign, live: Live,
                subscribers: Iterable[Subscriber] = ()) -> RunResult:  # fmt: skip
    """Run (or continue) the session's campaign on `live` until it is complete or stops safely; the store hears
    every document first, then `subscribers` in order. The devices are closed at the end."""
    try:
        context = RunContext([SessionLog(store), *subscribers])
        return Engine(devices(live, context, campaign.cell), context, history(store)).run(campaign.steps)
    finally:
        live.close()


def run_stored(store: SessionStore, live: Live, subscribers: Iterable[Subscriber] = ()) -> RunResult:
    """run_session of the campaign the session holds (its stored cell and plan)."""
    return run_session(store, stored_campaign(store), live, subscribers)


def open_cell(store: SessionStore, cell: Cell, console: OperatorConsole) -> Live:
    """The devices of the session's cell: the digital twin's (sim) or the real one (hardware, from the hardware
    config stored at the session's creation)."""
    meta = store.meta()
    if meta["mode"] == "sim":
        effects = json.loads(meta.get("effects", "{}") or "{}")
        speed = float(meta["sim_speed"]) if meta.get("sim_speed") else None
        return SimCell(cell, int(meta["seed"] or 0), store, effects, speed, say=console.say).live
    if meta["mode"] == "hardware":
        copy = SessionFiles(store.directory).hardware
        hw = load_hardware(copy, session_hardware(store))
        try:
            return connect_hardware(hw, cell, console.say, console.operator)
        except CampaignError as exc:
            raise InputError(f"{exc} (the session uses the hardware config stored at its creation, copied in "
                             f"{copy}: make the devices reachable there, then `trackcal resume "
                             f"{store.directory}`)") from None  # fmt: skip
    raise InputError(f"{store.directory}: a {meta['mode']} session cannot be run live")


def run_new(directory: Path, cell_ref: str, plan_doc: dict, cell: SimOptions | HardwareOptions,
            console: OperatorConsole, subscribers: Sequence[Subscriber] = ()) -> tuple[SessionStore, RunResult]:
    """`trackcal run`: a new session of the plan in the cell (simulated or real), run to its end or to a safe
    stop. A hardware config is checked before the session exists, then the cell and the plan."""
    if isinstance(cell, HardwareOptions):
        text = read_text(cell.config, InputError)
        load_hardware(cell.config, text)
        store, campaign = new_session(directory, cell_ref, plan_doc, "hardware", None,
                                      hardware=(text, str(Path(cell.config).resolve())))  # fmt: skip
    else:
        extra = {"sim_speed": str(cell.speed)} if cell.speed else {}
        store, campaign = new_session(directory, cell_ref, plan_doc, "sim", cell.seed, effects=cell.effects,
                                      extra=extra)  # fmt: skip
    return store, run_session(store, campaign, open_cell(store, campaign.cell, console), subscribers)


def resume(store: SessionStore, console: OperatorConsole, subscribers: Sequence[Subscriber] = ()) -> RunResult:
    """`trackcal resume`: continue the session's campaign (its stored cell and plan) on its cell."""
    campaign = stored_campaign(store)
    return run_session(store, campaign, open_cell(store, campaign.cell, console), subscribers)


def segments(events: list[Event]) -> list[tuple[list[Event], bool]]:
    """The recorded runs of a session (split at each campaign start) and whether each ended abruptly."""
    runs: list[list[Event]] = []
    for e in events:
        if e.kind == "campaign_started" or not runs:
            runs.append([])
        runs[-1].append(e)
    return [(run, not any(e.kind in ("campaign_done", "error") for e in run)) for run in runs]


def replay(recording: SessionStore, into: Path, cell_ref: str | None = None, plan_doc: dict | None = None,
           subscribers: Sequence[Subscriber] = ()) -> SessionStore:  # fmt: skip
    """`trackcal replay`: re-run the campaign with players of the recording instead of devices, into a new
    session, run by run: a recorded run that stopped (device fault) or was killed stops the replay's run at the
    same call, and the next run resumes exactly as the recorded one did. `cell_ref` / `plan_doc` replace the
    recorded ones (a changed config): the replay then stops at the first step whose device calls differ
    (ReplayDivergence)."""
    meta = recording.meta()
    plan_doc = plan_doc or session_plan(recording)
    seed = int(meta["seed"]) if meta["seed"] else None
    if cell_ref is not None:
        store, campaign = new_session(into, cell_ref, plan_doc, "replay", seed)
    else:
        with stored_config(recording) as cell_path:
            store, campaign = new_session(into, str(cell_path), plan_doc, "replay", seed)
    for run, abrupt in segments(recording.events()):
        context = RunContext([SessionLog(store), *subscribers])
        playback = Playback(run, context.where, ends_abruptly=abrupt)
        players = Live(*(playback.device(n) for n in ("tracker", "robot", "operator", "clock")),
                       cellio=playback.device("cellio") if "cellio" in playback.calls else None,
                       meteo=playback.device("meteo") if "meteo" in playback.calls else None)  # fmt: skip
        Engine(devices(players, context, campaign.cell), context, history(store)).run(campaign.steps)
    return store
