"""diagnose on the UR10's Series B as whole processes, against identify of the same table and against diagnose before
issue 26 and when stops 30 and 31 landed, interleaved: wall and CPU time medians.

Issue 26's goals: diagnose on Series B in under 4 s whole process on 2 cores, and at most 10x one identification of
the same table (the README's commands: `--weighting iid --params P`), with the same verdict and held-out figures.
Issue 41 keeps the time within 10x (its words: "time within 10x one identify on Series B as now"; where it means CPU
time it says so), while identify itself became faster (Series B 0.52 s at issue 26's close, 0.22 s on 2026-12-05);
the CPU ratio is printed beside it.

Before: the tree of each commit of BASELINES (git archive) imported first on PYTHONPATH as `trackcal`, so all run in
the same interpreter and virtual environment, interleaved on the same machine state. Without git history only
today's figures are printed. CPU is user + system time of the child process; on the shared 2-core machine wall time
depends on the others' load, so the ratios of interleaved medians say more than the seconds.

`python -m bench.bench_diagnose_process [REPEAT]` (default 5).
"""

from __future__ import annotations

import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench.goals import check
from studies.ur10_ipa.study import DATA, SERIES

BASELINES = {  # main before issue 26; when stops 30, 31, 52, 53, 54 and 55 landed
    "before issue 26": "c83d06f",
    "stop 30": "123db2d",
    "stop 31": "54ba974",
    "stop 52": "a93e702",
    "stop 53": "db38f9f",
    "stop 54": "06ba924",
    "stop 55": "3c4bf36",
}
ROOT = Path(__file__).resolve().parents[1]
PARAMS = "px1,py1,phix1,dq2,px2,phix2,phiy2,dq3,px3,phix3,phiy3,dq4,px4,py4,phix4,dq5"  # the README's UR10 section
CLI = [sys.executable, "-m", "trackcal.campaign.cli"]


def run(args: list[str], env: dict | None = None) -> tuple[float, float]:
    """(wall s, CPU s) of one child process."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    subprocess.run(args, capture_output=True, text=True, env=env, check=True)
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def baseline_tree(into: Path, commit: str) -> Path | None:
    """A directory whose `trackcal` is the tree of `commit`, or None without the git history."""
    pkg = into / "trackcal"
    pkg.mkdir(parents=True)
    try:
        archive = subprocess.run(["git", "-C", str(ROOT), "archive", commit], capture_output=True, check=True).stdout
        subprocess.run(["tar", "-x", "-C", str(pkg)], input=archive, check=True)
    except (OSError, subprocess.CalledProcessError):
        return None
    return into


def main(repeat: int = 5) -> None:
    source = DATA / SERIES["B"]
    if not source.exists():
        print("UR10 Series B: data not found (TRACKCAL_IPA_DATA), skipped")
        return
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        table = tmp / "b.csv"
        subprocess.run([*CLI, "import", "ipa-ur10", str(source), "--out", str(table)], capture_output=True, check=True)
        common = [str(table), "--cell", "ur10-ipa", "--weighting", "iid", "--params", PARAMS]
        cases = {
            "identify": ([*CLI, "identify", *common, "--out", str(tmp / "model.json")], None),
            "diagnose": ([*CLI, "diagnose", *common, "--json", str(tmp / "after.json")], None),
        }
        for i, (label, commit) in enumerate(BASELINES.items()):
            root = baseline_tree(tmp / f"tree{i}", commit)
            if root is not None:
                cases[f"diagnose {label}"] = (
                    [*CLI, "diagnose", *common, "--json", str(tmp / f"tree{i}.json")],
                    dict(os.environ, PYTHONPATH=str(root)),
                )
        times: dict[str, list[tuple[float, float]]] = {name: [] for name in cases}
        for i in range(repeat):  # interleaved
            for name, (args, env) in cases.items():
                times[name].append(run(args, env))
                print(
                    f"  run {i + 1}/{repeat} {name}: {times[name][-1][0]:.2f} s wall, {times[name][-1][1]:.2f} s CPU",
                    flush=True,
                )
        med = {
            name: (statistics.median(w for w, _ in ts), statistics.median(c for _, c in ts))
            for name, ts in times.items()
        }
        for name, (wall, cpu) in med.items():
            print(f"UR10 Series B {name}: {wall:.2f} s wall, {cpu:.2f} s CPU (median of {repeat}, whole process)")
        (dw, dc), (iw, ic) = med["diagnose"], med["identify"]
        print(f"diagnose / identify: {dw / iw:.1f}x wall, {dc / ic:.1f}x CPU")
        check("diagnose UR10 Series B whole process < 4 s wall (issue 26)", f"{dw:.2f} s", dw < 4)
        check("diagnose UR10 Series B <= 10x identify, wall (issues 26 and 41)", f"{dw / iw:.1f}x", dw / iw <= 10)
        after = json.loads((tmp / "after.json").read_text())
        for i, (label, commit) in enumerate(BASELINES.items()):
            if f"diagnose {label}" not in med:
                continue
            bw, bc = med[f"diagnose {label}"]
            before = json.loads((tmp / f"tree{i}.json").read_text())
            same = after["cause"] == before["cause"] and all(
                abs(after["holdout"][k] - before["holdout"][k]) <= 1e-6 for k in ("rms_geometric_mm", "rms_extended_mm")
            )
            print(
                f"{label} ({commit}) / now: {bw / dw:.1f}x wall, {bc / dc:.1f}x CPU; verdict {before['cause']}, "
                f"held-out RMS {before['holdout']['rms_geometric_mm']:.6f} -> "
                f"{before['holdout']['rms_extended_mm']:.6f} mm; the same as now within 1e-6 mm: {same}"
            )
        print(
            f"now: verdict {after['cause']}, held-out RMS {after['holdout']['rms_geometric_mm']:.6f} -> "
            f"{after['holdout']['rms_extended_mm']:.6f} mm"
        )


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 5)
