"""diagnose's peak memory per row (issue 41): the slope over table sizes and the UR10's Series B, against the tree
before this step, whole processes, interleaved.

Each child reads a table, takes its peak resident memory (VmHWM, `bench.memory`: start-up, imports and the table),
runs the diagnosis and takes the peak again; a second child runs it under tracemalloc and takes the traced peak above
the start. The tables: Series B (1,495 rows; the identifiable subset, i.i.d., as bench.bench_diagnose runs it) and
KR-270 twin campaigns of one kind at two sizes (`simulate_campaign`, a joint error map hidden, the cell's irreducible
parameters, i.i.d.). What grows with the rows is the slope between the two sizes (a 100k-row table pays it, not what
is there whatever the rows: imports, a piece of Jacobian rows, Gram matrices); Series B's figure is its peak over
its rows, both. It also prints the verdicts, which must be the same in both trees.

Goal (issue 41): at most 20 KB per row. `python -m bench.bench_diagnose_memory [REPEAT]` (default 1).
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from bench.bench_diagnose_process import baseline_tree
from bench.goals import check
from studies.ur10_ipa.study import DATA, SERIES
from trackcal.calib.doe.poses import random_poses
from trackcal.calib.io.table import write_table
from trackcal.calib.model.cell import load_cell
from trackcal.mocks.twin import Twin, simulate_campaign

BASELINE = "c81a048"  # main before the map's Jacobian was never held whole (issue 41, third step)
GOAL_KB_PER_ROW = 20.0
KR270_POSES = (1200, 2700)  # about 2,700 and 6,200 rows (a pose is measured from 2.2 (station, point) pairs): both past
# the size where a fold fills a piece of Jacobian rows (joint_map_fit.PIECE), so the slope is what grows with the rows
CHILD = """
import json, sys, tracemalloc
from bench.bench_diagnose import series_b
from bench.memory import peak_rss_mb
from trackcal.calib.diagnose import diagnose
from trackcal.calib.io.table import read_table
from trackcal.calib.model.cell import load_cell
from trackcal.calib.model.params import irreducible_params
case, traced = sys.argv[1], sys.argv[2] == "traced"
if case == "series_b":
    chain, table, points, params = series_b()
else:
    cell = load_cell("kr270")
    chain, table, points, params = cell.chain, read_table(case), cell.tool_points, irreducible_params(cell.chain)[0]
start = peak_rss_mb()
if traced:
    tracemalloc.start()
    base = tracemalloc.get_traced_memory()[0]
d = diagnose(chain, table, points, params, None)
peak = (tracemalloc.get_traced_memory()[1] - base) / 2**20 if traced else peak_rss_mb() - start
print(json.dumps({"rows": len(table), "mb": peak, "causes": [c["cause"] for c in d.causes]}))
"""


def child(case: str, mode: str, pythonpath: str | None) -> dict:
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    root = str(Path(__file__).resolve().parents[1])
    env["PYTHONPATH"] = os.pathsep.join(p for p in (pythonpath, root) if p)
    out = subprocess.run(
        [sys.executable, "-c", CHILD, case, mode], capture_output=True, text=True, env=env, check=True
    ).stdout
    return json.loads(out.strip().splitlines()[-1])


def kr270_tables(into: Path) -> list[str]:
    cell = load_cell("kr270")
    paths = []
    for n in KR270_POSES:
        twin = Twin(cell, seed=7, effects={"cyclic_error": 0.05})
        path = into / f"kr270-{n}.csv"
        write_table(simulate_campaign(twin, np.degrees(random_poses(cell, n, np.random.default_rng(7)))), path)
        paths.append(str(path))
    return paths


def main(repeat: int = 1) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        cases = kr270_tables(Path(tmp))
        if (DATA / SERIES["B"]).exists():
            cases.append("series_b")
        else:
            print(f"Series B not at {DATA} (TRACKCAL_IPA_DATA): skipped")
        trees = {"today": None, "before": baseline_tree(Path(tmp) / "before", BASELINE)}
        runs: dict[tuple, list[dict]] = {}
        for _ in range(repeat):
            for case in cases:
                for mode in ("rss", "traced"):
                    for name, tree in trees.items():  # interleaved
                        if name == "today" or tree is not None:
                            runs.setdefault((name, case, mode), []).append(child(case, mode, tree and str(tree)))
    for name in trees:
        for mode in ("rss", "traced"):
            got = {c: runs.get((name, c, mode)) for c in cases}
            if not all(got.values()):
                continue
            mb = {c: statistics.median(r["mb"] for r in rs) for c, rs in got.items()}
            rows = {c: rs[0]["rows"] for c, rs in got.items()}
            (a, b) = cases[:2]
            slope = (mb[b] - mb[a]) * 1024 / (rows[b] - rows[a])
            points = "; ".join(
                f"{Path(c).stem} {rows[c]} rows {mb[c]:.0f} MB ({mb[c] * 1024 / rows[c]:.0f} KB/row)" for c in cases
            )
            print(f"{name:6s} {mode:6s} slope {slope:.1f} KB per row (KR-270); {points}")
            if name == "today" and mode == "rss":
                print(
                    check(
                        "diagnose peak memory <= 20 KB per row (slope)",
                        f"{slope:.1f} KB per row",
                        slope <= GOAL_KB_PER_ROW,
                    )
                )
    for c in cases:
        verdicts = {name: runs[(name, c, "rss")][0]["causes"] for name in trees if (name, c, "rss") in runs}
        print(f"{Path(c).stem}: {verdicts}")
        if len(verdicts) == 2:
            same = verdicts["today"] == verdicts["before"]
            print(
                check(f"diagnose: the same verdict as before ({Path(c).stem})", "same" if same else "DIFFERENT", same)
            )


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 1)
