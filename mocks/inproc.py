"""In-process devices over the simulated world, for fast engine tests without sockets.

They implement the interfaces of drivers/interfaces.py exactly as the real clients do (same errors for
the same situations); the socket-level mocks in this folder serve the same world over real protocols.
"""

from __future__ import annotations

import numpy as np

from trackcal.drivers.errors import DeviceFault, MotionRefused, TargetNotVisible
from trackcal.drivers.interfaces import DeviceIdentity, Environment, RobotState, TrackerMeasurement, TrackerStatus
from trackcal.mocks.cell import NotVisible, World

ENV = Environment(20.0, 1013.25, 45.0)


class InprocTracker:
    def __init__(self, world: World):
        self.world = world
        self.initialized = False
        self.faults: list[str] = []  # queued faults: "beam", "connection"

    def connect(self) -> None: ...

    def initialize(self) -> None:
        self.initialized = True

    def configure(self) -> None: ...

    def set_environment(self, env: Environment) -> None: ...

    def set_reflector(self, reflector_id: int) -> None: ...

    def set_stationary_averaging(self, n_samples: int) -> None: ...

    def find_reflector(self, x_mm: float, y_mm: float, z_mm: float, search_radius_mm: float) -> None: ...

    def measure(self) -> TrackerMeasurement:
        if not self.initialized:
            raise DeviceFault("tracker not initialised", code="not_initialized", device="tracker (in-process)")
        if self.faults:
            fault = self.faults.pop(0)
            cls = TargetNotVisible if "beam" in fault else DeviceFault
            raise cls(f"injected fault: {fault}", code=fault, device="tracker (in-process)")
        try:
            x, y, z, sx, sy, sz = self.world.measure()
        except NotVisible as exc:  # the real tracker's answer when it finds no reflector
            raise TargetNotVisible(f"no reflector: {exc}", code="no_reflector", device="tracker (in-process)") from exc
        return TrackerMeasurement(x, y, z, sx, sy, sz, ENV)

    def status(self) -> TrackerStatus:
        return TrackerStatus(self.initialized, True, False)

    def go_birdbath(self) -> None: ...

    def identity(self) -> DeviceIdentity:
        return DeviceIdentity(model="simulated tracker (in-process)", source="simulated")

    def close(self) -> None: ...


class InprocRobot:
    def __init__(self, world: World, joint_speed_deg_s: float = 20.0):
        self.world = world
        self.speed = joint_speed_deg_s
        self.faults: list[str] = []
        lim = world.twin.cell.chain.limits_array()
        self.limits = np.degrees(lim)

    def connect(self) -> None: ...

    def joints(self) -> tuple[float, ...]:
        return tuple(float(v) for v in self.world.q_deg)

    def move(self, target_deg: tuple[float, ...], speed_override_pct: float) -> None:
        q = np.asarray(target_deg, dtype=float)
        if np.any(q < self.limits[:, 0]) or np.any(q > self.limits[:, 1]):
            raise MotionRefused("target outside the joint limits", device="robot (in-process)")
        if self.faults:
            fault = self.faults.pop(0)
            raise DeviceFault(f"injected fault: {fault}", code=fault, device="robot (in-process)")
        travel = float(np.max(np.abs(q - self.world.q_deg)))
        self.world.clock.sleep(travel / (self.speed * speed_override_pct / 100.0))
        self.world.robot_at(q)

    def wait_settled(self, tolerance_deg: float, window_s: float, timeout_s: float) -> tuple[float, ...]:
        self.world.clock.sleep(window_s)
        return self.joints()

    def stop(self) -> None: ...  # a move here ends before its call returns: there is never one to stop

    def state(self) -> RobotState:
        return RobotState(moving=False, fault=self.faults[0] if self.faults else "")

    def reset_faults(self) -> None: ...

    def identity(self) -> DeviceIdentity:
        return DeviceIdentity(model="simulated robot (in-process)", source="simulated")

    def close(self) -> None: ...


class InprocCellIO:
    def __init__(self, world: World):
        self.world = world

    def connect(self) -> None: ...

    def door_closed(self) -> bool:
        return self.world.door_closed

    def acknowledge_pressed(self) -> bool:
        return True

    def set_request_lamp(self, on: bool) -> None: ...

    def close(self) -> None: ...


class SimOperator:
    """The simulated operator: does what a prompt asks in the world, closes the door, acknowledges."""

    def __init__(self, world: World, seconds_per_action: float = 60.0):
        self.world = world
        self.seconds = seconds_per_action
        self.log: list[tuple[str, str]] = []

    def ask(self, kind: str, target: str, text: str) -> str:
        self.log.append((kind, text))
        if kind == "change_station":
            self.world.station = target
        elif kind == "move_reflector":
            self.world.point = target
        elif kind == "resume":
            self.world.door_closed = True
        self.world.clock.sleep(self.seconds)
        return "ack"
