"""issue 41: identify's memory grows by at most 1 KB per row above its start-up (a 1M-row table under 1.1 GB; the
dense Jacobian formed again after the fit once made it 3.4 KB). Peak resident memory of the command in fresh
processes (VmHWM, bench/memory.py: not ru_maxrss, which Linux carries across exec), 100 rows against 50,000: the
difference is what the rows cost, start-up and imports cancel."""

from __future__ import annotations

import subprocess
import sys

from bench.bench_identify import campaign
from trackcal.calib.io.table import write_table

BYTES_PER_ROW = 1024  # issue 41's goal: peak memory at most 1 KB per row above the start-up

RUN = """
import sys
from pathlib import Path
from trackcal.campaign.cli import main
assert main(["identify", sys.argv[1], "--cell", "kr270", "--out", sys.argv[2]]) == 0
print(next(int(x.split()[1]) for x in Path("/proc/self/status").read_text().splitlines() if x.startswith("VmHWM:")))
"""


def peak_kb(table_path, out_path) -> int:
    done = subprocess.run(
        [sys.executable, "-c", RUN, str(table_path), str(out_path)], capture_output=True, text=True, check=True
    )
    return int(done.stdout.strip().splitlines()[-1])


# two fresh processes and a 50k-row campaign: about 4 s (6 s of CPU, mostly generating the table)
def test_identify_memory_per_row(tmp_path):
    peaks, rows = [], (100, 50_000)
    for n in rows:  # the benchmark's KR-270 campaigns: random poses, 2 stations x 3 points, the twin's noise
        write_table(campaign(n)[1], str(tmp_path / f"t{n}.csv"))
        peaks.append(peak_kb(tmp_path / f"t{n}.csv", tmp_path / f"m{n}.json"))
    per_row = (peaks[1] - peaks[0]) * 1024 / (rows[1] - rows[0])
    assert per_row <= BYTES_PER_ROW, f"{per_row:.0f} bytes per row ({peaks[0]} kB at {rows[0]} rows, {peaks[1]} kB)"
