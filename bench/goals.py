"""The goals the benchmarks check (issues 13, 16 and 41: bench_identify_command's identify against numpy.loadtxt, its
memory per row and its start-up), each printed where it is measured and again, all together, at the end of
`python -m bench` (make bench)."""

from __future__ import annotations

RESULTS: list[tuple[str, str, bool]] = []

# issue 41: `trackcal run --sim` on the README's plan at most a third of the CPU per measurement it cost when the
# issue was filed (337 ms, docs/design/sim-cpu.md), the same session bytes (bench/bench_sim.py)
SIM_CPU_PER_MEASUREMENT_MS = 337 / 3
# issue 41: `trackcal identify` as a command (bench/bench_identify_command.py): on a 100k-row table at most 4x the CPU
# of a process that reads it with numpy.loadtxt (15x when the issue was filed; 4.7x before its third round, 3.3-3.6x
# after), at most 1 KB of peak memory per row above the start-up, and a 100-row identify at most 0.5 s of CPU
IDENTIFY_LOADTXT_RATIO = 4.0
IDENTIFY_BYTES_PER_ROW = 1024
IDENTIFY_STARTUP_S = 0.5


def check(goal: str, measured: str, ok: bool) -> str:
    """Record one goal with what was measured against it; "met" or "NOT met" for the caller's line."""
    RESULTS.append((goal, measured, ok))
    return "met" if ok else "NOT met"


def summary() -> str:
    width = max((len(g) for g, _, _ in RESULTS), default=0)
    lines = [f"{'met    ' if ok else 'NOT met'}  {goal:{width}s}  {measured}" for goal, measured, ok in RESULTS]
    met = sum(ok for _, _, ok in RESULTS)
    return "\n".join([f"== goals: {met} of {len(RESULTS)} met", *lines])
