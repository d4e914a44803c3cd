"""The installed package stands on its own: a wheel built from the repository, installed elsewhere, resolves the
shipped configs (`--cell kr270`) from its package data, from a directory that is not the repository."""

from __future__ import annotations

import json
import os
import subprocess
import sys

from tests.helpers import ROOT
from trackcal.campaign.cli import main


def test_wheel_installed_elsewhere_plans_for_a_shipped_cell(tmp_path):
    wheels, site, work = tmp_path / "wheels", tmp_path / "site", tmp_path / "work"
    work.mkdir()
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "-q"]
    subprocess.run(
        [*pip, "wheel", "--no-deps", "--no-build-isolation", "-w", str(wheels), str(ROOT)], check=True, cwd=tmp_path
    )
    (wheel,) = wheels.glob("trackcal-*.whl")
    subprocess.run([*pip, "install", "--no-deps", "--target", str(site), str(wheel)], check=True, cwd=tmp_path)
    assert (site / "trackcal" / "configs" / "cells" / "kr270.yaml").is_file()
    # one import package, its console script and the wheel's metadata: no generic top-level `calib`, `mocks` ...
    assert sorted(p.name for p in site.iterdir() if not p.name.endswith(".dist-info")) == ["bin", "trackcal"]
    assert [p.name for p in (site / "bin").iterdir()] == ["trackcal"]
    env = {k: v for k, v in os.environ.items() if k not in ("TRACKCAL_CONFIGS", "PYTHONPATH")}
    env["PYTHONPATH"] = str(site)  # the wheel's copy first; numpy, scipy, ... from this interpreter
    code = (
        "import sys, trackcal.campaign as campaign, trackcal.calib.model.cell as cell; "
        "from trackcal.campaign.cli import main; "
        "print(campaign.__file__, cell.CONFIGS); sys.exit(main(sys.argv[1:]))"
    )
    out = subprocess.run(
        [
            sys.executable,
            "-c",
            code,
            "plan",
            "--cell",
            "kr270",
            "--configs",
            "6",
            "--repeat",
            "1",
            "--starts",
            "20",
            "--refined",
            "1",
            "--json",
            "plan.json",
        ],
        cwd=work,
        env=env,
        capture_output=True,
        text=True,
    )
    assert out.returncode == 0, out.stderr
    module_file, configs = out.stdout.splitlines()[0].split()
    assert module_file.startswith(str(site)) and configs.startswith(str(site)), out.stdout
    plan = json.loads((work / "plan.json").read_text())
    # 6 configurations x 3 points x 2 stations: 36 rows at most (108 coordinates) for the KR-270 campaign's 39
    # unknowns (18 robot parameters, 2 stations x 6, 3 points x 3), so rho0 exists
    assert len(plan["poses_deg"]) == 6 and plan["rho0_mm"] > 0


def test_help_and_export_load_neither_pinocchio_nor_matplotlib(tmp_path):
    """Start-up time: the command table is light; a command's module is imported only when it runs."""
    code = (
        "import sys; from trackcal.campaign.cli import main\n"
        "try:\n    main(sys.argv[1:])\nexcept SystemExit:\n    pass\n"
        "print(sorted(m for m in ('pinocchio', 'matplotlib') if m in sys.modules))"
    )
    for argv in (["--help"], ["export", str(tmp_path / "no-session"), "--csv", str(tmp_path / "t.csv")]):
        out = subprocess.run([sys.executable, "-c", code, *argv], cwd=ROOT, capture_output=True, text=True)
        assert out.stdout.strip().splitlines()[-1] == "[]", (argv, out.stdout, out.stderr)


def test_identify_imports_neither_the_search_nor_scipy(tmp_path):
    """Start-up (issue 41): a plain identify needs the solver, the noise floor and the model file, not diagnose's
    search (calib.diagnose.diagnosis and its selection), scipy at all (scipy.optimize a warm-up fit's, scipy.special
    the tests' tails and the t quantile, now calib.identify.student's, scipy.linalg the joint error map's fit),
    pinocchio (gravity torques) or matplotlib (plots): before, the identify process imported all of them (scipy
    alone about 0.25 s of CPU)."""
    table = tmp_path / "t.csv"
    assert main(["simulate", "--cell", "kr270", "--poses", "20", "--out", str(table)]) == 0
    heavy = (
        "trackcal.calib.diagnose.diagnosis",
        "trackcal.calib.diagnose.selection",
        "trackcal.calib.diagnose.joint_map_fit",
        "scipy",
        "scipy.optimize",
        "scipy.special",
        "scipy.linalg",
        "scipy.stats",
        "pinocchio",
        "matplotlib",
    )
    argv = ["identify", str(table), "--cell", "kr270", "--out", str(tmp_path / "m.json")]
    code = (
        "import sys; from trackcal.campaign.cli import main\n"
        f"assert main({argv!r}) == 0\n"
        f"print(sorted(m for m in {heavy!r} if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[-1] == "[]", out.stdout[-500:]


def test_the_warmup_profile_imports_no_scipy_optimize():
    """Start-up (issue 41): diagnose profiles the warm-up's tau on grids (calib.diagnose.warmup), where scipy's bounded
    search imported scipy.optimize, 0.12 s of CPU of a diagnosis of the UR10's Series B."""
    code = (
        "import sys\n"
        "import numpy as np\n"
        "from trackcal.calib.diagnose.warmup import profile\n"
        "from trackcal.calib.doe.poses import random_poses\n"
        "from trackcal.calib.identify.noise import TrackerNoise\n"
        "from trackcal.calib.identify.solver import identify\n"
        "from trackcal.calib.model.cell import load_cell\n"
        "from trackcal.calib.model.params import irreducible_params\n"
        "from trackcal.mocks.twin import Twin, simulate_campaign\n"
        "cell = load_cell('kr270')\n"
        "twin = Twin(cell, seed=1, effects={'thermal_warmup': 0.06})\n"
        "table = simulate_campaign(twin, np.degrees(random_poses(cell, 12, np.random.default_rng(1))))\n"
        "params = irreducible_params(cell.chain)[0]\n"
        "geo = identify(cell.chain, table, cell.tool_points, params, noise=TrackerNoise())\n"
        "assert profile(cell.chain, table, geo, TrackerNoise(), params)['tau_s'] > 0\n"
        "print('scipy.optimize' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[-1] == "False", out.stdout[-500:]
