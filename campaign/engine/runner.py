"""Wiring a campaign: devices (simulated or real), recorders, the engine, resume and replay."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from trackcal.calib.model.cell import Cell
from trackcal.calib.model.kinematics import Kinematics
from trackcal.campaign.engine.engine import CampaignStopped, Devices, Engine
from trackcal.campaign.engine.recording import EndOfSegment, Playback, Recorder
from trackcal.campaign.engine.steps import Step
from trackcal.campaign.session.session import create_session, session_cell, session_plan, session_steps, stored_config
from trackcal.campaign.session.store import SessionStore


def expected_position(cell: Cell) -> Callable[[Step], tuple[float, float, float] | None]:
    """Where the reflector should be, in the station's frame, by the nominal model (for FindReflector)."""
    kin = Kinematics(cell.chain, [])

    def expected(step: Step):
        st = cell.stations.get(step.station)
        if st is None or step.point not in cell.tool_points:
            return None
        p = kin.points(np.radians(np.asarray(step.q_deg))[None], cell.tool_points[step.point])[0]
        x = st.rotation.T @ (p - st.position)
        return float(x[0]), float(x[1]), float(x[2])

    return expected


# How far a measurement may lie from where the nominal model expects it, before the campaign stops. The
# expectation errs by the robot's nominal-model error and by the station's placement error:
# - the uncalibrated KR-270 of the paper misses by at most 1.31 mm (Table 9, distance residuals before calibration);
# - a tracker set up on a nominal station of the cell config sits within about 20 mm (position) and 0.5 deg
#   (orientation) of it per axis, one standard deviation: the digital twin's model of a station set-up
#   (mocks/twin.py); an orientation error w moves a point at range r by |w x r| <= |w| r.
# Three standard deviations on each of the three axes: 3 * sqrt(3) * (20 mm + 0.5 deg * r) + 1.31 mm, i.e.
# 105 mm next to the tracker, 264 mm at 3.5 m. A cell's `measurement_tolerance_mm` replaces it.
NOMINAL_ROBOT_ERROR_MM = 1.31
STATION_POSITION_SIGMA_MM = 20.0
STATION_ORIENTATION_SIGMA_DEG = 0.5


def measurement_tolerance(cell: Cell) -> Callable[[float], float]:
    """range from the tracker (mm) -> how far (mm) a measurement may lie from its expected position."""
    if cell.measurement_tolerance_mm is not None:
        fixed = cell.measurement_tolerance_mm
        return lambda reach_mm: fixed

    def tolerance(reach_mm: float) -> float:
        station = STATION_POSITION_SIGMA_MM + np.radians(STATION_ORIENTATION_SIGMA_DEG) * reach_mm
        return float(3.0 * np.sqrt(3.0) * station + NOMINAL_ROBOT_ERROR_MM)

    return tolerance


@dataclass
class Live:
    """Live devices of a campaign (before recording wrappers)."""

    tracker: object
    robot: object
    operator: object
    clock: object
    cellio: object = None
    meteo: object = None
    close: Callable[[], None] = lambda: None


def recorded(store: SessionStore, live: Live, engine_context) -> Devices:
    def rec(name, dev):
        return None if dev is None else Recorder(name, dev, store, engine_context)

    return Devices(
        tracker=rec("tracker", live.tracker), robot=rec("robot", live.robot), operator=rec("operator", live.operator),
        clock=rec("clock", live.clock), cellio=rec("cellio", live.cellio), meteo=rec("meteo", live.meteo),
    )  # fmt: skip


def run_campaign(store: SessionStore, live: Live, progress=None, notify=None) -> Engine:
    """Run (or resume) the session's campaign on live devices; `progress` and `notify` as for Engine."""
    cell = session_cell(store)
    steps = session_steps(cell, session_plan(store))
    engine = Engine(store, Devices(None, None, None, None), progress=progress, notify=notify)
    engine.dev = recorded(store, live, engine.context)
    engine.dev.expected, engine.dev.tolerance = expected_position(cell), measurement_tolerance(cell)
    try:
        engine.run(steps)
    finally:
        live.close()
    return engine


def segments(events) -> list[tuple[list, bool]]:
    """The recorded runs of a session (split at each campaign start) and whether each ended abruptly."""
    runs: list[list] = []
    for e in events:
        if e.kind == "campaign_started" or not runs:
            runs.append([])
        runs[-1].append(e)
    return [(run, not any(e.kind in ("campaign_done", "error") for e in run)) for run in runs]


def replay_session(recording: SessionStore, into: Path, cell_ref: str | None = None, plan_doc: dict | None = None,
                   progress=None) -> SessionStore:  # fmt: skip
    """Re-run the campaign with players of the recording instead of devices, into a new session, run by
    run: a recorded run that stopped (device fault) or was killed stops the replay's run at the same call,
    and the next run resumes exactly as the recorded one did. `cell_ref` / `plan_doc` replace the recorded
    ones (a changed config): the replay then stops at the first step whose device calls differ."""
    meta = recording.meta()
    plan_doc = plan_doc or session_plan(recording)
    seed = int(meta["seed"]) if meta["seed"] else None
    if cell_ref is not None:
        store = create_session(into, cell_ref, plan_doc, "replay", seed)
    else:
        with stored_config(recording) as cell_path:
            store = create_session(into, str(cell_path), plan_doc, "replay", seed)
    cell = session_cell(store)
    steps = session_steps(cell, plan_doc)
    for run, abrupt in segments(recording.events()):
        engine = Engine(store, Devices(None, None, None, None), progress=progress)
        playback = Playback(run, engine.context, ends_abruptly=abrupt)
        players = Live(*(playback.device(n) for n in ("tracker", "robot", "operator", "clock")),
                       cellio=playback.device("cellio") if "cellio" in playback.calls else None,
                       meteo=playback.device("meteo") if "meteo" in playback.calls else None)  # fmt: skip
        engine.dev = recorded(store, players, engine.context)
        engine.dev.expected, engine.dev.tolerance = expected_position(cell), measurement_tolerance(cell)
        try:
            engine.run(steps)
        except (CampaignStopped, EndOfSegment):
            continue
    return store
