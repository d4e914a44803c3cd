"""The virtual clock of the mocks: tests and simulations run as fast as the machine goes (the real one is
drivers.interfaces.RealClock).

Everything in `mocks/` that waits or stamps time takes a clock, never `time` directly, so the same
seed gives the same bytes whatever the machine load.
"""

from __future__ import annotations

import threading
import time


class VirtualClock:
    """Monotonic virtual time. `sleep` advances it at once (and optionally a fraction in real time)."""

    def __init__(self, start: float = 0.0, real_fraction: float = 0.0) -> None:
        self._t = float(start)
        self._lock = threading.Lock()
        self.real_fraction = real_fraction

    def now(self) -> float:
        with self._lock:
            return self._t

    def advance(self, seconds: float) -> None:
        if seconds < 0:
            raise ValueError("a clock does not run backwards")
        with self._lock:
            self._t += seconds

    def sleep(self, seconds: float) -> None:
        if seconds <= 0:
            return
        self.advance(seconds)
        if self.real_fraction > 0:
            time.sleep(seconds * self.real_fraction)
