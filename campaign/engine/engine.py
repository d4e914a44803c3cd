"""The campaign engine: walks the plan's steps through its command table against the device interfaces, emits
documents to its subscribers, and returns how the run ended.

After Bluesky's RunEngine (bluesky/bluesky, bluesky/run_engine.py: a registry of commands, `_command_registry`,
that each message of a plan is dispatched through, and `emit` handing each document to the subscribers in turn;
`RunEngineResult` for what a run returns): here the messages are the plan's steps (engine/steps.py), the command
table is `Engine.handlers`, and the documents are `Document`s: `start`, `step_started`, every device `call` (by the
recorders around the devices, engine/recording.py), `prompt` and the `operator`'s answer, `measurement`,
`warning`, `error`, `step_done`, `progress`, and `stop` with the exit status; `station_fit` comes from a
subscriber, the residuals of a station block once its last step is done (engine/station_fit.py). The session
store is one subscriber (session/session.py SessionLog), the console's progress another (cli/campaign.py).
Subscribers are called synchronously, in order, before the engine goes on: a subscriber that must be durable (the
store) has committed each document before the next device call.

Rules it keeps:
- every device call, operator answer and measurement is emitted (so committed by the store) as it happens; a
  step is marked done only after its documents are emitted, and the next motion is never commanded before the
  previous measurement has been handed to every subscriber;
- no motion while the cell door is open or an operator prompt is outstanding: after any prompt, motion
  resumes only after door closed + acknowledge + the plan's explicit `resume` step, which also resets the
  robot's latched faults; during every move and settle the robot client itself polls the door
  (campaign/cells/checks.motion_guard): a door opened mid-motion brakes the robot and the step fails, so the
  campaign stops safely there;
- at every station set-up and before every point block the tracker is configured again (units, coordinate
  system type, measurement and statistic mode, system settings, read back: Tracker.configure) and given the
  environment, so that nothing another program changed on it in between reaches a measurement;
- after every move, the joints the robot settled at must equal the move's target within the controller's
  resolution (JOINT_RESOLUTION_DEG, one count); otherwise the campaign stops safely (code TARGET_MISMATCH) before
  anything is measured at that pose (a robot that reports on two channels checks them against each other first);
- every measurement is compared with where the nominal model expects the reflector (the position FindReflector
  is given); one farther than the cell's tolerance is not kept as a measurement: the campaign stops safely
  with the likely causes (units changed, wrong reflector, station moved);
- a point the tracker cannot see from the current station (no reflector, beam broken) is skipped there
  and covered from another station; any other device fault stops the campaign safely (the result's
  exit status "stopped") and a resume continues it: steps already done are skipped, the operator context
  (station, reflector) is re-confirmed, and an interrupted measurement is re-measured after moving to its pose
  again.

The engine knows no controller: it moves a `Robot` (drivers/interfaces.py).
"""

from __future__ import annotations

from bisect import bisect_right
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass, field, replace

import numpy as np

from trackcal.calib.identify.drift import DriftTest
from trackcal.campaign.engine.documents import (
    SCHEMAS,
    ErrorDoc,
    MeasurementDoc,
    OperatorDoc,
    ProgressDoc,
    PromptDoc,
    StartDoc,
    StepDoneDoc,
    StepStartedDoc,
    StopDoc,
    WarningDoc,
)
from trackcal.campaign.engine.recording import EndOfSegment
from trackcal.campaign.engine.steps import Step, StepKind, next_prompts
from trackcal.drivers.errors import DeviceError, DeviceFault, TargetNotVisible
from trackcal.drivers.interfaces import JOINT_RESOLUTION_DEG, CellIO, Clock, Meteo, Operator, Robot, Tracker

TARGET_MISMATCH = "target_mismatch"  # stop code: the robot settled elsewhere than the move's target


@dataclass(frozen=True)
class Document:
    """What the engine tells its subscribers: `name` (DOCUMENTS), its data, and the step and campaign time it
    belongs to (step -1: outside the steps)."""

    name: str
    data: dict
    step: int = -1
    t: float = 0.0


DOCUMENTS = tuple(SCHEMAS)  # their schemas: engine/documents.py
Subscriber = Callable[[Document], None]


class RunContext:
    """Where a run is (its step and campaign time) and who hears its documents. Built first and shared by the
    engine and the recorders around its devices, so that both emit into the same ordered stream."""

    def __init__(self, subscribers: Iterable[Subscriber] = ()) -> None:
        self.step = -1
        self.t = 0.0
        self.subscribers = list(subscribers)

    def where(self) -> tuple[int, float]:
        return self.step, self.t

    def emit(self, name: str, data: dict, step: int | None = None, t: float | None = None) -> None:
        """Hand one document to every subscriber, in order (each returns before the next is called)."""
        if name not in DOCUMENTS:
            raise ValueError(f"unknown document {name!r}")
        doc = Document(name, data, self.step if step is None else step, self.t if t is None else t)
        for subscriber in self.subscribers:
            subscriber(doc)


class _Stop(Exception):
    """The campaign stops safely at a step (internal: `Engine.run` reports it in its result)."""

    def __init__(self, step: int, reason: str, code: int | str | None = None):
        self.step, self.reason, self.code = step, reason, code
        super().__init__(reason)


@dataclass(frozen=True)
class History:
    """What the session already holds when a run starts (empty for a new one): steps done, whether a run started
    before, the campaign time of its last event, and its measurements (the drift checks compare with them)."""

    done: frozenset[int] = frozenset()
    resumed: bool = False
    t_last: float = 0.0
    measurements: tuple[MeasurementDoc, ...] = ()


@dataclass(frozen=True)
class RunResult:
    """How a run ended (after Bluesky's RunEngineResult). exit_status: "success" (the campaign is complete),
    "stopped" (stopped safely at `step` for `reason`: a resume continues it), "ended" (a replayed run whose
    recording ends there: the recorded process stopped or was killed). Counts are the session's: measurements
    stored, planned measurements skipped (not visible from the station), planned; `warnings` of this run; `code`:
    the stop's cause when a device fault named one (the door, a silent PLC, a stale stream ...)."""

    exit_status: str
    reason: str = ""
    step: int | None = None
    measured: int = 0
    skipped: int = 0
    planned: int = 0
    warnings: tuple[str, ...] = ()
    code: int | str | None = None

    @property
    def message(self) -> str:
        if self.exit_status == "stopped":
            return f"stopped safely at step {self.step}: {self.reason}"
        return self.reason or self.exit_status


@dataclass
class Live:
    """The devices of a cell as they come (real clients, the twin's, or players of a recording), before the
    recorders wrap them into `Devices`; `close` ends them all."""

    tracker: Tracker
    robot: Robot
    operator: Operator
    clock: Clock
    cellio: CellIO | None = None
    meteo: Meteo | None = None
    close: Callable[[], None] = lambda: None


@dataclass
class Devices:
    """What the engine talks to (real clients, recorders around them, or players of a recording)."""

    tracker: Tracker
    robot: Robot
    operator: Operator
    clock: Clock  # recorded, so that replay reproduces times
    cellio: CellIO | None = None  # the door (None: a cell without a PLC, the console operator only)
    meteo: Meteo | None = None
    expected: Callable[[Step], tuple[float, float, float] | None] | None = None  # where to look for the reflector
    tolerance: Callable[[float], float] | None = None  # mm a measurement may lie from `expected`, given its range
    drift: DriftTest = field(default_factory=DriftTest)  # the drift checks' test: the tracker's noise, the robot's
    # repeatability (the engine shares its false-alarm rate among the plan's checks)


class DoorInterlock:
    """No motion while the cell door is open or an operator prompt is outstanding (after Bluesky's suspenders).

    Any prompt closes it; only the explicit resume step (door closed + acknowledge) opens it again."""

    def __init__(self, door_closed: Callable[[], bool]) -> None:
        self.door_closed = door_closed  # reads the door now (True in a cell without a PLC)
        self.released = False

    def close(self) -> None:
        self.released = False

    def release(self) -> bool:
        """After an acknowledge: motion may resume if the door is closed; returns whether it may."""
        self.released = self.door_closed()
        return self.released


@dataclass(frozen=True)
class Progress:
    """Where a campaign is (the data of a `progress` document): measurements stored and skipped (the point not
    visible from the station) of those planned, and the next operator action."""

    measured: int
    skipped: int
    planned: int
    next_action: str


@dataclass
class Settings:
    speed_pct: float = 30.0
    settle_tolerance_deg: float = 0.001
    settle_window_s: float = 1.0
    settle_timeout_s: float = 60.0
    search_radius_mm: float = 50.0
    measure_attempts: int = 2  # a beam broken by someone walking through it is transient: look again once


def undrifted_blocks(steps: list[Step]) -> dict[int, str]:
    """The point blocks the plan gives no drift check: step index of each one's first measurement -> the warning.
    A station's reference pose is the pose its drift revisits measure (calib.doe.order: the pose it sees the most
    points from); a point that station does not see at that pose has no revisit to compare, so a move of the
    station during that block goes unnoticed. A station with no revisit at all (an ISO 9283 test: its repeats are
    its drift data) has no such block."""
    refs = {s.station: s.pose for s in steps if s.kind == StepKind.MEASURE and s.drift}
    checked = {(s.station, s.point) for s in steps if s.kind == StepKind.MEASURE and s.drift}
    out: dict[int, str] = {}
    seen: set[tuple[str, str]] = set()
    for i, s in enumerate(steps):
        key = (s.station, s.point)
        if s.kind != StepKind.MEASURE or s.station not in refs or key in checked or key in seen:
            continue
        seen.add(key)
        out[i] = (
            f"no drift check for {s.point} from {s.station}: the block's reference pose {refs[s.station]} "
            f"does not see {s.point} from {s.station}, so a move of station {s.station} during this block goes "
            "unnoticed"
        )
    return out


def drift_checks(steps: list[Step]) -> int:
    """How many drift comparisons the plan makes: every revisit of a block's reference measurement after its first."""
    seen: dict[tuple[str, str, str], int] = {}
    for s in steps:
        if s.kind == StepKind.MEASURE and s.drift:
            key = (s.station, s.point, s.pose)
            seen[key] = seen.get(key, 0) + 1
    return sum(n - 1 for n in seen.values())


class Engine:
    def __init__(
        self, devices: Devices, context: RunContext, history: History | None = None, settings: Settings | None = None
    ):
        self.dev = devices
        self.context = context
        self.history = history or History()
        self.settings = settings or Settings()
        self.measurements = list(self.history.measurements)
        self.warnings: list[str] = []
        self.t0 = 0.0
        self.drift = self.dev.drift
        self.offset = 0.0
        self.undrifted: dict[int, str] = {}  # step -> the warning its block has no drift check (undrifted_blocks)
        self.interlock = DoorInterlock(lambda: self.dev.cellio is None or self.dev.cellio.door_closed())
        self.handlers: dict[StepKind, Callable[[Step], None]] = {
            StepKind.CHANGE_STATION: self._change_station,
            StepKind.MOVE_REFLECTOR: self._move_reflector,
            StepKind.RESUME: lambda step: self._resume_motion(),
            StepKind.MOVE: self._move,
            StepKind.SETTLE: self._settle,
            StepKind.MEASURE: self._measure,
        }

    # ------------------------------------------------------------------ time and documents
    def tick(self) -> float:
        """Read the (recorded) campaign clock: seconds since the campaign start, continuing across resumes."""
        self.context.t = self.offset + (self.dev.clock.now() - self.t0)
        return self.context.t

    def _emit(self, name: str, data: dict) -> None:
        self.context.emit(name, data)

    def _warn(self, message: str) -> None:
        self.warnings.append(message)
        self._emit("warning", WarningDoc(message=message))

    # ------------------------------------------------------------------ running
    def run(self, steps: list[Step]) -> RunResult:
        """Walk the steps not done yet; a safe stop, or the end of a replayed recording, ends the run with its
        result (any other error propagates: nothing after it is emitted)."""
        done = self.history.done
        self.offset = self.context.t = self.history.t_last
        self._emit("start", StartDoc(resumed=self.history.resumed, steps=len(steps), done=len(done)))
        self.t0 = self.dev.clock.now()
        first = next((i for i in range(len(steps)) if i not in done), len(steps))
        self.drift = replace(self.dev.drift, checks=drift_checks(steps))
        self.undrifted = undrifted_blocks(steps)
        measures = [i for i, s in enumerate(steps) if s.kind == StepKind.MEASURE]
        following = next_prompts(steps)
        n_done = sum(1 for k in measures if k in done or k < first)
        try:
            if self.history.resumed and first < len(steps):
                try:
                    self._restore_context(steps, first)
                except DeviceError as exc:  # e.g. the operator not answering the re-confirmation: stop as in a step
                    raise self._stop_for(first, exc) from exc
            for i in range(first, len(steps)):
                if i in done:
                    continue
                self._execute(i, steps[i])
                n_done = bisect_right(measures, i)  # measured or skipped
                progress = Progress(
                    len(self.measurements), max(0, n_done - len(self.measurements)), len(measures), following[i]
                )
                self._emit("progress", ProgressDoc(**asdict(progress)))
        except _Stop as stop:
            return self._end("stopped", stop.reason, stop.step, n_done, len(measures), stop.code)
        except EndOfSegment as end:
            return self._end("ended", str(end), self.context.step, n_done, len(measures))
        self.context.step = -1
        return self._end("success", "", None, len(measures), len(measures))

    def _end(
        self, status: str, reason: str, step: int | None, n_done: int, planned: int, code: int | str | None = None
    ) -> RunResult:
        measured = len(self.measurements)
        result = RunResult(
            status, reason, step, measured, max(0, n_done - measured), planned, tuple(self.warnings), code
        )
        self._emit("stop", StopDoc(exit_status=status, reason=reason))
        return result

    def _restore_context(self, steps: list[Step], first: int) -> None:
        """Re-confirm the physical state a crash may have changed, then continue at `first`."""
        before = steps[:first]
        ctx = [s for s in before if s.kind == StepKind.CHANGE_STATION][-1:] + [
            s for s in before if s.kind == StepKind.MOVE_REFLECTOR and s.station == steps[first].station
        ][-1:]
        self.context.step = first
        self._warn(f"resuming at step {first}: re-confirming the operator context")
        for s in ctx:
            self._prompt(s.kind, s.station if s.kind == StepKind.CHANGE_STATION else s.point, f"Resuming: {s.label}")
            if s.kind == StepKind.CHANGE_STATION:
                self._set_up_tracker()  # a restarted process talks to a tracker it has not initialised
        if ctx:
            self._resume_motion()
        here = steps[first]
        if here.approach and not here.via and here.kind in (StepKind.MOVE, StepKind.SETTLE, StepKind.MEASURE):
            # an ISO 9283 vAP visit (7.2): the pose is reached from its approach point, so that comes first again
            via = next(s for s in reversed(before) if s.kind == StepKind.MOVE and s.via)
            self._move(via)
            self._settle(via)
        if here.kind in (StepKind.SETTLE, StepKind.MEASURE):
            move = next(s for s in reversed(before) if s.kind == StepKind.MOVE)
            self._move(move)
            if steps[first].kind == StepKind.MEASURE:
                self._settle(move)

    def _execute(self, i: int, step: Step) -> None:
        self.context.step = i
        self.tick()
        self._emit("step_started", StepStartedDoc(step=step.to_dict()))
        try:
            self.handlers[step.kind](step)
        except DeviceError as exc:
            raise self._stop_for(i, exc) from exc
        self._emit("step_done", StepDoneDoc())

    def _stop_for(self, i: int, exc: DeviceError) -> _Stop:
        """The safe stop at step i for a device error, its error document emitted (with the fault's code, which
        names the cause: the session records which)."""
        code = getattr(exc, "code", None)
        doc = ErrorDoc(type=type(exc).__name__, message=str(exc))
        if code is not None:
            doc["code"] = code
        self._emit("error", doc)
        return _Stop(i, str(exc), code)

    # ------------------------------------------------------------------ step kinds
    def _change_station(self, step: Step) -> None:
        self._prompt(step.kind, step.station, step.label)
        self._set_up_tracker()

    def _move_reflector(self, step: Step) -> None:
        self._prompt(step.kind, step.point, step.label)
        self._configure_tracker()

    def _prompt(self, kind: str, target: str, text: str) -> None:
        self.interlock.close()
        self._emit("prompt", PromptDoc(kind=kind, target=target, text=text))
        answer = self.dev.operator.ask(kind, target, text)
        self._emit("operator", OperatorDoc(answer=answer))

    def _resume_motion(self) -> None:
        """Door closed + acknowledge: only then may the robot move again."""
        text = "Leave the cell, close the door and acknowledge to resume motion"
        while True:
            self._emit("prompt", PromptDoc(kind=StepKind.RESUME, target="", text=text))
            answer = self.dev.operator.ask(StepKind.RESUME, "", text)
            self._emit("operator", OperatorDoc(answer=answer))
            if self.interlock.release():
                self.dev.robot.reset_faults()  # the operator acknowledged: the controller's latched faults go
                return
            self._warn("the cell door is open: motion stays blocked")

    def _set_up_tracker(self) -> None:
        self.dev.tracker.initialize()
        self._configure_tracker()

    def _configure_tracker(self) -> None:
        """Everything a measurement depends on, set again (another program may have changed it meanwhile)."""
        self.dev.tracker.configure()
        if self.dev.meteo is not None:
            self.dev.tracker.set_environment(self.dev.meteo.read())

    def _move(self, step: Step) -> None:
        if not self.interlock.released:
            raise _Stop(self.context.step, "motion requested without an acknowledged resume")
        if not self.interlock.door_closed():
            self._warn("the cell door opened: motion blocked until resumed")
            self.interlock.close()
            self._resume_motion()
        wait = step.not_before_s - self.tick()  # an ISO 9283 drift group (7.6) starts at its time
        if wait > 0:
            self.dev.clock.sleep(wait)
        # an ISO 9283 test velocity (6.7) is the step's own; every other move the session's setting
        self.dev.robot.move(tuple(step.q_deg), step.speed_pct or self.settings.speed_pct)

    def _settle(self, step: Step) -> None:
        """Wait until the robot stands; it must stand at the step's target, to one count of the controller."""
        s = self.settings
        q = self.dev.robot.wait_settled(s.settle_tolerance_deg, s.settle_window_s, s.settle_timeout_s)
        target = tuple(step.q_deg)
        if len(q) != len(target):
            raise DeviceFault(
                f"{step.pose}: the robot settled with {len(q)} joints, the target has {len(target)}",
                code=TARGET_MISMATCH,
                device="robot",
            )
        for j, (a, t) in enumerate(zip(q, target, strict=True), 1):
            if abs(round(float(a) / JOINT_RESOLUTION_DEG) - round(float(t) / JOINT_RESOLUTION_DEG)) > 1:
                raise DeviceFault(
                    f"{step.pose}: the robot settled with joint {j} at {float(a):.4f} deg, not at the "
                    f"target {float(t):.4f} deg (more than one count of {JOINT_RESOLUTION_DEG:g} deg "
                    "apart): nothing is measured at this pose",
                    code=TARGET_MISMATCH,
                    device="robot",
                )

    def _measure(self, step: Step) -> None:
        if self.context.step in self.undrifted:  # the block's first measurement: said once, as the block starts
            self._warn(self.undrifted[self.context.step])
        q = self.dev.robot.joints()
        env = self.dev.meteo.read() if self.dev.meteo is not None else None
        expected = self.dev.expected(step) if self.dev.expected is not None else None
        for attempt in range(1, self.settings.measure_attempts + 1):
            try:
                if expected is not None:
                    self.dev.tracker.find_reflector(*expected, self.settings.search_radius_mm)
                m = self.dev.tracker.measure()
                break
            except TargetNotVisible as exc:
                last = attempt == self.settings.measure_attempts
                then = "skipped here" if last else "looking again"
                where = f"{step.point} not measurable from {step.station} at {step.pose}"
                self._warn(f"{where}: {exc}; {then}")
                if last and step.drift:  # a reference revisit lost: the block's drift check with it
                    self._warn(
                        f"no drift check for {step.point} from {step.station} in this block: its reference "
                        f"pose {step.pose} could not be measured, so a move of station {step.station} during "
                        "the block goes unnoticed"
                    )
                if last:
                    return
        if expected is not None and self.dev.tolerance is not None:
            self._check_plausible(step, expected, m)
        env = env or m.environment
        self.tick()
        data = MeasurementDoc(
            pose=step.pose,
            station=step.station,
            point=step.point,
            drift=step.drift,
            q_deg=[round(float(v), 4) for v in q],
            xyz_mm=[m.x_mm, m.y_mm, m.z_mm],
            std_mm=[m.std_x_mm, m.std_y_mm, m.std_z_mm],
            env=[env.temperature_c, env.pressure_hpa, env.humidity_pct],
        )
        if step.approach:
            data["approach"] = step.approach
        if step.speed_pct:
            data["velocity_pct"] = step.speed_pct
        if step.group:
            data["drift_group"] = step.group
        if step.check:
            data["field_check"] = True
        self._emit("measurement", data)
        self.measurements.append(data)
        if step.drift:
            self._check_drift(data)

    def _check_plausible(self, step: Step, expected: tuple[float, float, float], m) -> None:
        e, x = np.asarray(expected, dtype=float), np.array([m.x_mm, m.y_mm, m.z_mm])
        off, reach = float(np.linalg.norm(x - e)), float(np.linalg.norm(e))
        tolerance = self.dev.tolerance(reach)
        if off <= tolerance:
            return
        message = (
            f"{step.point} from {step.station} at {step.pose} was measured {off:.1f} mm from where the nominal "
            f"model expects it (tolerance {tolerance:.0f} mm; {float(np.linalg.norm(x)) / reach:.4g} times "
            "the expected distance from the tracker), so it is not stored as a measurement. Likely causes: the "
            "tracker's units or coordinate system were changed (by another program?), the wrong reflector, "
            f"or station {step.station} moved"
        )
        self._emit(
            "error", ErrorDoc(type="ImplausibleMeasurement", message=message, xyz_mm=x.tolist(), expected_mm=e.tolist())
        )
        raise _Stop(self.context.step, message)

    def _check_drift(self, data: MeasurementDoc) -> None:
        first = next(
            (
                m
                for m in self.measurements
                if m["drift"]
                and (m["station"], m["point"], m["pose"]) == (data["station"], data["point"], data["pose"])
            ),
            None,
        )
        if first is None:
            return
        a, b = np.asarray(first["xyz_mm"], dtype=float), np.asarray(data["xyz_mm"], dtype=float)
        if self.drift.alarms(a, b):
            self._warn(
                f"drift check: {data['point']} at {data['pose']} moved {float(np.linalg.norm(b - a)):.3f} mm "
                f"since the start of the block, {self.drift.distance(a, b):.1f} standard deviations of the "
                f"tracker's noise and the robot's repeatability there (alarm above {self.drift.level:.1f}): "
                f"has station {data['station']} moved?"
            )
