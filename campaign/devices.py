"""The devices of a campaign: the simulated cell (mock servers on loopback, real clients), or the real cell."""

from __future__ import annotations

import contextlib

import numpy as np

from calib.cell import Cell
from calib.poses import points_in_box
from drivers.emscon import EmsconTracker
from drivers.kuka import KukaKrc2
from drivers.meteo import SerialMeteo
from drivers.plc import ModbusCellIO

from .console import console
from .operator import PlcOperator
from .runner import Live
from .store import SessionStore

HOME_DEG = (0.0, -90.0, 90.0, 0.0, 90.0, 0.0)  # KR C2 HOME of the KRL program (configs/krc2)
# Rated axis speeds of a KR 270 are about 100 deg/s for A1-A3 (KUKA KR QUANTEC data sheet: A1 105, A2 101,
# A3 96 deg/s); the slowest of them sets the simulated PTP duration at 100 % override.
SIM_JOINT_SPEED_DEG_S = 96.0


def cell_box_check(cell: Cell):
    """The robot client's pre-send check: every reference point of the target pose inside the cell box."""

    def check(q_deg) -> str | None:
        if points_in_box(cell, np.radians(np.asarray(q_deg, dtype=float))[None])[0]:
            return None
        return "a reference point of the target pose leaves the cell box"

    return check


def joint_limits_deg(cell: Cell) -> list[tuple[float, float]]:
    return [(float(lo), float(hi)) for lo, hi in np.degrees(cell.chain.limits_array())]


class SimCell:
    """The digital twin's cell served over the real protocols on loopback: emScon tracker, KR C2 (EKI + RSI,
    connecting to us like the real controller), Modbus PLC with a simulated operator, serial meteo on a
    pseudo-terminal; `live` holds the real clients talking to them. The mocks stay reachable (tracker_mock,
    controller, plc, human, world) so tests can inject faults mid-campaign.

    On resume the world learns which measurements the session already holds, so every measurement keeps its
    noise (a pure function of the seed and the step's identity). `speed`: simulated seconds per real second
    (None: as fast as the machine goes)."""

    def __init__(self, cell: Cell, seed: int, store: SessionStore | None = None,
                 effects: dict[str, float] | None = None, speed: float | None = None) -> None:  # fmt: skip
        from mocks.clock import VirtualClock
        from mocks.emscon_server import EmsconMockServer
        from mocks.krc2 import MockKrc2
        from mocks.meteo_pty import MockMeteo
        from mocks.operator import SimHuman
        from mocks.plc_server import MockPlc
        from mocks.twin import Twin
        from mocks.world import World

        self.clock = VirtualClock(real_fraction=0.0 if not speed else 1.0 / speed)
        self.world = World(Twin(cell, seed=seed, effects=effects or {}), self.clock)
        if store is not None:
            self.world.restore_counts([(e.data["station"], e.data["point"], tuple(e.data["q_deg"]))
                                       for e in store.events("measurement")])  # fmt: skip
        self._started: list = []
        try:
            self.tracker_mock = self._up(
                EmsconMockServer(
                    lambda expected: self.world.measure(), self.clock, reflector_present=self.world.reflector_visible
                )
            )
            self.tracker_mock.start()
            tracker = EmsconTracker(*self.tracker_mock.address, timeout_s=10.0)
            robot = self._up(
                KukaKrc2(
                    "127.0.0.1",
                    0,
                    "127.0.0.1",
                    0,
                    joint_limits_deg=joint_limits_deg(cell),
                    cell_box_check=cell_box_check(cell),
                    connect_timeout_s=20.0,
                )
            )
            robot.listen()
            self.controller = self._up(
                MockKrc2(
                    robot.eki_address,
                    robot.rsi_address,
                    self.clock,
                    HOME_DEG,
                    on_joints=self.world.robot_at,
                    joint_speed_deg_s=SIM_JOINT_SPEED_DEG_S,
                    seed=seed,
                    overshoot_deg=0.0,
                )
            )
            self.controller.start()
            self.plc = self._up(MockPlc(clock=self.clock).start())
            self.meteo_mock = self._up(MockMeteo(seed, self.clock).start())
            self.human = self._up(SimHuman(self.world, self.plc).start())
            cellio = ModbusCellIO(*self.plc.address, timeout_s=5.0)
            meteo = SerialMeteo(self.meteo_mock.port_path, timeout_s=5.0)
            for dev in (tracker, robot, cellio, meteo):
                dev.connect()
            self._started[:0] = [tracker, cellio, meteo]
        except BaseException:
            self.close()
            raise
        operator = PlcOperator(cellio, console, poll_s=0.005)
        self.live = Live(tracker, robot, operator, self.clock, cellio, meteo, close=self.close)

    def _up(self, device):
        self._started.append(device)
        return device

    def close(self) -> None:
        """Clients first, then the mocks, in reverse order of start; one failing stop never keeps the others up."""
        for dev in reversed(self._started):
            fn = getattr(dev, "close", None) or getattr(dev, "stop", None)
            with contextlib.suppress(Exception):
                fn()
        self._started = []
