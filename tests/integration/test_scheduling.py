"""make test's scheduler (tests/conftest.py, UrGroupScheduling): which tests xdist deals out as one unit of work.

A test dealt out alone may run on any worker; a unit runs whole on one. The UR group shares fixed ports; a module
that shares a module- or class-scoped fixture between its tests is a unit so that the fixture is made once, not once
per worker (issue 37: make test under 6 minutes on 2 cores)."""

from types import SimpleNamespace

import pytest

from tests.helpers import ROOT


@pytest.fixture
def scheduler(pytestconfig, tmp_path):
    """The scheduler of tests/conftest.py (the conftest pytest loaded), reading test files under tmp_path."""
    conftest = next(
        p
        for p in pytestconfig.pluginmanager.get_plugins()
        if getattr(p, "__file__", None) == str(ROOT / "tests" / "conftest.py")
    )
    sched = object.__new__(conftest.UrGroupScheduling)  # its __init__ needs a worker count, _split_scope does not
    sched.config = SimpleNamespace(rootpath=tmp_path)
    return sched, conftest


@pytest.mark.parametrize("scope", ["module", "class"])
def test_a_module_that_shares_a_fixture_is_one_unit(scheduler, tmp_path, scope):
    """Its tests are one unit; a test of a module sharing none is dealt out alone; the UR group stays one unit
    whatever its modules' fixtures."""
    sched, conftest = scheduler
    (tmp_path / "test_shared.py").write_text(f'@pytest.fixture(scope="{scope}")\ndef campaign():\n    ...\n')
    (tmp_path / "test_alone.py").write_text("@pytest.fixture\ndef plan(tmp_path):\n    ...\n")
    twin_ur = "Twin" + "Ur"  # spelled apart: this module starts no UR controller and is no member of the group
    (tmp_path / "test_ur.py").write_text(f'@pytest.fixture(scope="{scope}")\ndef cell():\n    return {twin_ur}(...)\n')
    units = {sched._split_scope(f"test_shared.py::{name}") for name in ("test_a", "test_b", "Test::test_c")}
    assert units == {"test_shared.py"}
    assert sched._split_scope("test_alone.py::test_a") == "test_alone.py::test_a"
    assert sched._split_scope("test_ur.py::test_a") == conftest.UR_GROUP
