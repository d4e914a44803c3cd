"""The device interfaces the campaign sees. Real clients and test doubles implement them.

Units: millimetres, degrees, degrees Celsius, hPa, percent relative humidity, seconds.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Protocol, runtime_checkable


@dataclass(frozen=True)
class Environment:
    temperature_c: float
    pressure_hpa: float
    humidity_pct: float


@dataclass(frozen=True)
class TrackerMeasurement:
    """One stationary measurement of the reflector centre in the tracker (station) frame."""

    x_mm: float
    y_mm: float
    z_mm: float
    std_x_mm: float
    std_y_mm: float
    std_z_mm: float
    environment: Environment


@dataclass(frozen=True)
class TrackerStatus:
    initialized: bool
    reflector_locked: bool
    busy: bool
    detail: str = ""


READ_FROM_DEVICE = "read from the device"
FROM_HARDWARE_FILE = "from the hardware file"


@dataclass(frozen=True)
class DeviceIdentity:
    """Who a device is, for a certificate's item and instrument: its serial number, its model (type, name), its
    software (firmware and software versions, one phrase), each "" where nothing says it; `source` where they come
    from: READ_FROM_DEVICE (the device's own answer) or FROM_HARDWARE_FILE (a controller whose protocol offers no
    identity query: what the cell's hardware file states)."""

    serial: str = ""
    model: str = ""
    software: str = ""
    source: str = READ_FROM_DEVICE


@runtime_checkable
class Tracker(Protocol):
    def connect(self) -> None: ...
    def initialize(self) -> None: ...
    def configure(self) -> None:
        """Set everything a measurement depends on (units mm/deg/degC/hPa/%RH, Cartesian coordinates, the
        stationary measurement mode and its settings) and check what the tracker reads back."""
        ...

    def set_environment(self, env: Environment) -> None: ...
    def set_reflector(self, reflector_id: int) -> None: ...
    def set_stationary_averaging(self, n_samples: int) -> None: ...
    def find_reflector(self, x_mm: float, y_mm: float, z_mm: float, search_radius_mm: float) -> None: ...
    def measure(self) -> TrackerMeasurement: ...
    def status(self) -> TrackerStatus: ...
    def go_birdbath(self) -> None: ...
    def identity(self) -> DeviceIdentity:
        """The tracker's serial number, type and firmware, as it reports them."""
        ...

    def close(self) -> None: ...


# One count of a joint angle as a controller reports it: KRL writes $AXIS_ACT with 4 decimals on EKI
# (drivers.kuka.eki_codec) and the RSI client reads <AIPos> to 4 decimals (drivers.kuka.rsi_link; the mock sends
# 4, kuka_experimental's kuka_rsi_simulator sends Python's str() of the float, more digits than a count).
JOINT_RESOLUTION_DEG = 1e-4


class StopCause(str):
    """Why the robot must stop now, as a motion guard answers it: the one line for people (the string itself) and
    a stable `code` naming the cause (the stop's DeviceFault code, so the session records which cause it was)."""

    code: str

    def __new__(cls, text: str, code: str) -> StopCause:
        cause = super().__new__(cls, text)
        cause.code = code
        return cause


def stop_code(reason) -> str:
    """The DeviceFault code of a guard stop: its StopCause's code (door_open, plc_silent, estop_pressed ...),
    "stopped" for a plain reason (a guard's text, stop())."""
    return getattr(reason, "code", "stopped")


@dataclass(frozen=True)
class RobotState:
    """What the controller says of the arm now: moving or standing, and the fault it holds ("" when none)."""

    moving: bool
    fault: str = ""


@runtime_checkable
class Robot(Protocol):
    """What the campaign moves: any controller family (KR C2 over EKI + RSI, ...) implements it, and the engine
    knows no other word of a controller."""

    def connect(self) -> None: ...
    def joints(self) -> tuple[float, ...]:
        """Actual joint angles in degrees, at the controller's precision (0.0001 deg)."""
        ...

    def move(self, target_deg: tuple[float, ...], speed_override_pct: float) -> None:
        """Check the target (joint limits, cell box) and move there (joint interpolated); returns once the move is
        done."""
        ...

    def wait_settled(self, tolerance_deg: float, window_s: float, timeout_s: float) -> tuple[float, ...]:
        """Wait until the actual joints stay within `tolerance_deg` for `window_s`; returns them (the engine compares
        them with the move's target: they must equal it within JOINT_RESOLUTION_DEG). A controller reporting its
        joints on more than one channel checks that they agree (DeviceFault otherwise)."""
        ...

    def stop(self) -> None:
        """Brake the running move on its path (a controlled stop, drives stay on); returns once the arm stands."""
        ...

    def state(self) -> RobotState: ...
    def reset_faults(self) -> None:
        """Clear the controller's latched faults (E-stop seen, drives off) once the operator acknowledged;
        DeviceFault if one is still active."""
        ...

    def identity(self) -> DeviceIdentity:
        """The controller's serial number and software version: read from it where its protocol offers a query,
        else what the hardware file states (source FROM_HARDWARE_FILE)."""
        ...

    def close(self) -> None: ...


@runtime_checkable
class CellIO(Protocol):
    def connect(self) -> None: ...
    def door_closed(self) -> bool: ...
    def acknowledge_pressed(self) -> bool: ...
    def set_request_lamp(self, on: bool) -> None: ...
    def close(self) -> None: ...


@runtime_checkable
class Meteo(Protocol):
    def connect(self) -> None: ...
    def read(self) -> Environment: ...
    def close(self) -> None: ...


@runtime_checkable
class Clock(Protocol):
    """Campaign and device time in seconds (monotonic); mocks and tests run a virtual one."""

    def now(self) -> float: ...
    def sleep(self, seconds: float) -> None: ...


@runtime_checkable
class Operator(Protocol):
    def ask(self, kind: str, target: str, text: str) -> str:
        """Show the request (kind: change_station, move_reflector or resume; target: station or point id) and
        block until the operator acknowledges; returns the answer."""
        ...


@runtime_checkable
class SharedOperator(Protocol):
    """An operator that can share a prompt with others (the console, the cell's button, the operator's page):
    the prompt is offered to each, polled until one answers, and withdrawn from the others (the first answer
    wins). Polling never blocks for long; an operator that can no longer answer raises ConnectionLost from
    `poll` (it leaves the others in charge)."""

    def offer(self, kind: str, target: str, text: str) -> None:
        """Show the request (as `Operator.ask`), without waiting."""
        ...

    def poll(self) -> str | None:
        """The answer (who gave it) if the request was acknowledged since `offer`, else None."""
        ...

    def withdraw(self) -> None:
        """Another operator answered: take the request down."""
        ...


class RealClock:
    """The wall clock a real cell runs on (time.monotonic)."""

    def now(self) -> float:
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds)
