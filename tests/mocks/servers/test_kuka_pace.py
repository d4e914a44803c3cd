"""The free-running mock KUKA controller's pace (mocks/servers/kuka/controller.py `_pace`, issue 40: 186 frames/s
against 250 at 4 ms, because it slept a whole cycle after each cycle's work): cycle n is due n periods after the
first on the wall clock, whatever the work took, with no drift; a cycle late by more than a period is counted as an
overrun, late cycles catch up, and past CATCH_UP_CYCLES the schedule starts again. The wall clock is a fake one the
test moves: no wall-clock speed involved."""

from __future__ import annotations

import pytest

from trackcal.mocks.clock import VirtualClock
from trackcal.mocks.servers.krc4.controller import KRC4_CYCLE_S, MockKrc4
from trackcal.mocks.servers.kuka.controller import CATCH_UP_CYCLES

HOME = (0.0, -90.0, 90.0, 0.0, 90.0, 0.0)


class FakeWall:
    def __init__(self) -> None:
        self.t = 1000.0
        self.slept: list[float] = []

    def now(self) -> float:
        return self.t

    def sleep(self, seconds: float) -> None:
        self.slept.append(seconds)
        self.t += max(0.0, seconds)


def _mock(real_fraction: float = 1.0):
    wall = FakeWall()
    mock = MockKrc4(
        ("127.0.0.1", 0), ("127.0.0.1", 9), VirtualClock(real_fraction=real_fraction), HOME, wall_clock=wall
    )
    return mock, wall


@pytest.mark.parametrize("cycle_s", [KRC4_CYCLE_S, 0.012])
def test_each_cycle_is_due_a_period_after_the_last_whatever_its_work_took(cycle_s):
    mock, wall = _mock()
    mock.cycle_s = cycle_s
    try:
        start = wall.t
        work = [0.3, 0.9, 0.0, 0.5, 0.99] * 40  # fractions of a cycle spent exchanging before the pace
        for w in work:
            wall.t += w * cycle_s
            mock._pace()
        # the first cycle sets the schedule at its end; every later one ends exactly a period after the one before
        assert wall.t - start == pytest.approx(len(work) * cycle_s + work[0] * cycle_s, abs=1e-9)
        assert mock.overruns == 0
        assert mock.clock.now() == pytest.approx(len(work) * cycle_s)  # the controller's time: one cycle each
    finally:
        mock.stop()


def test_late_cycles_catch_up_and_a_stall_past_the_catch_up_bound_starts_a_new_schedule():
    mock, wall = _mock()
    try:
        p = KRC4_CYCLE_S
        mock._pace()  # the schedule: due at now + p
        due = wall.t
        wall.t += 1.5 * p  # the work of the next cycle took 1.5 periods: 0.5 behind, the next runs at once
        mock._pace()
        assert wall.t == pytest.approx(due + 1.5 * p) and mock.overruns == 0
        mock._pace()  # back on schedule: due + 2 p
        assert wall.t == pytest.approx(due + 2 * p)
        wall.t += 5 * p  # a stall of 5 periods: 4 behind, the late cycles run at once until on schedule again
        for _ in range(5):
            mock._pace()
        assert wall.t == pytest.approx(due + 7 * p)  # no sleep: the cycles of the stall caught up
        mock._pace()
        assert wall.t == pytest.approx(due + 8 * p) and mock.overruns >= 1  # on the schedule of the first cycle
        wall.t += (CATCH_UP_CYCLES + 5) * p  # a stall past the bound
        before = mock.overruns
        mock._pace()
        assert mock.overruns == before + 1
        resumed = wall.t
        mock._pace()
        assert wall.t == pytest.approx(resumed + p)  # a new schedule from the stall's end, no burst
    finally:
        mock.stop()


def test_a_virtual_clock_without_real_time_is_not_paced():
    mock, wall = _mock(real_fraction=0.0)
    try:
        for _ in range(10):
            mock._pace()
        assert wall.slept == [] and mock.clock.now() == pytest.approx(10 * KRC4_CYCLE_S)
    finally:
        mock.stop()
