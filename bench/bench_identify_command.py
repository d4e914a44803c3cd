"""`trackcal identify` as a command (issue 41): the whole process against numpy reading the same table.

- CPU: `trackcal identify` on a 100k-row KR-270 table (bench_identify's synthetic campaign: random poses, 2 stations x
  3 points) in a fresh process, against a fresh process that imports numpy and reads the same table with
  `numpy.loadtxt` (its numeric columns); medians of repeats interleaved A, B, A, B, ... (children's user + system
  CPU, `os.times`). Goal: at most 4x (bench.goals, as the two below).
- Memory: the peak resident size (VmHWM, bench/memory.py) of identify on 100 rows and on 100k rows in fresh
  processes; the difference per row is what the rows cost above the start-up. Goal: at most 1 KB per row.
- Start-up: the whole process of identify on a 100-row table, median CPU of fresh processes. Goal: at most 0.5 s.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile

import numpy as np

from bench.bench_identify import campaign
from bench.goals import IDENTIFY_BYTES_PER_ROW, IDENTIFY_LOADTXT_RATIO, IDENTIFY_STARTUP_S, check
from trackcal.calib.io.table import write_table

PEAK = """
import sys
from bench.memory import peak_rss_mb
from trackcal.campaign.cli import main
assert main(["identify", sys.argv[1], "--cell", "kr270", "--out", sys.argv[2]]) == 0
print(peak_rss_mb())
"""
LOADTXT = "import sys, numpy; numpy.loadtxt(sys.argv[1], delimiter=',', skiprows=1, usecols=[0, 1, *range(5, 14)])"


def cpu_of(argv: list[str]) -> tuple[float, str]:
    """CPU seconds (user + system) of a fresh process, and its output."""
    # bytecode cached as on a user's machine (this sandbox sets PYTHONDONTWRITEBYTECODE: every import compiled)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    before = os.times()
    done = subprocess.run(argv, check=True, capture_output=True, text=True, env=env)
    after = os.times()
    return after.children_user - before.children_user + after.children_system - before.children_system, done.stdout


def identify_argv(table: str, out: str) -> list[str]:
    return [sys.executable, "-m", "trackcal.campaign.cli", "identify", table, "--cell", "kr270", "--out", out]


def main(repeats: int = 3, startup_repeats: int = 7) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        big, small = f"{tmp}/t100k.csv", f"{tmp}/t100.csv"
        write_table(campaign(100_000)[1], big)
        write_table(campaign(100)[1], small)
        runs = {"identify": identify_argv(big, f"{tmp}/m.json"), "loadtxt": [sys.executable, "-c", LOADTXT, big]}
        times: dict[str, list[float]] = {name: [] for name in runs}
        for _ in range(repeats):
            for name, argv in runs.items():
                times[name].append(cpu_of(argv)[0])
        t_id, t_np = float(np.median(times["identify"])), float(np.median(times["loadtxt"]))
        ok = check(
            f"identify 100k rows <= {IDENTIFY_LOADTXT_RATIO:.0f}x numpy.loadtxt (whole processes, CPU)",
            f"{t_id / t_np:.1f}x",
            t_id / t_np <= IDENTIFY_LOADTXT_RATIO,
        )
        print(
            f"100k rows, CPU medians of {repeats} interleaved fresh processes: identify {t_id:.2f} s, numpy.loadtxt "
            f"{t_np:.2f} s: {t_id / t_np:.1f}x (goal <= {IDENTIFY_LOADTXT_RATIO:.0f}x: {ok})"
        )
        peaks = [float(cpu_of([sys.executable, "-c", PEAK, t, f"{tmp}/m.json"])[1].split()[-1]) for t in (small, big)]
        per_row = (peaks[1] - peaks[0]) * 2**20 / (100_000 - 100)
        ok = check(
            f"identify peak memory <= {IDENTIFY_BYTES_PER_ROW} bytes per row above the start-up",
            f"{per_row:.0f} bytes per row",
            per_row <= IDENTIFY_BYTES_PER_ROW,
        )
        print(
            f"peak memory: {peaks[0]:.0f} MB at 100 rows, {peaks[1]:.0f} MB at 100k rows: {per_row:.0f} bytes per "
            f"row (goal <= {IDENTIFY_BYTES_PER_ROW}: {ok})"
        )
        start = float(np.median([cpu_of(identify_argv(small, f"{tmp}/m.json"))[0] for _ in range(startup_repeats)]))
        ok = check(
            f"identify 100 rows <= {IDENTIFY_STARTUP_S} s CPU whole process",
            f"{start:.2f} s",
            start <= IDENTIFY_STARTUP_S,
        )
        print(
            f"identify on 100 rows, whole process: {start:.2f} s CPU, median of {startup_repeats} (goal <= "
            f"{IDENTIFY_STARTUP_S} s: {ok})"
        )


if __name__ == "__main__":
    main()
