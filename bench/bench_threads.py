"""BLAS threads: whole `trackcal` processes with the default (one BLAS thread) against two (numpy's default on
the project's 2-core machines), interleaved, in one run.

Commands: `plan` of the paper's section 7.2 case (a process pool of two, as the CLI runs it) and `identify`
of a 1000-row campaign. Printed: medians of wall time and of CPU time (the children's, from os.wait4).
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time

import numpy as np

from bench.bench_identify import campaign
from trackcal.calib.io.table import write_table

REPEATS = 3


def run(argv: list[str], threads: int) -> tuple[float, float]:
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")}
    env["TRACKCAL_BLAS_THREADS"] = str(threads)
    t0 = time.perf_counter()
    before = os.times()
    subprocess.run([sys.executable, "-m", "trackcal.campaign.cli", *argv], check=True, capture_output=True, env=env)
    after = os.times()
    cpu = (after.children_user - before.children_user) + (after.children_system - before.children_system)
    return time.perf_counter() - t0, cpu


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        cell, table = campaign(1000)
        write_table(table, f"{tmp}/t.csv")
        commands = {
            "plan 6 x 3": [
                "plan",
                "--cell",
                "kr270",
                "--configs",
                "6",
                "--repeat",
                "3",
                "--no-visibility",
                "--json",
                f"{tmp}/p.json",
            ],
            "identify 1000 rows": ["identify", f"{tmp}/t.csv", "--cell", "kr270", "--out", f"{tmp}/m.json"],
        }
        for name, argv in commands.items():
            times: dict[int, list[tuple[float, float]]] = {1: [], 2: []}
            for _ in range(REPEATS):
                for threads in (2, 1):
                    times[threads].append(run(argv, threads))
            (w1, c1), (w2, c2) = (np.median(np.array(times[t]), axis=0) for t in (1, 2))
            print(
                f"{name:20s} one BLAS thread {w1:5.1f} s wall {c1:5.1f} s CPU; two {w2:5.1f} s wall {c2:5.1f} s CPU "
                f"-> one thread is {w2 / w1:.1f}x faster (wall)"
            )


if __name__ == "__main__":
    main()
