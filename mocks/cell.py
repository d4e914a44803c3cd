"""The simulated cell around the twin: where the tracker stands, which nest holds the reflector, where
the robot is, the door, and the virtual clock. Every mock server and the simulated operator act on it.

Noise identity: the n-th measurement of (station, point, reported joints) in a campaign. A campaign
resumed after a crash restores these counts from its session (`restore_counts`), so it sees exactly the
numbers an uninterrupted campaign sees.
"""

from __future__ import annotations

import threading
from collections import Counter

import numpy as np

from trackcal.mocks.clock import VirtualClock
from trackcal.mocks.twin import Twin


class NotVisible(Exception):
    """The reflector does not face the tracker (or no reflector is on a nest)."""


class World:
    def __init__(self, twin: Twin, clock: VirtualClock | None = None, measure_s: float = 2.0):
        self.twin = twin
        self.clock = clock or VirtualClock()
        self.measure_s = measure_s
        self.station: str | None = None
        self.point: str | None = None
        self.q_deg = np.zeros(twin.cell.chain.dof)
        self.door_closed = True
        self.counts: Counter = Counter()
        self.t_start = self.clock.now()
        self.lock = threading.Lock()

    def robot_at(self, q_deg) -> None:
        """The robot is at (and reports) q_deg; called at every controller cycle while it moves."""
        with self.lock:
            self.q_deg = np.round(np.asarray(q_deg, dtype=float), 4)
            self.twin.move_to(self.q_deg)

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
