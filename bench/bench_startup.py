"""Every command's start-up as the test suite runs it (issues 37 and 41): whole processes of the commands `make test`
starts most, now against the tree before they imported only what they need, interleaved.

`make test` starts ~250 `trackcal` processes (run 31, iso9283 28, identify 21, simulate 27, resume 11, export 11,
...); each pays its imports. Per command: the CPU of the whole child process (user + system, resource.getrusage of
the children) and its imports' share (`-X importtime`: the sum of the top-level modules' cumulative times, wall
time of one process), medians of interleaved repeats; the outputs of both trees compared byte for byte (the
report's HTML but its line of the time it was written).

Before: the tree of BASELINE (git archive) first on PYTHONPATH as `trackcal`, as bench_diagnose_process does; same
interpreter and virtual environment. Bytecode cached as on a user's machine (this sandbox sets
PYTHONDONTWRITEBYTECODE: every import would be compiled). Goal (issue 37's start-up round): at least 0.2 s of CPU
less per process for run, resume, replay, export, report and iso9283 plan.

`python -m bench.bench_startup [REPEAT]` (default 5).
"""

from __future__ import annotations

import os
import re
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from bench.bench_diagnose_process import baseline_tree
from bench.goals import check

BASELINE = "3a02ddd"  # main before the start-up round (each command importing only what it needs)
CLI = [sys.executable, "-m", "trackcal.campaign.cli"]
GOAL_S = 0.2  # CPU saved per process, for the commands of GOAL_COMMANDS
GOAL_COMMANDS = ("run", "resume", "replay", "export", "report", "iso9283 plan")
# small cases as the tests': test_campaign_cli.py's plan of 5 configurations with a tenth of its search, and its
# campaign, test_iso9283_campaign.py's one-way ISO plan, test_packaging.py's 20-pose simulated table
PLAN = ["--cell", "kr270", "--configs", "5", "--repeat", "1", "--starts", "20", "--refined", "1", "--noise", "iid"]
ISO = ["--cell", "kr270", "--cycles", "2", "--vap-cycles", "0", "--load", "unloaded", "--velocities", "100"]
STAMP = re.compile(rb"\d{4}-\d\d-\d\d \d\d:\d\d UTC")  # the report's time of writing


def cpu(argv: list[str], env: dict, cwd: Path) -> float:
    """CPU seconds (user + system) of one child process."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run(argv, capture_output=True, env=env, cwd=cwd, check=True)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def import_s(argv: list[str], env: dict, cwd: Path) -> float:
    """Seconds of one process's imports: the top-level modules' cumulative times of `-X importtime`."""
    argv = [argv[0], "-X", "importtime", *argv[1:]]
    done = subprocess.run(argv, capture_output=True, text=True, env=env, cwd=cwd, check=True)
    tops = [line.split("|") for line in done.stderr.splitlines() if line.startswith("import time:")]
    return sum(int(t[1]) for t in tops[1:] if not t[2].startswith("  ")) / 1e6  # [0]: the header


def cases(i: int) -> dict[str, list[str]]:
    """Each command's argv, in the folder of one tree (paths relative to it: the outputs that name their inputs name
    the same ones in both trees), the `i`-th run writing fresh outputs."""
    return {
        "plan": [*CLI, "plan", *PLAN, "--json", f"plan{i}.json"],
        "run": [*CLI, "run", "--cell", "kr270", "--plan", "plan.json", "--sim", "--seed", "4"]
        + ["--session", f"s{i}", "--no-analysis"],
        "resume": [*CLI, "resume", "s", "--no-analysis"],
        "replay": [*CLI, "replay", "s", "--into", f"replay{i}"],
        "export": [*CLI, "export", "s", "--csv", f"export{i}.csv"],
        "report": [*CLI, "report", "analysed", "--out", f"report{i}"],
        "iso9283 plan": [*CLI, "iso9283", "plan", *ISO, "--json", f"iso{i}.json"],
        "simulate": [*CLI, "simulate", "--cell", "kr270", "--poses", "20", "--out", f"sim{i}.csv"],
        "identify": [*CLI, "identify", "sim0.csv", "--cell", "kr270", "--out", f"model{i}.json"],
    }


def prepare(d: Path, env: dict) -> None:
    """The plan, a complete session and identify's table, made by the tree itself in `d`."""
    d.mkdir(parents=True, exist_ok=True)
    run = [*cases(0)["run"][:-3], "--session", "s", "--no-analysis"]  # in the folder `s`
    for argv in (cases(0)["simulate"], [*CLI, "plan", *PLAN, "--json", "plan.json"], run):
        subprocess.run(argv, capture_output=True, env=env, cwd=d, check=True)


def analysed(trees: dict[str, Path], env: dict) -> None:
    """One analysed session for every tree's `report` (run by the first tree): a session's report shows its wall
    times, which two campaigns would not share."""
    first, *others = trees.values()
    argv = [*cases(0)["run"][:-3], "--session", "analysed"]  # analysed at its end
    subprocess.run(argv, capture_output=True, env=env, cwd=first, check=True)
    for d in others:
        shutil.copytree(first / "analysed", d / "analysed")


def fresh(d: Path, i: int) -> None:
    """Remove what the `i`-th run of the cases writes (run and replay refuse an existing session folder)."""
    for name in (f"s{i}", f"replay{i}", f"report{i}"):
        shutil.rmtree(d / name, ignore_errors=True)


def same_outputs(now: Path, before: Path) -> dict[str, bool]:
    """Each output of the last run of both trees, byte for byte."""
    files = ["plan1.json", "export1.csv", "replay1/table.csv", "iso1.json", "sim1.csv", "model1.json"]
    out = {f: (now / f).read_bytes() == (before / f).read_bytes() for f in files}
    for d in (now, before):
        subprocess.run([*CLI, "export", "s1", "--csv", "run.csv"], capture_output=True, cwd=d, check=True)
    out["run session's table"] = (now / "run.csv").read_bytes() == (before / "run.csv").read_bytes()
    html = [STAMP.sub(b"", (d / "report1" / "report.html").read_bytes()) for d in (now, before)]
    out["report1/report.html of the same session (but its time of writing)"] = html[0] == html[1]
    return out


def main(repeat: int = 5) -> None:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        root = baseline_tree(tmp / "tree", BASELINE)
        if root is None:
            print("start-up: no git history for the baseline tree, skipped")
            return
        trees = {"now": env, "before": dict(env, PYTHONPATH=str(root))}
        for name, tree_env in trees.items():
            prepare(tmp / name, tree_env)
        analysed({name: tmp / name for name in trees}, env)
        names = list(cases(0))
        times: dict[tuple[str, str], list[float]] = {(c, t): [] for c in names for t in trees}
        for i in range(1, repeat + 1):  # interleaved: each command in both trees before the next one
            for t in trees:
                fresh(tmp / t, i)
            order = list(trees.items())[:: 1 if i % 2 else -1]  # which tree goes first alternates
            for c in names:
                for t, tree_env in order:
                    times[c, t].append(cpu(cases(i)[c], tree_env, tmp / t))
            print(f"  repeat {i}/{repeat} done", flush=True)
        imports = {}
        for c in names:
            for t, tree_env in trees.items():
                fresh(tmp / t, 0)  # each case writes one of them: the others' outputs are not read again
                imports[c, t] = import_s(cases(0)[c], tree_env, tmp / t)
        print(f"{'command':14s} {'CPU before':>10s} {'CPU now':>8s} {'saved':>6s}  {'imports before':>14s} {'now':>6s}")
        for c in names:
            before, now = statistics.median(times[c, "before"]), statistics.median(times[c, "now"])
            print(
                f"{c:14s} {before:9.2f}s {now:7.2f}s {before - now:5.2f}s  {imports[c, 'before']:13.2f}s "
                f"{imports[c, 'now']:5.2f}s"
            )
            if c in GOAL_COMMANDS:
                saved = f"{before - now:.2f} s"
                check(f"{c}: >= {GOAL_S} s CPU less per process (issue 37)", saved, before - now >= GOAL_S)
        print(f"CPU: medians of {repeat} interleaved whole processes; imports: one process each (-X importtime)")
        for f, same in same_outputs(tmp / "now", tmp / "before").items():
            print(f"  {f}: {'byte-identical' if same else 'DIFFERS'}")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 5)
