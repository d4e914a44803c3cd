"""Reading measurement tables (issues 12 and 16): CPU time at 100k rows against the per-cell reader of issue 12
(csv.reader and one Python float() per cell, rebuilt here as the baseline) and against the general parser alone
(numpy's loadtxt per block, the reader before the grid parser of plain blocks), medians of interleaved repeats;
and the peak memory of a child process reading a 1e6-row table (its VmHWM, bench/memory.py, and above the
imports' own)."""

from __future__ import annotations

import csv
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from unittest import mock

import numpy as np

from bench.goals import check
from trackcal.calib.io import csv_grid
from trackcal.calib.io.table import read_table

HEADER = "seq,t_s,pose,station,point,q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,x_mm,y_mm,z_mm\n"
CHILD = """
import sys
from bench.memory import peak_rss_mb
from trackcal.calib.io.table import read_table
base = peak_rss_mb()
table = read_table(sys.argv[1])
print(len(table), base, peak_rss_mb())
"""


def write_rows(path: Path, n: int, seed: int = 0) -> None:
    """A DESIGN.md table: 9 rows per pose (3 points, 3 stations), q to 1e-4 deg, xyz to 1e-4 mm."""
    rng = np.random.default_rng(seed)
    with path.open("w") as fh:
        fh.write(HEADER)
        for start in range(0, n, 100_000):
            i = np.arange(start, min(start + 100_000, n))
            num = np.column_stack([rng.uniform(-100, 0, (len(i), 6)), rng.uniform(-3000, 3000, (len(i), 3))])
            fh.write(
                "".join(
                    f"{a + 1},{0.1 * a:.3f},Q{a // 9},S{a % 3 + 1},P{a // 3 % 3 + 1},"
                    + ",".join(f"{v:.4f}" for v in r)
                    + "\n"
                    for a, r in zip(i.tolist(), num.tolist(), strict=True)
                )
            )


def per_cell_reader(path: Path) -> int:
    """The baseline: every numeric cell through Python's float()."""
    with path.open(newline="") as fh:
        rows = list(csv.reader(fh))
    numeric = [0, 1, *range(5, 14)]
    values = [[float(row[c]) for c in numeric] for row in rows[1:]]
    return len(values)


def general_reader(path: Path) -> int:
    """read_table with every block given to the general parser (loadtxt), as before the grid parser."""
    with mock.patch.object(csv_grid, "split", return_value=None):
        return len(read_table(path))


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        small, large = Path(tmp) / "t100k.csv", Path(tmp) / "t1m.csv"
        write_rows(small, 100_000)
        readers = {read_table: [], general_reader: [], per_cell_reader: []}
        for _ in range(7):
            for reader, times in readers.items():
                t0 = time.process_time()
                reader(small)
                times.append(time.process_time() - t0)
        t_new, t_general, t_cell = (float(np.median(times)) for times in readers.values())
        ok = check("read 100k table rows < 0.3 s CPU", f"{t_new:.3f} s", t_new < 0.3)
        print(
            f"read 100k rows ({small.stat().st_size / 1e6:.0f} MB): {t_new:.3f} s CPU; general parser alone "
            f"{t_general:.3f} s ({t_general / t_new:.1f}x), per-cell baseline {t_cell:.3f} s ({t_cell / t_new:.1f}x) "
            f"(goal under 0.3 s: {ok})"
        )
        write_rows(large, 1_000_000)
        out = subprocess.run([sys.executable, "-c", CHILD, str(large)], capture_output=True, text=True, check=True)
        n, base, peak = out.stdout.split()
        base, peak = float(base), float(peak)  # MB
        print(
            f"read {n} rows ({large.stat().st_size / 1e6:.0f} MB): peak RSS {peak:.0f} MB, "
            f"{peak - base:.0f} MB above the imports (goal under 1 GB: "
            f"{check('read 1M table rows < 1 GB', f'{peak:.0f} MB', peak < 1024)})"
        )


if __name__ == "__main__":
    main()
