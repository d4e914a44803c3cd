"""The simulated cell around the twin: where the tracker stands, which nest holds the reflector, where
the robot is, the door, and the virtual clock. Every mock server and the simulated operator act on it.

Noise identity: the n-th measurement of (station, point, reported joints) in a campaign. A campaign
resumed after a crash restores these counts from its session (`restore_counts`), so it sees exactly the
numbers an uninterrupted campaign sees.
"""

from __future__ import annotations

import threading
from collections import Counter
from math import copysign

import numpy as np

from trackcal.mocks.clock import VirtualClock
from trackcal.mocks.twin import Twin


def _round4(v: float) -> float:
    """v rounded to 4 decimals as np.round(v, 4) rounds it (v * 10^4, to the nearest integer with ties to even,
    divided by 10^4: the same bits, sign of zero included), in plain floats: a controller reports every cycle of a
    move, and numpy's dispatch on six values cost more than the rest of the world's cycle (issue 41)."""
    return copysign(round(v * 1e4) / 1e4, v)


class NotVisible(Exception):
    """The reflector does not face the tracker (or no reflector is on a nest)."""


class World:
    def __init__(self, twin: Twin, clock: VirtualClock | None = None, measure_s: float = 2.0):
        self.twin = twin
        self.clock = clock or VirtualClock()
        self.measure_s = measure_s
        self.station: str | None = None
        self.point: str | None = None
        self._q = [0.0] * twin.cell.chain.dof  # where the robot is (deg, 4 decimals): q_deg
        self.door_closed = True
        self.counts: Counter = Counter()
        self.t_start = self.clock.now()
        self.lock = threading.Lock()

    @property
    def q_deg(self) -> np.ndarray:
        """Where the robot is (deg, 4 decimals), a new array."""
        return np.array(self._q)

    def robot_at(self, q_deg) -> None:
        """The robot is at (and reports) q_deg (finite); called at every controller cycle while it moves."""
        q = [_round4(v) for v in map(float, q_deg)]
        with self.lock:
            self._q = q
            self.twin.move_to(q)

    def reflector_visible(self) -> bool:
        with self.lock:
            if self.station is None or self.point is None:
                return False
            return self.twin.visible(self.q_deg, self.point, self.station)

    def key(self) -> tuple[str, str, tuple[float, ...]]:
        return (str(self.station), str(self.point), tuple(float(v) for v in self.q_deg))

    def restore_counts(self, measured: list[tuple[str, str, tuple[float, ...]]]) -> None:
        self.counts = Counter(measured)

    def measure(self) -> tuple[float, float, float, float, float, float]:
        """One stationary measurement: position and its standard deviations (mm), station frame."""
        with self.lock:
            if self.station is None or self.point is None:
                raise NotVisible("no reflector on a nest")
            if not self.twin.visible(self.q_deg, self.point, self.station):
                raise NotVisible(f"reflector {self.point} does not face station {self.station}")
            k = self.key()
            n = self.counts[k]
            self.counts[k] += 1
            label = f"{k[0]}/{k[1]}/{'/'.join(f'{v:.4f}' for v in k[2])}/{n}"
            t = self.clock.now() - self.t_start
            x = self.twin.measure(self.q_deg, self.point, self.station, label, t)
            sd = np.sqrt(np.diag(self.twin.noise.covariance(x[None])[0]))
        self.clock.sleep(self.measure_s)
        return (*(float(v) for v in x), *(float(v) for v in sd))
