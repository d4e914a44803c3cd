"""batch diagnose (issue 26): a plain loop in one process, the local process pool, and a Dask LocalCluster of 2
worker processes, on the same simulated campaigns of mixed causes, in one run; the verdicts must be identical.

Wall time of each whole batch (results folders fresh each time) and the peak resident memory of this process and of
its children (the pool's workers; Dask's run in processes of their own, reported by the cluster). N campaigns,
default 200 as the issue asks; BENCH_BATCH_N sets another number for a quick look.
"""

from __future__ import annotations

import os
import resource
import tempfile
import time
from pathlib import Path

from bench.goals import check
from trackcal.campaign.jobs.batch import BatchOptions, batch, find_campaigns, result_key, run_chunk
from trackcal.campaign.jobs.simulate import SimulateOptions, parse_effects, simulate

N = int(os.environ.get("BENCH_BATCH_N", "200"))
EFFECTS = ["", "backlash:0.05", "joint_compliance:0.05", "encoder_scale:0.05", "thermal_drift:0.05"]


def make_tables(folder: Path, n: int) -> None:
    for i in range(n):
        simulate(SimulateOptions(cell="kr270", out=str(folder / f"c{i:03d}.csv"), poses=25, seed=1000 + i,
                                 effects=parse_effects([EFFECTS[i % len(EFFECTS)]] if EFFECTS[i % len(EFFECTS)]
                                                       else None)))  # fmt: skip


def loop(opts: BatchOptions) -> list[str]:
    """The plain loop a user would write: one campaign after the other in this process."""
    Path(opts.out).mkdir(parents=True, exist_ok=True)
    campaigns = find_campaigns(opts.inputs, opts.cell)
    rows = run_chunk([(c, result_key(c, opts)) for c in campaigns], opts)
    return [r.get("cause", r.get("error")) for r in rows]


def main() -> None:
    from distributed import LocalCluster  # lazy: optional dependency, only this benchmark

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "campaigns"
        folder.mkdir()
        t0 = time.monotonic()
        make_tables(folder, N)
        print(f"{N} campaigns simulated in {time.monotonic() - t0:.0f} s")
        verdicts, walls = {}, {}
        for name in ("loop", "pool", "dask"):
            opts = BatchOptions(task="diagnose", inputs=[str(folder)], out=str(Path(tmp) / name), cell="kr270")
            t0 = time.monotonic()
            if name == "loop":
                verdicts[name] = loop(opts)
            elif name == "pool":
                verdicts[name] = [r.get("cause", r.get("error")) for r in batch(opts).rows]
            else:
                with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cl:
                    t0 = time.monotonic()  # the cluster's start is not the batch's
                    opts = BatchOptions(**{**opts.__dict__, "scheduler": cl.scheduler_address})
                    verdicts[name] = [r.get("cause", r.get("error")) for r in batch(opts).rows]
            walls[name] = time.monotonic() - t0
            print(f"{name}: {walls[name]:.1f} s wall for {N} diagnoses")
        same = verdicts["loop"] == verdicts["pool"] == verdicts["dask"]
        own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        kids = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
        print(f"peak resident memory: this process {own:.0f} MB, largest child {kids:.0f} MB")
        ok = same and walls["pool"] < walls["loop"]
        print(check("batch diagnose: pool faster than a loop, Dask and pool verdicts identical",
                    f"loop {walls['loop']:.0f} s, pool {walls['pool']:.0f} s, Dask {walls['dask']:.0f} s "
                    f"({N} campaigns), verdicts identical: {same}", ok))  # fmt: skip


if __name__ == "__main__":
    main()
