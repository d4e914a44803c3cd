"""diagnose: today's algorithm against the one before issue 16, in one process, CPU-time medians.

Cases (issue 16): a 156-row KR-270 campaign with a hidden backlash (twin seed 5, 75 random poses), and
the real UR10 Series B (1,495 poses, i.i.d. weighting, the identifiable subset, as `trackcal diagnose
--weighting iid` runs it). Goals: the KR-270 campaign in under 3 s and Series B in under 15 s, whole
process on 2 cores, one BLAS thread.

Baseline: `calib/diagnose.py` as of commit BASELINE_COMMIT (before forward selection, the linearised
folds and the change-point scan), loaded from git into this process so both run interleaved on the same
machine state. Without git history the baseline cannot be loaded; then only today's figures are printed,
and the baseline measured when this bench was written stands in the comparison (1 BLAS thread, shared
2-core machine, process CPU time): KR-270 40-pose 69-row campaign 1.6-1.9 s per diagnosis; Series B
28.7 s.
"""

from __future__ import annotations

import importlib.util
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from bench.goals import check
from studies.ur10_ipa.study import DATA, SERIES
from trackcal.calib.diagnose import diagnose
from trackcal.calib.doe.poses import random_poses
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.model.cell import load_cell
from trackcal.calib.model.params import irreducible_params
from trackcal.calib.model.subset import identifiable_subset
from trackcal.campaign.importers.ipa_ur10 import POINT, read_ipa_series
from trackcal.mocks.twin import Twin, simulate_campaign

BASELINE_COMMIT = "c29c288"
ROOT = Path(__file__).resolve().parents[1]
UR10_SCRIPT = """
import time, numpy as np
from bench.bench_diagnose import series_b
from trackcal.calib.diagnose import diagnose
chain, b, tmac, params = series_b()
t = time.process_time()
d = diagnose(chain, b, tmac, params, None)
print(d.cause, time.process_time() - t)
"""


# where the modules the baseline imports (relatively, from the flat calib/ of its time) live today
BASELINE_IMPORTS = {
    ".chain": "trackcal.calib.model.chain",
    ".extensions": "trackcal.calib.diagnose.extensions",
    ".identify": "trackcal.calib.identify.solver",
    ".noise": "trackcal.calib.identify.noise",
    ".params": "trackcal.calib.model.params",
    ".table": "trackcal.calib.io.table",
}


def baseline_module():
    """The baseline diagnose module, or None when the git history is not at hand."""
    try:
        src = subprocess.run(
            ["git", "-C", str(ROOT), "show", f"{BASELINE_COMMIT}:calib/diagnose.py"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout
    except (OSError, subprocess.CalledProcessError):
        return None
    for relative, module in BASELINE_IMPORTS.items():
        src = src.replace(f"from {relative} import ", f"from {module} import ")
    spec = importlib.util.spec_from_loader("trackcal.calib._diagnose_baseline", loader=None)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # dataclasses look their module up
    exec(compile(src, f"{BASELINE_COMMIT}:calib/diagnose.py", "exec"), mod.__dict__)
    return mod


def kr270_case():
    cell = load_cell("kr270")
    twin = Twin(cell, seed=5, effects={"backlash": 0.05})
    table = simulate_campaign(twin, np.degrees(random_poses(cell, 75, np.random.default_rng(5))))
    return cell, table, irreducible_params(cell.chain)[0]


def series_b():
    cell = load_cell("ur10-ipa")
    tmac = {POINT: cell.tool_points[POINT]}
    b = read_ipa_series(DATA / SERIES["B"], station="B")
    irr, _ = irreducible_params(cell.chain)
    params, _ = identifiable_subset(cell.chain, irr, np.radians(b.q_deg), tmac)
    return cell.chain, b, tmac, params


def cpu(f):
    t = time.process_time()
    out = f()
    return time.process_time() - t, out


def whole_process_ur10() -> tuple[float, float, str]:
    """(wall s, CPU s of the child process, verdict) of diagnosing Series B in a fresh process."""
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", PYTHONPATH=str(ROOT))
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", UR10_SCRIPT], capture_output=True, text=True, env=env, check=True)
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    child = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, child, out.stdout.split()[0]


def main(repeat: int = 3) -> None:
    base = baseline_module()
    cell, table, params = kr270_case()
    ours, old = [], []
    for _ in range(repeat):  # interleaved
        t, d = cpu(lambda: diagnose(cell.chain, table, cell.tool_points, params, TrackerNoise()))
        ours.append(t)
        if base is not None:
            t, d_old = cpu(lambda: base.diagnose(cell.chain, table, cell.tool_points, params, TrackerNoise()))
            old.append(t)
    t_med = statistics.median(ours)
    ok = check(f"diagnose KR-270 {len(table)} rows < 3 s CPU", f"{t_med:.2f} s", t_med < 3)
    line = f"KR-270 {len(table)} rows: diagnose {t_med:.2f} s CPU (goal < 3 s: {ok}) -> {d.cause}"
    if old:
        line += (
            f"; before issue 16 {statistics.median(old):.2f} s -> {d_old.cause}; "
            f"{statistics.median(old) / statistics.median(ours):.1f}x faster"
        )
    print(line)
    if not series_b_available():
        print("UR10 Series B: data not found (TRACKCAL_IPA_DATA), skipped")
        return
    chain, b, tmac, params_b = series_b()
    t_ours, d = cpu(lambda: diagnose(chain, b, tmac, params_b, None))
    line = f"UR10 Series B {len(b)} rows: diagnose {t_ours:.1f} s CPU -> {d.cause}"
    if base is not None:
        t_old, d_old = cpu(lambda: base.diagnose(chain, b, tmac, params_b, None))
        line += f"; before issue 16 {t_old:.1f} s -> {d_old.cause}; {t_old / t_ours:.1f}x faster"
    print(line)
    wall, child, cause = whole_process_ur10()
    ok16 = check("diagnose UR10 Series B whole process < 15 s wall (issue 16)", f"{wall:.1f} s", wall < 15)
    ok13 = check("diagnose UR10 Series B whole process < 30 s wall (issue 13)", f"{wall:.1f} s", wall < 30)
    print(
        f"UR10 Series B whole process (fresh interpreter, 1 BLAS thread): {child:.1f} s CPU, {wall:.1f} s wall "
        f"(goal < 15 s: {ok16}; < 30 s: {ok13}) -> {cause}"
    )


def series_b_available() -> bool:
    return (DATA / SERIES["B"]).exists()


if __name__ == "__main__":
    main()
