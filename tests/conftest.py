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
# test modules that start one, and the README's examples (a `trackcal mock --cell ur10`), share a worker.
UR_PORTS = re.compile(r"127\.0\.0\.([3-9]|[1-9][0-9]+)\b|MockUr|TwinUr|free_loopback|UrServer|JointFollower"
                      r"|UrController|mocks\.servers\.ur|mock --cell ur")  # fmt: skip


@functools.cache
def starts_a_ur_controller(path: Path) -> bool:
    return path.name in ("test_readme.py", "test_docs.py") or bool(UR_PORTS.search(path.read_text(encoding="utf-8")))


@pytest.hookimpl(tryfirst=True)  # before xdist's own hook, which reads the group into the node id
def pytest_collection_modifyitems(config, items):
    for item in items:
        if starts_a_ur_controller(item.path):
            item.add_marker(pytest.mark.xdist_group("ur-ports"))


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
