"""Fixtures shared by the test modules (helpers are in helpers.py) and the hypothesis profiles.

HYPOTHESIS_PROFILE=ci (what .ci/run sets): derandomized, so CI runs the same examples every time; the default
`dev` profile draws new examples on every run and keeps the failing ones in .hypothesis/. Neither has a deadline:
no test may depend on how fast a loaded machine is.
"""

import os

import pytest
from hypothesis import settings

from tests.helpers import mock_process
from trackcal.calib.model.cell import load_cell
from trackcal.calib.model.params import irreducible_params

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
