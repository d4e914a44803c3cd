"""Fixtures shared by the test modules (helpers are in helpers.py) and the hypothesis profiles.

HYPOTHESIS_PROFILE=ci (what .ci/run sets): derandomized, so CI runs the same examples every time; the default
`dev` profile draws new examples on every run and keeps the failing ones in .hypothesis/. Neither has a deadline:
no test may depend on how fast a loaded machine is.

The repository root is on sys.path in a test run (pyproject's pythonpath, `python -m pytest`) for tests/ and
studies/; its rooms are importable only as trackcal.<room>, so that each module is one module object (issue 37: from
the root, `campaign.cli` and `trackcal.campaign.cli` were two, and an `except` on one's error class missed the other's).
"""

import functools
import importlib.abc
import os
import re
import sys
from pathlib import Path

import pytest
from hypothesis import settings
from xdist.scheduler import LoadGroupScheduling

from tests.helpers import mock_process
from trackcal.calib.model.cell import load_cell
from trackcal.calib.model.params import irreducible_params
from trackcal.campaign.cli.blas import limited_blas

ROOMS = ("calib", "campaign", "drivers", "mocks", "configs")


class RoomsOnlyInsideTrackcal(importlib.abc.MetaPathFinder):
    """Refuses `import calib` (and the other rooms) at the top level: the one way in is `trackcal.calib`."""

    def find_spec(self, name, path=None, target=None):
        if name in ROOMS:
            raise ModuleNotFoundError(f"import trackcal.{name}, not {name} (the rooms live inside trackcal)", name=name)
        return None


sys.meta_path.insert(0, RoomsOnlyInsideTrackcal())

# A module that names a loopback address of its own (127.0.0.3 and up: the mock UR controller's ports are fixed,
# 29999 and 30001-30004, so each controller needs an address) is one unit of work: its tests take turns there. No two
# modules name the same address (tests/integration/test_scheduling.py), and the twin's UR controllers (`trackcal mock
# --cell ur10`, TwinUr) claim a free one (mocks/servers/ur/twin_controller.py claim_loopback), so the units run side
# by side on any worker.
OWN_ADDRESS = re.compile(r"\b127\.0\.0\.([3-9]|[1-9][0-9]+)\b")


@functools.cache
def own_addresses(path: Path) -> frozenset[str]:
    return frozenset(m.group(0) for m in OWN_ADDRESS.finditer(path.read_text(encoding="utf-8")))


# A module whose tests share a module- or class-scoped fixture (a simulated campaign, a plan, a fitted model) runs on
# one worker, so that the fixture is made once: dealt out test by test, each worker made it again (issue 37: the ISO
# 9283 acceptance campaign's fixture, 3 minutes on a loaded machine, was made on both workers).
SHARED_FIXTURE = re.compile(r"""scope=["'](module|class)["']""")


@functools.cache
def shares_a_fixture(path: Path) -> bool:
    return bool(SHARED_FIXTURE.search(path.read_text(encoding="utf-8")))


class UnitScheduling(LoadGroupScheduling):
    """xdist's loadgroup, with the units found by the controller from each test's file: a module naming an address of
    its own or sharing a fixture is one unit; any other test is dealt out alone. Not an `xdist_group` marker: xdist
    3.8's worker marks a grouped test by appending `@group` to `item._nodeid`, and its scheduler reads the group back
    from that suffix; pytest 9.2 builds `item.nodeid` from a structured id (`item._id`), so the suffix never reaches
    the scheduler and the group's tests were dealt out one by one to any worker (pytest-xdist issue #1386, fix open in
    PR #1388). The controller knows each test's file from its node id."""

    def _split_scope(self, nodeid: str) -> str:
        module = nodeid.split("::", 1)[0]
        path = self.config.rootpath / module
        if own_addresses(path) or shares_a_fixture(path):
            return module
        return super()._split_scope(nodeid)


@pytest.hookimpl(optionalhook=True)  # xdist's hook: absent when xdist is not loaded (-p no:xdist)
def pytest_xdist_make_scheduler(config, log):
    return UnitScheduling(config, log) if config.getvalue("dist") == "loadgroup" else None


settings.register_profile("ci", deadline=None, derandomize=True, print_blob=True)
settings.register_profile("dev", deadline=None)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "dev"))


@pytest.fixture(scope="session", autouse=True)
def one_blas_thread():
    """Each test process runs BLAS on one thread, as every trackcal command does (`campaign.cli.blas`: parallelism
    comes from processes), and so do the processes it starts: xdist runs a worker per core already, and OpenBLAS's
    own threads on top of them spin on the cores the other workers need (tests/calib/doe/test_doe.py's two plan tests
    alone on 2 cores: 36 s CPU and 30 s wall with OpenBLAS's default threads, 9.5 s and 10 s with one)."""
    with limited_blas():
        yield


@pytest.fixture(scope="session")
def kr270():
    return load_cell("kr270")


@pytest.fixture(scope="session")
def kr270_params(kr270):
    return irreducible_params(kr270.chain)[0]


@pytest.fixture
def mock_cell(tmp_path):
    """`trackcal mock` in its own process; yields (process, hardware file). Stopped by SIGINT if still running."""
    hw = tmp_path / "H.yaml"
    with mock_process("kr270", 3, hw, sim_speed=50.0) as proc:  # a cell 50x faster than real time (the tests wait less)
        yield proc, hw
