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

ROOMS = ("calib", "campaign", "drivers", "mocks", "configs")


class RoomsOnlyInsideTrackcal(importlib.abc.MetaPathFinder):
    """Refuses `import calib` (and the other rooms) at the top level: the one way in is `trackcal.calib`."""

    def find_spec(self, name, path=None, target=None):
        if name in ROOMS:
            raise ModuleNotFoundError(f"import trackcal.{name}, not {name} (the rooms live inside trackcal)", name=name)
        return None


sys.meta_path.insert(0, RoomsOnlyInsideTrackcal())

# The mock UR controller serves fixed ports (29999, 30001-30004) on a loopback address, picked free from 127.0.0.31
# up or named by the test: two xdist workers (make test: -n auto, --dist loadgroup) could take the same one, so the
# test modules that start one, and the README's examples (a `trackcal mock --cell ur10`, and examples that build on
# each other in one module-scoped folder), share a worker: the group UR_GROUP.
UR_GROUP = "ur-ports"
UR_PORTS = re.compile(
    r"127\.0\.0\.([3-9]|[1-9][0-9]+)\b|MockUr|TwinUr|free_loopback|UrServer|JointFollower"
    r"|UrController|mocks\.servers\.ur|mock --cell ur"
)


@functools.cache
def starts_a_ur_controller(path: Path) -> bool:
    return path.name in ("test_readme.py", "test_docs.py") or bool(UR_PORTS.search(path.read_text(encoding="utf-8")))


# A module whose tests share a module- or class-scoped fixture (a simulated campaign, a plan, a fitted model) runs on
# one worker, so that the fixture is made once: dealt out test by test, each worker made it again (issue 37: the ISO
# 9283 acceptance campaign's fixture, 3 minutes on a loaded machine, was made on both workers).
SHARED_FIXTURE = re.compile(r"""scope=["'](module|class)["']""")


@functools.cache
def shares_a_fixture(path: Path) -> bool:
    return bool(SHARED_FIXTURE.search(path.read_text(encoding="utf-8")))


class UrGroupScheduling(LoadGroupScheduling):
    """xdist's loadgroup, with UR_GROUP found by the controller from each test's file. xdist 3.8's worker marks a
    grouped test by appending `@group` to `item._nodeid`, and its scheduler reads the group back from that suffix;
    pytest 9.2 builds `item.nodeid` from a structured id (`item._id`), so the suffix never reaches the scheduler and
    the group's tests were dealt out one by one to any worker (pytest-xdist issue #1386, fix open in PR #1388):
    whatever marker a hook added, and however early. The controller knows each test's file from its node id. A
    module that shares a fixture between its tests is one unit of work too (SHARED_FIXTURE)."""

    def _split_scope(self, nodeid: str) -> str:
        module = nodeid.split("::", 1)[0]
        if starts_a_ur_controller(self.config.rootpath / module):
            return UR_GROUP
        if shares_a_fixture(self.config.rootpath / module):
            return module
        return super()._split_scope(nodeid)


@pytest.hookimpl(optionalhook=True)  # xdist's hook: absent when xdist is not loaded (-p no:xdist)
def pytest_xdist_make_scheduler(config, log):
    return UrGroupScheduling(config, log) if config.getvalue("dist") == "loadgroup" else None


@pytest.fixture(autouse=True)
def one_worker_per_group(request, tmp_path_factory):
    """Under xdist, each test of UR_GROUP writes its worker's id to a file all workers share (the run's base
    temporary folder, whose popen-gwN sub-folders are the workers'): a second id fails the test that finds it."""
    worker = os.environ.get("PYTEST_XDIST_WORKER")
    if worker is None or not starts_a_ur_controller(request.node.path):
        return
    ledger = tmp_path_factory.getbasetemp().parent / f"{UR_GROUP}.workers"
    with ledger.open("a", encoding="utf-8") as f:  # one short line per append: whole, whoever else appends
        f.write(f"{worker} {request.node.nodeid}\n")
    others = {line for line in ledger.read_text(encoding="utf-8").splitlines() if line.split(" ", 1)[0] != worker}
    if others:
        pytest.fail(f"the {UR_GROUP} group runs on two xdist workers: {worker} here, and {sorted(others)[0]}")


settings.register_profile("ci", deadline=None, derandomize=True, print_blob=True)
settings.register_profile("dev", deadline=None)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "dev"))


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
