"""mocks.operator.SimHuman looks at the HMI when trackcal writes to it, not every few milliseconds (issue 41: his
looking every 2 ms of wall time cost 0.9-2 s of CPU a README campaign). What he does with a request is the
campaign tests' (tests/integration/test_sim_sockets.py, the README's run)."""

from __future__ import annotations

import time

import pytest

from trackcal.mocks.cell import World
from trackcal.mocks.clock import VirtualClock
from trackcal.mocks.operator import LOOK_S, SimHuman
from trackcal.mocks.servers.plc import MockPlc
from trackcal.mocks.twin import Twin


class CountingPlc(MockPlc):
    looks = 0

    @property
    def operator_request(self):
        self.looks += 1
        return super().operator_request


@pytest.fixture()
def plc():
    plc = CountingPlc(clock=VirtualClock()).start()
    yield plc
    plc.stop()


def test_with_nothing_written_he_looks_once_per_look_period(kr270, plc):
    """Fails before issue 41: about one look per 2 ms (some 100 in 0.25 s). The bound counts the periods of the
    wall time that really passed, so a slow machine only lowers the count."""
    human = SimHuman(World(Twin(kr270, seed=1)), plc).start()
    t0 = time.monotonic()
    time.sleep(0.25)
    human.stop()
    assert plc.looks <= (time.monotonic() - t0) / LOOK_S + 2


def test_a_write_wakes_whoever_waits_for_it(plc):
    seen = plc.wait_request_written(-1, 0.0)
    plc._lock.acquire()
    plc._request_written()  # what the server does when trackcal writes the lamp or a request register
    plc._lock.release()
    assert plc.wait_request_written(seen, 10.0) == seen + 1
