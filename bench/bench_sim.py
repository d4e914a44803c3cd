"""`trackcal run --sim` CPU per measurement on the README's plan (issue 41), this tree against another checkout; the
goal is bench.goals.SIM_CPU_PER_MEASUREMENT_MS, a third of the 337 ms the issue was filed with.

The README's campaign (`trackcal plan --cell kr270 --configs 6 --repeat 3`, then `trackcal run --cell kr270 --plan
plan.json --sim --seed 1`) as whole processes, CPU time of every process (resource.getrusage of the children: the
command, its threads, the mocks), not wall time, in repeats interleaved with the same command of the checkout at
--base (main before the change: `git worktree add --detach DIR main`), which runs on this tree's interpreter with
DIR first on the import path. The measurement rows of the two sessions' exported tables are compared byte for byte.
Sessions live on a tmpfs when the machine has one, as the tests' do.

    python -m bench.bench_sim --base /tmp/main-checkout [--repeats 3]
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from bench.goals import SIM_CPU_PER_MEASUREMENT_MS, check


def cpu_of(cmd: list[str], env: dict, cwd: Path) -> float:
    """CPU seconds (user + system) of one child process and everything it waited for."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run(cmd, env=env, cwd=cwd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def tree_env(base: Path | None, root: Path) -> dict:
    """The environment that runs `trackcal` from `base` (None: this tree, as installed)."""
    env = dict(os.environ)
    if base is not None:
        links = root / "base-links"
        links.mkdir(exist_ok=True)
        if not (links / "trackcal").exists():
            (links / "trackcal").symlink_to(base.resolve())
        env["PYTHONPATH"] = f"{links}{os.pathsep}{base.resolve()}"
    return env


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", type=Path, help="a checkout of the tree to compare with (main); none: skipped")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    if args.base is None:
        print("skipped: no --base checkout to compare with (python -m bench.bench_sim --base DIR)")
        return
    shm = "/dev/shm" if os.path.isdir("/dev/shm") and os.access("/dev/shm", os.W_OK) else None
    root = Path(tempfile.mkdtemp(prefix="bench-sim-", dir=shm))
    trackcal = [sys.executable, "-c", "from trackcal.campaign.cli import main; main()"]
    trees = {"base": tree_env(args.base, root), "this": tree_env(None, root)}
    cpu: dict[str, list[float]] = {name: [] for name in trees}
    tables: dict[str, set[bytes]] = {name: set() for name in trees}
    try:
        subprocess.run(
            [*trackcal, "plan", "--cell", "kr270", "--configs", "6", "--repeat", "3", "--json", "plan.json"],
            env=trees["this"],
            cwd=root,
            check=True,
            stdout=subprocess.DEVNULL,
        )
        for rep in range(args.repeats):
            for name, env in trees.items():
                session = root / f"{name}-{rep}"
                cpu[name].append(
                    cpu_of(
                        [
                            *trackcal,
                            "run",
                            "--cell",
                            "kr270",
                            "--plan",
                            "plan.json",
                            "--sim",
                            "--seed",
                            "1",
                            "--session",
                            str(session),
                        ],
                        env,
                        root,
                    )
                )
                tables[name].add((session / "table.csv").read_bytes())
                print(f"  {name}: {cpu[name][-1]:.1f} s CPU", flush=True)
    finally:
        shutil.rmtree(root, ignore_errors=True)
    rows = len(next(iter(tables["this"])).splitlines()) - 1
    same = len(tables["this"]) == 1 and tables["this"] == tables["base"]
    med = {name: statistics.median(times) for name, times in cpu.items()}
    ratio = med["this"] / med["base"]
    print(
        f"{rows} measurements; median CPU of {args.repeats}: base {med['base']:.1f} s "
        f"({med['base'] / rows * 1000:.0f} ms a measurement), this tree {med['this']:.1f} s "
        f"({med['this'] / rows * 1000:.0f} ms), {ratio:.2f}x; "
        f"tables {'identical' if same else 'DIFFERENT'}"
    )
    per_measurement = med["this"] / rows * 1000
    verdict = check(
        f"run --sim CPU per measurement <= {SIM_CPU_PER_MEASUREMENT_MS:.0f} ms (a third of 337), the same tables",
        f"{per_measurement:.0f} ms ({ratio:.2f}x the base's), tables {'identical' if same else 'DIFFERENT'}",
        per_measurement <= SIM_CPU_PER_MEASUREMENT_MS and same,
    )
    print(f"goal: at most {SIM_CPU_PER_MEASUREMENT_MS:.0f} ms a measurement: {per_measurement:.0f} ms, {verdict}")


if __name__ == "__main__":
    main()
