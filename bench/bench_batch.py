"""batch diagnose (issue 26): a plain loop in one process, the local process pool, and a Dask LocalCluster of 2
worker processes, on the same simulated campaigns of mixed causes, in one run; the verdicts must be identical.

    python -m bench.bench_batch [--n 200] [--poses 30] [--rounds 10] [--tables DIR]

N small campaigns (30 poses each by default, so that 200 diagnoses of each kind finish in one sitting; the KR-270
twin, no hidden effect or one of four causes at 0.05 mm, in turn) are split into rounds; each round is diagnosed by
the three, in an order that rotates from round to round (interleaved, so that the load of a shared machine falls on
all three alike), each into a fresh results folder. Reported: the wall time of each summed over the rounds, their
ratios, whether the verdicts (cause, causes, held-out RMS of both models) are identical across the three, and the
peak resident memory (ru_maxrss) of this process (which ran the loop and holds every result), of its largest child
process (a pool or Dask worker), and of each Dask worker as it reports itself.
"""

from __future__ import annotations

import argparse
import resource
import shutil
import tempfile
import time
from pathlib import Path

from distributed import LocalCluster

from bench.goals import check
from trackcal.campaign.cli.blas import limited_blas
from trackcal.campaign.jobs.batch import BatchOptions, batch, find_campaigns, result_key, run_chunk
from trackcal.campaign.jobs.simulate import SimulateOptions, parse_effects, simulate

EFFECTS = ["", "backlash:0.05", "joint_compliance:0.05", "encoder_scale:0.05", "thermal_drift:0.05"]
KINDS = ("loop", "pool", "dask")


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


def _maxrss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def main() -> None:

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=200, help="campaigns (default 200, as the issue asks)")
    ap.add_argument("--poses", type=int, default=30, help="poses per campaign")
    ap.add_argument("--rounds", type=int, default=10, help="interleaved rounds")
    ap.add_argument(
        "--tables",
        type=Path,
        help="take the tables c000.csv ... of this folder (simulated by an earlier "
        "run with the same --poses) instead of simulating them",
    )
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.monotonic()
        dirs = make_tables(Path(tmp) / "campaigns", args.n, args.poses, args.rounds, args.tables)
        print(
            f"{args.n} campaigns of {args.poses} poses {'copied' if args.tables else 'simulated'} in "
            f"{time.monotonic() - t0:.0f} s"
        )
        verdicts: dict[str, list] = {k: [] for k in KINDS}
        walls = dict.fromkeys(KINDS, 0.0)
        with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
            for r, d in enumerate(dirs):
                order = KINDS[r % 3 :] + KINDS[: r % 3]
                for kind in order:
                    opts = BatchOptions(
                        task="diagnose",
                        inputs=[str(d)],
                        out=str(Path(tmp) / kind / d.name),
                        cell="kr270",
                        scheduler=cluster.scheduler_address if kind == "dask" else None,
                    )
                    t0 = time.monotonic()
                    rows = loop(opts) if kind == "loop" else [verdict(x) for x in batch(opts).rows]
                    walls[kind] += time.monotonic() - t0
                    verdicts[kind].extend(rows)
                print(f"round {r + 1}/{len(dirs)}: " + ", ".join(f"{k} {walls[k]:.0f} s" for k in KINDS), flush=True)
            with cluster.get_client() as client:
                dask_rss = client.run(lambda: resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
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
        kids = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
        workers = ", ".join(f"{v:.0f}" for v in dask_rss.values())
        print(
            f"peak resident memory: this process (loop, all results) {_maxrss_mb():.0f} MB, largest child process "
            f"(pool or Dask worker) {kids:.0f} MB, Dask workers {workers} MB"
        )
        ok = same and walls["pool"] < walls["loop"]
        print(
            check(
                "batch diagnose: pool faster than a loop, loop, pool and Dask verdicts identical",
                f"loop {walls['loop']:.0f} s, pool {walls['pool']:.0f} s, Dask {walls['dask']:.0f} s "
                f"({args.n} campaigns), verdicts identical: {same}",
                ok,
            )
        )


if __name__ == "__main__":
    with limited_blas():  # as `python -m bench` and every trackcal command run
        main()
