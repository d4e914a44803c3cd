"""batch diagnose (issues 26 and 41): a plain loop in one process, the local process pool, and a Dask LocalCluster of
2 worker processes, on the same simulated campaigns of mixed causes, in one run; the verdicts must be identical.

    python -m bench.bench_batch [--n 200] [--poses 30] [--rounds 10] [--tables DIR] [--keep DIR]

N small campaigns (30 poses each by default, so that 200 diagnoses of each kind finish in one sitting; the KR-270
twin, no hidden effect or one of four causes at 0.05 mm, in turn) are split into rounds; each round is diagnosed by
the three, in an order that rotates from round to round (interleaved, so that the load of a shared machine falls on
all three alike), each into a fresh results folder, each round one `batch` of the pool and one of Dask. The cluster
is started before the first round and its start is timed apart, not counted (issue 41).

Reported: the wall time of each summed over the rounds, their ratios, whether the verdicts (cause, causes, held-out
RMS of both models) are identical across the three; after each round the resident memory (and the private part:
bench.memory) of this process (which ran the loop and holds every result), of the Dask workers, and the peak of the
pool's workers during its batch (a pool lives one batch); a batch's fixed cost and the scheduler's cost per task, of
empty tasks through the same map (campaign.jobs.batch.map_chunks) on the pool and on Dask; and a batch of ESTIMATE_N
campaigns estimated linearly from this run: time = fixed cost + time per campaign, memory = the last round's + the
growth per campaign a process ran (the fitted slope over the rounds after the first) times the campaigns it would
add. A pool worker's growth is not seen across rounds (each batch has a new pool): the loop's (this process's) is
taken, the same code in one process. A Dask worker's growth is distributed's profiler's (profile_history_s): it
stops once the profile history is full, and the estimate is also printed with that cap.

Goal (issue 41): Dask within DASK_OVER_POOL of the pool's time on the same cores once the cluster runs.
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import tempfile
import threading
import time
from pathlib import Path

import dask.config
import numpy as np
from dask.utils import parse_timedelta
from distributed import LocalCluster

from bench.goals import check
from bench.memory import children, peak_rss_mb, private_mb, rss_mb
from trackcal.campaign.cli.blas import limited_blas
from trackcal.campaign.jobs.batch import BatchOptions, batch, find_campaigns, map_chunks, result_key, run_chunk
from trackcal.campaign.jobs.simulate import SimulateOptions, parse_effects, simulate

EFFECTS = ["", "backlash:0.05", "joint_compliance:0.05", "encoder_scale:0.05", "thermal_drift:0.05"]
KINDS = ("loop", "pool", "dask")
DASK_OVER_POOL = 1.2  # issue 41: batch on Dask within 1.2x the local pool on the same cores, the cluster running
ESTIMATE_N = 1000  # issue 41: a 1,000-campaign batch estimated from this run
SAMPLE_S = 0.25  # how often the pool's workers' memory is read while they live
EMPTY_TASKS = 100  # empty tasks whose time gives the scheduler's cost per task
COST_REPEATS = 3  # interleaved repeats of that measurement (medians)


def make_tables(folder: Path, n: int, poses: int, rounds: int, reuse: Path | None = None) -> list[Path]:
    """n tables in `rounds` folders; `reuse`: copied from a folder of tables an earlier run kept (--keep)."""
    dirs = [folder / f"round{r:02d}" for r in range(rounds)]
    for d in dirs:
        d.mkdir(parents=True)
    for i in range(n):
        effect = EFFECTS[i % len(EFFECTS)]
        if reuse is not None:
            shutil.copy(reuse / f"c{i:03d}.csv", dirs[i % rounds] / f"c{i:03d}.csv")
            continue
        simulate(
            SimulateOptions(
                cell="kr270",
                out=str(dirs[i % rounds] / f"c{i:03d}.csv"),
                poses=poses,
                seed=1000 + i,
                effects=parse_effects([effect] if effect else None),
            )
        )
    return dirs


def verdict(row: dict) -> tuple:
    if "error" in row:
        return (row["campaign"], "error", row["error"])
    return (
        row["campaign"],
        row["cause"],
        tuple(row["causes"]),
        row["holdout_geometric_mm"],
        row["holdout_extended_mm"],
    )


def loop(opts: BatchOptions) -> list[tuple]:
    """The plain loop a user would write: one campaign after the other in this process."""
    Path(opts.out).mkdir(parents=True, exist_ok=True)
    campaigns = find_campaigns(opts.inputs, opts.cell)
    return [verdict(r) for r in run_chunk([(c, result_key(c, opts)) for c in campaigns], opts)]


class ChildPeaks:
    """A thread that reads the memory of this process's children (but `skip`) every SAMPLE_S while a pool's batch
    runs: each one's peak resident (VmHWM) and peak private MB, the largest of the children read since `take`."""

    def __init__(self, skip: set[int]) -> None:
        self.skip = skip
        self.rss = self.private = 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="child-peaks", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(SAMPLE_S):
            for pid in set(children()) - self.skip:
                try:
                    self.rss = max(self.rss, peak_rss_mb(pid))
                    self.private = max(self.private, private_mb(pid))
                except (OSError, RuntimeError):  # it ended between the listing and the read
                    continue

    def take(self) -> tuple[float, float]:
        out = (self.rss, self.private)
        self.rss = self.private = 0.0
        return out

    def close(self) -> None:
        self._stop.set()
        self._thread.join()


def task_cost(scheduler: str | None, opts: BatchOptions) -> tuple[float, float]:
    """(a batch's fixed cost, the cost of each further task), s: map_chunks of one empty chunk, then of EMPTY_TASKS
    empty chunks, on the pool (scheduler None) or on Dask."""

    def run(k: int) -> float:
        t0 = time.monotonic()
        list(map_chunks(run_chunk, [[] for _ in range(k)], (opts,), scheduler))  # drained: each chunk's [] result
        return time.monotonic() - t0

    one = run(1)
    return one, (run(EMPTY_TASKS) - one) / (EMPTY_TASKS - 1)


def costs(scheduler: str, tmp: Path) -> dict[str, tuple[float, float]]:
    """task_cost of the pool and of Dask, COST_REPEATS times interleaved: the medians."""
    opts = BatchOptions(task="diagnose", inputs=[], out=str(tmp / "empty"), cell="kr270")
    runs: dict[str, list] = {"pool": [], "dask": []}
    for _ in range(COST_REPEATS):
        runs["pool"].append(task_cost(None, opts))
        runs["dask"].append(task_cost(scheduler, opts))
    return {k: tuple(statistics.median(x) for x in zip(*v, strict=True)) for k, v in runs.items()}


def run_rounds(dirs: list[Path], tmp: Path, cluster: LocalCluster, workers: dict[str, int]) -> tuple[dict, dict, list]:
    """The interleaved rounds: (verdicts by kind, wall s by kind, one memory row per round: campaigns done so far,
    this process's and each Dask worker's (rss, private) MB now, the pool workers' peak (rss, private) MB)."""
    verdicts: dict[str, list] = {k: [] for k in KINDS}
    walls = dict.fromkeys(KINDS, 0.0)
    memory = []
    peaks = ChildPeaks(set(workers.values()))
    try:
        for r, d in enumerate(dirs):
            order = KINDS[r % 3 :] + KINDS[: r % 3]
            pool_peak = (0.0, 0.0)
            for kind in order:
                opts = BatchOptions(
                    task="diagnose",
                    inputs=[str(d)],
                    out=str(tmp / kind / d.name),
                    cell="kr270",
                    scheduler=cluster.scheduler_address if kind == "dask" else None,
                )
                peaks.take()
                t0 = time.monotonic()
                rows = loop(opts) if kind == "loop" else [verdict(x) for x in batch(opts).rows]
                walls[kind] += time.monotonic() - t0
                pool_peak = peaks.take() if kind == "pool" else pool_peak
                verdicts[kind].extend(rows)
            dask_mem = {w: (rss_mb(pid), private_mb(pid)) for w, pid in workers.items()}
            memory.append((len(verdicts["loop"]), (rss_mb(), private_mb()), dask_mem, pool_peak))
            print(
                f"round {r + 1}/{len(dirs)}: " + ", ".join(f"{k} {walls[k]:.0f} s" for k in KINDS) + "; MB resident "
                f"(private): this process {rss_mb():.0f} ({private_mb():.0f}), pool workers' peak {pool_peak[0]:.0f} "
                f"({pool_peak[1]:.0f}), Dask workers "
                + ", ".join(f"{m[0]:.0f} ({m[1]:.0f})" for m in dask_mem.values()),
                flush=True,
            )
    finally:
        peaks.close()
    return verdicts, walls, memory


def slope(xs: list[float], ys: list[float]) -> float:
    """MB per campaign: the least-squares line's slope over the rounds after the first (its imports and caches)."""
    return float(np.polyfit(xs[1:], ys[1:], 1)[0]) if len(xs) > 2 else float("nan")


def profile_history_s() -> float:
    """How long a Dask worker keeps the profile its statistical profiler samples (distributed.worker.profile: every
    10 ms, a tree of the call stacks per 1 s cycle, the last distributed.admin.low-level-log-length cycles kept):
    what makes a worker's memory grow by the campaign until that many cycles have passed (issue 41)."""
    cycles = dask.config.get("distributed.admin.low-level-log-length")
    return cycles * parse_timedelta(dask.config.get("distributed.worker.profile.cycle"))


def estimate(n: int, rounds: int, walls: dict, cost: dict, memory: list) -> None:
    """Print ESTIMATE_N campaigns' time and memory, linear in this run's (see the module's doc)."""
    print(f"estimate for {ESTIMATE_N} campaigns in one batch, linear in this run's {n}:")
    for k in KINDS:
        fixed = cost[k][0] if k in cost else 0.0
        per = (walls[k] - rounds * fixed) / n
        print(f"  {k}: {fixed + per * ESTIMATE_N:.0f} s ({per:.3f} s per campaign + {fixed:.2f} s per batch)")
    done = [float(m[0]) for m in memory]
    mine = slope(done, [m[1][0] for m in memory])
    print(
        f"  this process: {memory[-1][1][0] + mine * (ESTIMATE_N - n):.0f} MB resident ({mine * 1024:.0f} KB per "
        "campaign of the loop; it also holds the pool's and Dask's results)"
    )
    pool_rss = max(m[3][0] for m in memory)
    per_worker = n / rounds / 2  # the campaigns one of 2 pool workers ran in one round's batch
    print(
        f"  each pool worker: {pool_rss + mine * (ESTIMATE_N / 2 - per_worker):.0f} MB resident (its peak in a round, "
        "growing as the loop does)"
    )
    held = profile_history_s() / (2 * walls["dask"] / n)  # campaigns of one of 2 workers in its profile history
    for w in memory[-1][2]:
        ys = [m[2][w][0] for m in memory]
        per = slope([x / 2 for x in done], ys)  # each of the 2 workers ran about half the campaigns
        print(
            f"  Dask worker {w}: {ys[-1] + per * (ESTIMATE_N - n) / 2:.0f} MB resident "
            f"({per * 1024:.0f} KB per campaign it ran), at most "
            f"{ys[-1] + per * max(0.0, min(ESTIMATE_N / 2, held) - n / 2):.0f} MB if the growth is Dask's profile "
            f"history ({profile_history_s():.0f} s, about {held:.0f} campaigns of a worker)"
        )


def report(args: argparse.Namespace, verdicts: dict, walls: dict, cost: dict) -> None:
    same = verdicts["loop"] == verdicts["pool"] == verdicts["dask"]
    errors = sum(1 for v in verdicts["loop"] if v[1] == "error")
    causes = sorted({v[1] for v in verdicts["loop"]})
    print(f"{args.n} diagnoses each ({args.poses} poses; causes found: {', '.join(causes)}; {errors} errors)")
    for k in KINDS:
        print(
            f"  {k}: {walls[k]:.1f} s wall, {walls[k] / args.n:.2f} s per campaign, "
            f"{walls['loop'] / walls[k]:.2f}x the loop"
        )
    print(f"verdicts identical across loop, pool and Dask: {same}")
    for k, (fixed, per_task) in cost.items():
        print(f"  {k}: {fixed * 1000:.0f} ms per batch (one empty task), {per_task * 1000:.1f} ms per further task")
    print(
        check(
            "batch diagnose: pool faster than a loop, loop, pool and Dask verdicts identical",
            f"loop {walls['loop']:.0f} s, pool {walls['pool']:.0f} s, Dask {walls['dask']:.0f} s "
            f"({args.n} campaigns), verdicts identical: {same}",
            same and walls["pool"] < walls["loop"],
        )
    )
    ratio = walls["dask"] / walls["pool"]
    print(
        check(
            f"batch on Dask within {DASK_OVER_POOL}x the local pool, the cluster's start not counted",
            f"Dask {walls['dask']:.0f} s, pool {walls['pool']:.0f} s: {ratio:.2f}x ({args.n} campaigns)",
            ratio <= DASK_OVER_POOL,
        )
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=200, help="campaigns (default 200, as the issue asks)")
    ap.add_argument("--poses", type=int, default=30, help="poses per campaign")
    ap.add_argument("--rounds", type=int, default=10, help="interleaved rounds")
    ap.add_argument(
        "--tables",
        type=Path,
        help="take the tables c000.csv ... of this folder (simulated by an earlier run with the same --poses, "
        "--keep) instead of simulating them",
    )
    ap.add_argument("--keep", type=Path, help="copy the tables c000.csv ... to this folder, for a later --tables")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.monotonic()
        dirs = make_tables(Path(tmp) / "campaigns", args.n, args.poses, args.rounds, args.tables)
        print(
            f"{args.n} campaigns of {args.poses} poses {'copied' if args.tables else 'simulated'} in "
            f"{time.monotonic() - t0:.0f} s"
        )
        if args.keep:
            args.keep.mkdir(parents=True, exist_ok=True)
            for table in Path(tmp, "campaigns").glob("round*/c*.csv"):
                shutil.copy(table, args.keep / table.name)
        t0 = time.monotonic()
        with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
            with cluster.get_client() as client:
                workers = client.run(os.getpid)
            print(f"Dask LocalCluster of 2 worker processes started in {time.monotonic() - t0:.1f} s (not counted)")
            verdicts, walls, memory = run_rounds(dirs, Path(tmp), cluster, workers)
            cost = costs(cluster.scheduler_address, Path(tmp))
        report(args, verdicts, walls, cost)
        estimate(args.n, args.rounds, walls, cost, memory)


if __name__ == "__main__":
    with limited_blas():  # as `python -m bench` and every trackcal command run
        main()
