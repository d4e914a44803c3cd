"""One `trackcal run --sim` derives each thing once (issue 37, "Derive each thing once"): the cell is built once, the
plan's steps once, the noise floor once, the TCP difference at most once, and no two identifications fit the same
model to the same table (the nominal "before" fit and the geometric fit once each, then one per candidate cause)."""

import json
import sys
from collections import defaultdict

import pytest

from tests.helpers import feasible_plan, inproc_live
from trackcal.calib.diagnose.noise_floor import noise_floor
from trackcal.calib.identify.solver import identify
from trackcal.calib.model.cell import Cell
from trackcal.campaign.cli import main
from trackcal.campaign.engine.steps import plan_steps
from trackcal.campaign.report.tcp import tcp_difference

SEED = 3


def counted(monkeypatch, fn, calls: list) -> None:
    """Every binding of `fn` in trackcal's modules replaced by one that records its arguments in `calls`."""

    def recording(*args, **kw):
        calls.append((args, kw))
        return fn(*args, **kw)

    for module in list(sys.modules.values()):
        if getattr(module, "__name__", "").startswith("trackcal") and getattr(module, fn.__name__, None) is fn:
            monkeypatch.setattr(module, fn.__name__, recording)


def fit_key(args, kw) -> tuple:
    """What an identification fits: the table's rows, the robot parameters, the extension and the weighting."""
    chain, table, _tool, params = args[:4]
    ext = kw.get("extension")
    return (
        table.q_deg.tobytes(),
        table.xyz.tobytes(),
        tuple(p.name for p in params),
        chain.name,
        None if ext is None else repr(ext),
        repr(kw.get("noise")),
    )


@pytest.fixture
def counts(kr270, monkeypatch):
    """The calls of one `trackcal run --sim` (in process, the twin's in-process devices instead of its sockets: the
    derivations do not depend on the transport)."""
    calls = defaultdict(list)
    for fn in (identify, noise_floor, plan_steps, tcp_difference):
        counted(monkeypatch, fn, calls[fn.__name__])
    built = Cell.__init__

    def building(self, *args, **kw):
        calls["cell"].append((args, kw))
        built(self, *args, **kw)

    monkeypatch.setattr(Cell, "__init__", building)
    monkeypatch.setattr(
        "trackcal.campaign.jobs.campaign._open_cell", lambda store, cell, *a, **kw: inproc_live(cell, SEED, store)[1]
    )
    return calls


def test_one_run_derives_each_thing_once(kr270, counts, tmp_path):
    # 6 configurations measured once: enough rows to identify the irreducible set (README's `plan --configs 6`)
    plan = tmp_path / "plan.json"
    plan.write_text(json.dumps(feasible_plan(kr270, 6, seed=5, repeat=1)))
    d = tmp_path / "session"
    assert main(["run", "--cell", "kr270", "--plan", str(plan), "--sim", "--seed", str(SEED), "--session", str(d)]) == 0
    assert (d / "report" / "report.html").is_file()  # the whole end of the run happened
    assert len(counts["cell"]) == 1
    assert len(counts["plan_steps"]) == 1
    assert len(counts["noise_floor"]) == 1
    assert len(counts["tcp_difference"]) <= 1
    fits = [fit_key(*c) for c in counts["identify"]]
    assert len(fits) >= 2 and len(set(fits)) == len(fits)  # the "before" and the geometric fit at least, each once
