"""make test's scheduler (tests/conftest.py, UnitScheduling): which tests xdist deals out as one unit of work.

A test dealt out alone may run on any worker; a unit runs whole on one. A module that names a loopback address of its
own (a mock UR controller's fixed ports there) is a unit, and no other module names that address; a module that
shares a module- or class-scoped fixture between its tests is a unit so that the fixture is made once, not once per
worker (issue 37: make test under 6 minutes on 2 cores)."""

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
    sched = object.__new__(conftest.UnitScheduling)  # its __init__ needs a worker count, _split_scope does not
    sched.config = SimpleNamespace(rootpath=tmp_path)
    return sched, conftest


@pytest.mark.parametrize("scope", ["module", "class"])
def test_a_module_that_shares_a_fixture_or_names_an_address_is_one_unit(scheduler, tmp_path, scope):
    """Its tests are one unit; a test of a module sharing none and naming no address of its own is dealt out alone,
    127.0.0.1 and .2 being everyone's."""
    sched, _ = scheduler
    address = ".".join(["127", "0", "0", "31"])  # built: this module names no address of its own
    (tmp_path / "test_shared.py").write_text(f'@pytest.fixture(scope="{scope}")\ndef campaign():\n    ...\n')
    (tmp_path / "test_alone.py").write_text("@pytest.fixture\ndef plan(tmp_path):\n    ...\n")
    (tmp_path / "test_local.py").write_text('HOSTS = ["127.0.0.1", "127.0.0.2"]\n')
    (tmp_path / "test_ur.py").write_text(f'HOST = "{address}"\n')
    units = {sched._split_scope(f"test_shared.py::{name}") for name in ("test_a", "test_b", "Test::test_c")}
    assert units == {"test_shared.py"}
    assert sched._split_scope("test_alone.py::test_a") == "test_alone.py::test_a"
    assert sched._split_scope("test_local.py::test_a") == "test_local.py::test_a"
    assert {sched._split_scope(f"test_ur.py::test_{x}") for x in "ab"} == {"test_ur.py"}


def test_no_two_modules_name_the_same_address(scheduler):
    """Two units run at once on two workers: a mock UR controller serves fixed ports, so an address named by two
    modules could be taken twice (the twin's controllers claim theirs from 127.0.0.31 up, mocks/servers/ur)."""
    _, conftest = scheduler
    owners: dict[str, list[str]] = {}
    for path in sorted((ROOT / "tests").rglob("test_*.py")):
        for address in conftest.own_addresses(path):
            owners.setdefault(address, []).append(path.relative_to(ROOT).as_posix())
    assert owners, "no module names an address of its own: OWN_ADDRESS finds nothing"
    shared = {a: ms for a, ms in owners.items() if len(ms) > 1}
    assert not shared, f"addresses named by more than one test module: {shared}"
