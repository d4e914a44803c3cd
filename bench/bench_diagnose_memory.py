"""diagnose's peak memory per row on the UR10's Series B (issue 41), against the tree before issue 41's diagnose
memory work, whole processes, interleaved.

Each child reads Series B, takes its peak resident memory (VmHWM, `bench.memory`: start-up, imports and the table),
runs the diagnosis (the identifiable subset, i.i.d., as bench.bench_diagnose runs it) and takes the peak again: the
difference over the rows is what a row costs. It also prints the verdict, which must be the same in both trees.

Goal (issue 41): at most 20 KB per row. `python -m bench.bench_diagnose_memory [REPEAT]` (default 2).
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from bench.bench_diagnose_process import baseline_tree
from bench.goals import check
from studies.ur10_ipa.study import DATA, SERIES

BASELINE = "6401bb5"  # the integration branch before issue 41's diagnose memory work
GOAL_KB_PER_ROW = 20.0
CHILD = """
import json
from bench.bench_diagnose import series_b
from bench.memory import peak_rss_mb
from trackcal.calib.diagnose import diagnose
chain, b, tmac, params = series_b()
start = peak_rss_mb()
d = diagnose(chain, b, tmac, params, None)
print(json.dumps({"rows": len(b), "start_mb": start, "peak_mb": peak_rss_mb(), "cause": d.cause,
                  "causes": [c["cause"] for c in d.causes]}))
"""


def child(pythonpath: str | None) -> dict:
    env = dict(os.environ)
    root = str(Path(__file__).resolve().parents[1])
    env["PYTHONPATH"] = os.pathsep.join(p for p in (pythonpath, root) if p)
    out = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True, env=env, check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def main(repeat: int = 2) -> None:
    if not (DATA / SERIES["B"]).exists():
        print(f"Series B not at {DATA} (TRACKCAL_IPA_DATA): skipped")
        return
    with tempfile.TemporaryDirectory() as tmp:
        base = baseline_tree(Path(tmp), BASELINE)
        runs: dict[str, list[dict]] = {"today": [], "before": []}
        for _ in range(repeat):
            runs["today"].append(child(None))
            if base is not None:
                runs["before"].append(child(str(base)))
    for name, rs in runs.items():
        if not rs:
            continue
        per_row = statistics.median((r["peak_mb"] - r["start_mb"]) * 1024 / r["rows"] for r in rs)
        r, peak = rs[0], statistics.median(x["peak_mb"] for x in rs)
        print(
            f"{name:7s} rows {r['rows']} start {r['start_mb']:.0f} MB peak {peak:.0f} MB: {per_row:.0f} KB per row; "
            f"verdict {r['cause']} ({', '.join(r['causes'])})"
        )
        if name == "today":
            print(
                check(
                    "diagnose peak memory <= 20 KB per row (Series B)",
                    f"{per_row:.0f} KB per row",
                    per_row <= GOAL_KB_PER_ROW,
                )
            )
    if runs["before"]:
        same = all(a["causes"] == b["causes"] for a, b in zip(runs["today"], runs["before"], strict=True))
        print(check("diagnose: the same verdict as before (Series B)", "same" if same else "DIFFERENT", same))


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 2)
