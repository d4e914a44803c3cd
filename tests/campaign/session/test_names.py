"""Names are data, never markup: a point, station or session folder whose name holds rich console markup runs,
is killed and resumed like any other, shown as it is; names the cell display (the PLC's HMI: 16 ASCII characters)
shows alike are refused when the cell loads, in one line."""

import io
import json
import os
import signal
import subprocess
import time

import pytest
import yaml
from rich.console import Console

from tests.helpers import ROOT, TRACKCAL, count_measurements, feasible_plan
from trackcal.calib.model.cell import load_cell
from trackcal.campaign.cells.operator import PlcOperator
from trackcal.campaign.session.store import SessionStore

# configs/tools/kr270-3point.yaml's nests under other names; configs/cells/kr270.yaml's stations likewise
NESTS = {"P1": [277, -47, -94], "P2[/bold]": [276, -48, 94], "P3-on-the-wrist-flange": [278, 104, -2]}
STATIONS = {"S1": ([3200, 1500, 900], 200), "S[/]2": ([2800, -1800, 900], 150)}


def write_cell(d, nests=NESTS, stations=STATIONS):
    """The KR-270 cell of configs/cells/kr270.yaml with its points and stations named `nests` and `stations`."""
    d.mkdir(exist_ok=True)
    (d / "tool.yaml").write_text(
        yaml.safe_dump({"name": "named", "points": {k: {"xyz_mm": v, "normal": [1, 0, 0]} for k, v in nests.items()}})
    )
    cell = yaml.safe_load((ROOT / "configs" / "cells" / "kr270.yaml").read_text())
    cell |= {
        "robot": str(ROOT / "configs" / "robots" / "kr270.yaml"),
        "tool": "tool.yaml",
        "stations": {k: {"position_mm": p, "yaw_deg": y} for k, (p, y) in stations.items()},
    }
    (d / "cell.yaml").write_text(yaml.safe_dump(cell))
    return d / "cell.yaml"


def run(*args):
    return subprocess.run([*TRACKCAL, *args], capture_output=True, text=True)


def test_markup_names_run_are_killed_and_resume(tmp_path):
    """`P2[/bold]` and `S[/]2` (a closing tag that matches nothing: rich's MarkupError) and a session folder
    `m[red]x` (a style rich would swallow): the run is killed -9 after its first measurement and resumed; every
    prompt and path is printed as it is, and the resumed campaign completes. The point longer than the display
    (22 characters) is shown cut on the HMI, where the simulated operator finds it as a person would."""
    cell = write_cell(tmp_path / "cell")
    plan = tmp_path / "plan.json"
    plan.write_text(json.dumps(feasible_plan(load_cell(str(cell)), 2, seed=2, repeat=1)))
    d = tmp_path / "m[red]x"
    proc = subprocess.Popen(
        [
            *TRACKCAL,
            "run",
            "--cell",
            str(cell),
            "--plan",
            str(plan),
            "--sim",
            "--seed",
            "4",
            "--session",
            str(d),
            "--no-analysis",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + 60
    while count_measurements(d / "session.sqlite") < 1 and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.002)
    os.kill(proc.pid, signal.SIGKILL)
    assert proc.wait() == -signal.SIGKILL, proc.stderr.read()  # it was still running: no traceback ended it
    out = run("resume", str(d), "--no-analysis")
    assert out.returncode == 0 and out.stderr == "", out.stderr
    text = " ".join(out.stdout.split())  # rich folds long lines
    assert "put the reflector on P2[/bold]" in text and "move the tracker to station S[/]2" in text
    assert "put the reflector on P3-on-the-wrist-flange" in text
    out = run("resume", str(d))
    assert out.returncode == 0 and f"{d}: the campaign is already complete" in " ".join(out.stdout.split())
    store = SessionStore.open(d, readonly=True)
    measured = [e.data for e in store.events() if e.kind == "measurement"]
    assert {m["point"] for m in measured} == set(NESTS) and {m["station"] for m in measured} == set(STATIONS)


def test_plc_operator_line_is_data():
    """The operator's line on a console that reads markup (rich's default): the name is shown, not parsed."""

    class Cell:
        def set_request_lamp(self, on):
            pass

    out = Console(file=io.StringIO(), width=200)
    PlcOperator(Cell(), out.print).offer("move_reflector", "P2[/bold]", "put the reflector on P2[/bold]")
    assert "put the reflector on P2[/bold] (press the acknowledge button)" in out.file.getvalue()


# what the display shows: configs/hardware/cell-plc-registers.md, "HMI request": 16 characters, ASCII ('?' else)
@pytest.mark.parametrize(
    ("what", "a", "b", "shown"),
    [
        ("points", "Reflector-nest-left-1", "Reflector-nest-left-2", "Reflector-nest-l"),
        ("points", "Pé", "Pè", "P?"),
        ("stations", "Station-behind-fence-A", "Station-behind-fence-B", "Station-behind-f"),
    ],
)
def test_names_shown_alike_are_refused(tmp_path, what, a, b, shown):
    nests, stations = dict(NESTS), dict(STATIONS)
    if what == "points":
        nests |= {a: NESTS["P1"], b: NESTS["P3-on-the-wrist-flange"]}
    else:
        stations |= {a: STATIONS["S1"], b: STATIONS["S[/]2"]}
    cell = write_cell(tmp_path / "cell", nests, stations)
    plan = tmp_path / "plan.json"
    plan.write_text(json.dumps({"poses_deg": [[0, -90, 90, 0, 0, 0]], "repeat": 1}))
    out = run("run", "--cell", str(cell), "--plan", str(plan), "--sim", "--session", str(tmp_path / "s"))
    assert out.returncode == 2 and len(out.stderr.splitlines()) == 1, out.stderr
    assert f"{what} " in out.stderr and f"both show as {shown!r}" in out.stderr
    assert f"{a!r} and {b!r}" in out.stderr or f"{b!r} and {a!r}" in out.stderr
    assert not (tmp_path / "s").exists()
