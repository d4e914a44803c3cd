"""`run --sim` campaign time: the simulated KR C2 free-running (every 12 ms cycle exchanged, paced by wall time:
how `run --sim` ran before issue 16, and how `trackcal mock` still serves another process) against the controller
in lockstep with trackcal's client on the virtual clock, which skips the cycles the robot stands through unread.

The campaign is the README's: `trackcal plan --cell kr270 --configs 6 --repeat 3` (seed 0), run on the twin with
seed 1 (run_stored of SimCell, the measurement part of `trackcal run --sim`; the analysis after it is the same
for both). Sessions live on a tmpfs when the machine has one, as the tests' do (the store fsyncs every event).
Wall and CPU time (this process: every thread of trackcal and of the mocks) are medians of repeats interleaved
in one process. In the same run the exported table of the lockstep controller without skipping (every idle
cycle exchanged) is compared byte for byte with the skipping one's, and the free-running one's measurements
(everything but the wall-paced timestamps) with both.

    python -m bench.bench_sim_campaign [--repeats 3]
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import io
import os
import shutil
import statistics
import tempfile
import time
from pathlib import Path

from bench.goals import check
from trackcal.calib.model.cell import load_cell
from trackcal.campaign.cells.sim import SimCell
from trackcal.campaign.jobs.campaign import new_session, run_stored
from trackcal.campaign.jobs.plan import PlanOptions, build_design, search_doc
from trackcal.campaign.session.session import write_export

SEED = 1
MODES = {
    "free (before)": {"lockstep": False},
    "lockstep, every cycle": {"skip_idle": False},
    "lockstep, idle skipped": {},
}


def readme_plan(cell) -> dict:
    options = PlanOptions(configs=6, repeat=3, seed=0)
    return search_doc(build_design(cell, options), options)


def run(cell, plan: dict, root: Path, name: str, **sim_kw) -> tuple[float, float, bytes, dict]:
    """(wall s, CPU s, exported table bytes, controller counts) of one simulated campaign."""
    directory = root / name
    shutil.rmtree(directory, ignore_errors=True)
    store, _ = new_session(directory, "kr270", plan, "sim", SEED)
    sim = SimCell(cell, SEED, store, **sim_kw)
    try:
        w0, c0 = time.perf_counter(), time.process_time()
        with contextlib.redirect_stdout(io.StringIO()):  # the simulated operator's prompts, 16 per run
            run_stored(store, sim.live)
        wall, cpu = time.perf_counter() - w0, time.process_time() - c0
        ctl = sim.controller
        counts = {"cycles": ctl.cycles, "frames": ctl.frames_sent, "skipped": ctl.idle_skipped}
    finally:
        sim.close()
    write_export(store, directory / "export.csv")
    return wall, cpu, (directory / "export.csv").read_bytes(), counts


def without_time(table: bytes) -> list[list[str]]:
    rows = list(csv.reader(io.StringIO(table.decode())))
    col = rows[0].index("t_s")
    return [r[:col] + r[col + 1 :] for r in rows]


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    cell = load_cell("kr270")
    plan = readme_plan(cell)
    shm = "/dev/shm" if os.path.isdir("/dev/shm") and os.access("/dev/shm", os.W_OK) else None
    root = Path(tempfile.mkdtemp(prefix="bench-sim-", dir=shm))
    times: dict[str, list[tuple[float, float]]] = {m: [] for m in MODES}
    tables: dict[str, bytes] = {}
    free_t_s_differ = False  # the free-running controller's idle cycles advance the clock at the machine's pace
    try:
        for rep in range(args.repeats):
            for mode, kw in MODES.items():
                if mode == "lockstep, every cycle" and rep:  # timed once: it is there for the byte comparison
                    continue
                wall, cpu, table, counts = run(cell, plan, root, f"{len(times[mode])}-{mode[:4]}", **kw)
                times[mode].append((wall, cpu))
                first = tables.setdefault(mode, table)
                if rep and first != table:
                    if mode != "free (before)" or without_time(first) != without_time(table):
                        raise SystemExit(f"{mode}: two runs exported different measurements")
                    free_t_s_differ = True
                print(f"  {mode:24s} wall {wall:6.1f} s  CPU {cpu:6.1f} s  {counts}", flush=True)
    finally:
        shutil.rmtree(root, ignore_errors=True)
    n = len(without_time(tables["free (before)"])) - 1
    med = {m: (statistics.median(w for w, _ in t), statistics.median(c for _, c in t)) for m, t in times.items()}
    for mode, (wall, cpu) in med.items():
        print(f"{mode:24s} median of {len(times[mode])}: wall {wall:6.1f} s, CPU {cpu:6.1f} s")
    skip, free = med["lockstep, idle skipped"], med["free (before)"]
    same_bytes = tables["lockstep, idle skipped"] == tables["lockstep, every cycle"]
    same_values = without_time(tables["lockstep, idle skipped"]) == without_time(tables["free (before)"])
    print(
        f"exported table, idle skipped vs every cycle exchanged: {'byte-identical' if same_bytes else 'DIFFERENT'}; "
        f"vs free-running, every column but t_s: {'identical' if same_values else 'DIFFERENT'}; repeated "
        f"lockstep runs byte-identical, free-running runs' t_s {'differ' if free_t_s_differ else 'agree'}"
    )
    ratio = skip[0] / free[0]
    verdict = check(
        f"run --sim {n} measurements in half the time, table unchanged",
        f"wall {skip[0]:.1f} vs {free[0]:.1f} s ({ratio:.2f}x), CPU {skip[1]:.1f} vs {free[1]:.1f} s, "
        f"table {'byte-identical' if same_bytes and same_values else 'CHANGED'}",
        ratio <= 0.5 and same_bytes and same_values,
    )
    print(f"goal: {n} measurements in half the time, table unchanged: {ratio:.2f}x, {verdict}")


if __name__ == "__main__":
    main()
