"""The schema of each document the engine emits (a Document's `data`), one TypedDict per kind, after bluesky's
event-model (event_model/documents/*.py: one TypedDict per document type, the keys and their types written once).

The engine builds each document through its TypedDict, the session store keeps them as they are (the event kinds of
campaign/session/store.py are these names, `start` stored as campaign_started and a successful `stop` as
campaign_done), and every reader (export, resume, replay, the station fits, the operator's page, ISO 9283) reads them
by these keys: a key is spelled here, and tests/test_documents.py checks every document of a run against its schema.
Units: mm and degrees, campaign time in seconds. (No `from __future__ import annotations` here: a TypedDict reads
NotRequired from its evaluated annotations.)
"""

from typing import Any, NotRequired, TypedDict, cast


class StartDoc(TypedDict):
    """A run starts (or resumes: `resumed`) with `steps` steps, `done` of them done before."""

    resumed: bool
    steps: int
    done: int


class StepStartedDoc(TypedDict):
    step: dict[str, Any]  # engine/steps.py Step.to_dict()


class StepDoneDoc(TypedDict):
    """The step is done: a resume does not execute it again."""


class CallError(TypedDict):
    type: str  # the driver error's class (drivers/errors.py)
    message: str
    code: int | str | None  # a device fault's cause (the door, a silent PLC ...)
    device: str


class CallDoc(TypedDict):
    """One call of a device's method, with its result or its error: what a replay plays back."""

    device: str  # tracker, robot, operator, clock, cellio, meteo
    op: str
    args: list[Any]
    result: NotRequired[Any]
    error: NotRequired[CallError]


class PromptDoc(TypedDict):
    kind: str  # a StepKind of the operator's (change_station, move_reflector, resume ...)
    target: str  # the station or point
    text: str


class OperatorDoc(TypedDict):
    """The `operator` document: the operator's answer to the prompt before it."""

    answer: str


class MeasurementDoc(TypedDict):
    """One tracker measurement: the reflector `point` at `pose` from `station`, the joints read from the controller
    then, the reflector centre in the station's frame with its standard deviations, and the air (temperature C,
    pressure hPa, humidity %)."""

    pose: str
    station: str
    point: str
    drift: bool  # a drift-check visit (the block's reference pose revisited)
    q_deg: list[float]
    xyz_mm: list[float]
    std_mm: list[float]
    env: list[float]
    approach: NotRequired[str]  # ISO 9283 multi-directional test (7.3): the side the pose was approached from
    velocity_pct: NotRequired[float]  # ISO 9283 test velocity (6.7): the move's speed, % of the rated velocity
    drift_group: NotRequired[int]  # ISO 9283 drift test (7.6): the group of P1 measurements (1, 2, ...)
    field_check: NotRequired[bool]  # the tracker's field check: a known length's end, not a test measurement


class WarningDoc(TypedDict):
    message: str


class ErrorDoc(TypedDict):
    """What stopped the run: a device fault (`code`: its cause) or an implausible measurement (where it was and where
    the nominal model expected it)."""

    type: str
    message: str
    code: NotRequired[int | str]
    xyz_mm: NotRequired[list[float]]
    expected_mm: NotRequired[list[float]]


class ProgressDoc(TypedDict):
    """Measurements stored and skipped (the point not visible from the station) of those planned, and the next
    operator action (not stored)."""

    measured: int
    skipped: int
    planned: int
    next_action: str


class StopDoc(TypedDict):
    exit_status: str  # success, stopped, ended (engine.RunResult)
    reason: str


class StationResidual(TypedDict):
    step: int
    pose: str
    point: str
    d_mm: list[float]  # measured - the nominal model placed on the block, station frame


class StationFitDoc(TypedDict):
    """A station block's measurements against the nominal model placed on them (engine/station_fit.py): `note` says
    why there are no residuals when the block cannot be placed."""

    block: int
    station: str
    planned: int
    measured: int
    residuals: list[StationResidual]
    rms_mm: NotRequired[float]
    max_mm: NotRequired[float]
    position_mm: NotRequired[list[float]]  # the station's origin in the robot's base frame
    note: NotRequired[str]


class IdentityDoc(TypedDict):
    """Who the devices were at a run's start (campaign/cells/identity.py): each device's serial, model, software and
    `source` (read from the device, or from the hardware file), or {"error": why} when it could not be read."""

    tracker: dict[str, str]
    robot: dict[str, str]


def measurement(data: dict) -> MeasurementDoc:
    """A stored `measurement` document's data, read as what it is (no copy: the keys are checked by the type
    checker at every reader, and by tests/test_documents.py against the engine's)."""
    return cast(MeasurementDoc, data)


SCHEMAS: dict[str, type] = {
    "start": StartDoc,
    "step_started": StepStartedDoc,
    "call": CallDoc,
    "prompt": PromptDoc,
    "operator": OperatorDoc,
    "measurement": MeasurementDoc,
    "warning": WarningDoc,
    "error": ErrorDoc,
    "step_done": StepDoneDoc,
    "progress": ProgressDoc,
    "stop": StopDoc,
    "station_fit": StationFitDoc,
    "identity": IdentityDoc,
}
