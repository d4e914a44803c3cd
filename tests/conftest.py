"""Fixtures shared by the test modules (helpers are in helpers.py) and the hypothesis profiles.

HYPOTHESIS_PROFILE=ci (what .ci/run sets): derandomized, so CI runs the same examples every time; the default
`dev` profile draws new examples on every run and keeps the failing ones in .hypothesis/. Neither has a deadline:
no test may depend on how fast a loaded machine is.
"""

import os
import signal
import subprocess

import pytest
from hypothesis import settings

from tests.helpers import ROOT, TRACKCAL, wait_for
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
    proc = subprocess.Popen([*TRACKCAL, "mock", "--cell", "kr270", "--seed", "3", "--write-hardware", str(hw)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)  # fmt: skip
    try:
        wait_for(hw, proc)
        yield proc, hw
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
