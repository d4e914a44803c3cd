"""One iteration of the identification solver, before and after issue 26's rework of the kinematics and the
Jacobian blocks: `Problem.normal_equations`, `residual_and_jacobian`, `residual` and `predicted`, interleaved
medians, and the largest difference of their outputs (relative to the output's magnitude).

Cases: the UR10's Series B (1495 rows, one station, one point; when the data set is present) and a KR-270 twin
campaign with 3 stations x 3 points, each without extension, with joint features (joint_compliance on the UR10,
backlash on the twin), with growth (thermal_drift) and with both, i.i.d. and whitened (the tracker's noise
model); on Series B also a joint error map wide as diagnose's (residual_and_jacobian only, as diagnose uses it).

Before: calib/model/kinematics.py and calib/identify/solver.py of commit BASELINE_COMMIT (git show), loaded as
modules of their own next to today's package (the rest of trackcal is shared), so both run in this process on the
same machine state. Without git history only today's times are printed. Timings taken while other work loads
the machine are inflated; the ratios of interleaved medians say more than the milliseconds.

`python -m bench.bench_jacobian [REPEAT]` (default 15).
"""

from __future__ import annotations

import dataclasses
import statistics
import subprocess
import sys
import time
import types
from pathlib import Path

import numpy as np

from bench.goals import check
from studies.ur10_ipa.study import DATA, SERIES
from trackcal.calib.diagnose.extensions import build_extension, combine
from trackcal.calib.diagnose.joint_map import map_extension
from trackcal.calib.doe.poses import random_poses
from trackcal.calib.identify import solver
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.model.cell import StationPlacement, load_cell
from trackcal.calib.model.params import irreducible_params, param_by_name
from trackcal.calib.model.rigid import exp_so3, rot_axis
from trackcal.campaign.importers.ipa_ur10 import read_ipa_series
from trackcal.mocks.twin import Twin, simulate_campaign

BASELINE_COMMIT = "123db2d"  # main before this rework
ROOT = Path(__file__).resolve().parents[1]
PARAMS = "px1,py1,phix1,dq2,px2,phix2,phiy2,dq3,px3,phix3,phiy3,dq4,px4,py4,phix4,dq5"  # the README's UR10 section
MAP_HARMONICS = 27  # ~300 joint error map columns: the width of diagnose's widest map on Series B (~650) halved
GOAL_PARTS = ("_blocks", "Kinematics.jacobian", "predicted")  # the brief's 2x: the pass's parts the profile named
TOLERANCE = 1e-12  # largest difference allowed, relative to the output's magnitude


def baseline_modules() -> types.SimpleNamespace | None:
    """The baseline's kinematics and solver modules (its solver on its kinematics), or None without git history."""

    def load(name: str, path: str) -> types.ModuleType:
        source = subprocess.run(
            ["git", "-C", str(ROOT), "show", f"{BASELINE_COMMIT}:{path}"], capture_output=True, check=True, text=True
        ).stdout
        module = types.ModuleType(name)
        module.__file__ = f"{BASELINE_COMMIT}:{path}"
        sys.modules[name] = module  # dataclasses look their module up
        exec(compile(source, module.__file__, "exec"), module.__dict__)  # noqa: S102 (our own file, at a commit)
        return module

    try:
        kin = load("bench_baseline_kinematics", "calib/model/kinematics.py")
        today = sys.modules["trackcal.calib.model.kinematics"]
        sys.modules["trackcal.calib.model.kinematics"] = kin  # the baseline solver imports the baseline kinematics
        try:
            sol = load("bench_baseline_solver", "calib/identify/solver.py")
        finally:
            sys.modules["trackcal.calib.model.kinematics"] = today
    except (OSError, subprocess.CalledProcessError):
        return None
    return types.SimpleNamespace(kinematics=kin, solver=sol)


def twin_table():
    """A KR-270 twin campaign seen from 3 stations (the cell's two and a third), 3 points, a hidden backlash."""
    cell = load_cell("kr270")
    third = StationPlacement(rotation=rot_axis(2, np.radians(-90.0)), position=np.array([0.0, -3500.0, 900.0]))
    cell = dataclasses.replace(cell, stations=dict(cell.stations, S3=third))
    twin = Twin(cell, seed=5, effects={"backlash": 0.05})
    table = simulate_campaign(twin, np.degrees(random_poses(cell, 60, np.random.default_rng(5))))
    return cell, table, irreducible_params(cell.chain)[0]


def cases() -> list[tuple[str, tuple, tuple[str, ...]]]:
    """(name, Problem arguments, functions to time)."""
    every = ("normal_equations", "residual_and_jacobian", "residual", "predicted")
    parts = (*every, *PARTS)  # the parts too, for a case without and one with an extension
    out = []
    tables = []
    source = DATA / SERIES["B"]
    if source.exists():
        ur = load_cell("ur10-ipa")
        tables.append(
            (
                "Series B",
                ur,
                read_ipa_series(source),
                [param_by_name(ur.chain, p) for p in PARAMS.split(",")],
                "joint_compliance",
            )
        )
    else:
        print("UR10 Series B: data not found (TRACKCAL_IPA_DATA), the twin only")
    tables.append(("twin 3x3", *twin_table(), "backlash"))
    for label, cell, table, params, joint_cause in tables:
        joint = build_extension(joint_cause, cell.chain, table)
        growth = build_extension("thermal_drift", cell.chain, table)
        exts = {"none": None, "joint": joint, "growth": growth, "joint+growth": combine([joint, growth])}
        for ext_name, ext in exts.items():
            for weighting, noise in (("iid", None), ("whitened", TrackerNoise())):
                measured = parts if (ext_name, weighting) in (("none", "iid"), ("joint", "whitened")) else every
                out.append(
                    (
                        f"{label} {ext_name} {weighting}",
                        (cell.chain, table, cell.tool_points, params, noise, None, ext),
                        measured,
                    )
                )
        if label == "Series B":
            wide = map_extension(np.radians(table.q_deg), MAP_HARMONICS)
            out.append(
                (
                    f"{label} map({wide.size}) iid",
                    (cell.chain, table, cell.tool_points, params, None, None, wide),
                    ("residual_and_jacobian",),
                )
            )
    return out


def moved(problem, rng: np.random.Generator):
    """The problem's initial state moved off its start (every kind of unknown), in the problem's own State."""
    s = problem.initial
    stations = [
        type(st)(exp_so3(rng.normal(0, 1e-3, 3)) @ st.rotation, st.translation + rng.normal(0, 1.0, 3))
        for st in s.stations
    ]
    return type(s)(
        s.dev + rng.normal(0, 1e-4, len(s.dev)),
        stations,
        s.points + rng.normal(0, 0.5, s.points.shape),
        s.ext + rng.normal(0, 1e-6, len(s.ext)),
    )


def _jacobian(problem, s) -> tuple:
    """The chain's part of a pass, called as the problem's normal equations call it (its first chunk's poses)."""
    ch = problem.chunks[0]
    q, tool = problem.q[problem.pose_first[ch.poses]], s.points[problem.pt_idx[ch.rows]]
    jac = problem.kin.jacobian(q, tool, s.dev, rows=ch.of_row)
    return jac.p, jac.d_params, jac.d_point


PARTS = {  # the parts of a pass, as the profile names them; the rest are Problem methods of the state
    "_blocks": lambda problem, s: problem._blocks(s, problem.chunks[0]),  # every table here is one chunk
    "Kinematics.jacobian": _jacobian,
    "Kinematics.points": lambda problem, s: problem.kin.points(problem.q, s.points[problem.pt_idx], s.dev),
}


def call(problem, name: str, state) -> tuple:
    out = PARTS[name](problem, state) if name in PARTS else getattr(problem, name)(state)
    return out if isinstance(out, tuple) else (out,)


def rel_diff(a: tuple, b: tuple) -> float:
    worst = 0.0
    for x, y in zip(a, b, strict=True):
        x, y = np.asarray(x, float), np.asarray(y, float)
        size = max(float(np.max(np.abs(x), initial=0.0)), 1e-300)
        worst = max(worst, float(np.max(np.abs(x - y), initial=0.0)) / size)
    return worst


def identifications(base) -> bool:
    """identify before and after on every case: the same number of iterations, parameters within 1e-6 of their
    standard deviations (the solver stops at 1e-9 of the noise level)."""
    alike = True
    for name, args, functions in cases():
        if "residual" not in functions:  # the wide map alone is not identifiable: it is timed, not fitted
            continue
        before = base.solver.identify(*args[:5], extension=args[6])
        after = solver.identify(*args[:5], extension=args[6])
        moved = float(np.max(np.abs(before.dev - after.dev) / np.sqrt(np.diag(before.param_cov()))))
        alike &= before.iterations == after.iterations and moved <= 1e-6
        print(
            f"identify {name:34s} iterations {before.iterations} -> {after.iterations}, parameters moved by "
            f"{moved:.1e} of their standard deviations"
        )
    return alike


def main(repeat: int = 15) -> None:
    base = baseline_modules()
    if base is None:
        print("no git history: today's times only")
    worst, totals, goal = 0.0, {"old": 0.0, "new": 0.0}, {"old": 0.0, "new": 0.0}
    print(f"{'case':34s} {'function':22s} {'before ms':>9s} {'after ms':>9s} {'ratio':>6s} {'max rel diff':>12s}")
    for name, args, functions in cases():
        new = solver.Problem(*args)
        old = None if base is None else base.solver.Problem(*args)
        s_new = moved(new, np.random.default_rng(1))
        s_old = None if old is None else moved(old, np.random.default_rng(1))
        for fn in functions:
            t = {"old": [], "new": []}
            for _ in range(repeat):  # interleaved
                for which, problem, state in (("old", old, s_old), ("new", new, s_new)):
                    if problem is None:
                        continue
                    t0 = time.perf_counter()
                    call(problem, fn, state)
                    t[which].append(time.perf_counter() - t0)
            after = 1e3 * statistics.median(t["new"])
            if old is None:
                print(f"{name:34s} {fn:22s} {'-':>9s} {after:9.2f}")
                continue
            before = 1e3 * statistics.median(t["old"])
            diff = rel_diff(call(old, fn, s_old), call(new, fn, s_new))
            worst = max(worst, diff)
            totals["old"] += before
            totals["new"] += after
            if name.startswith("Series B") and fn in GOAL_PARTS:
                goal["old"] += before
                goal["new"] += after
            print(f"{name:34s} {fn:22s} {before:9.2f} {after:9.2f} {before / after:6.2f} {diff:12.1e}")
    if base is None:
        return
    ratio = totals["old"] / totals["new"]
    print(f"every case, sum of medians: before {totals['old']:.1f} ms, after {totals['new']:.1f} ms: {ratio:.2f}x")
    if goal["old"]:
        ratio = goal["old"] / goal["new"]
        print(
            f"Series B, {' + '.join(GOAL_PARTS)}: before {goal['old']:.1f} ms, after {goal['new']:.1f} ms: "
            f"{ratio:.2f}x, {check('solver pass on Series B: 2x faster', f'{ratio:.2f}x', ratio >= 2.0)} (>= 2x)"
        )
    print(
        f"largest difference: {worst:.1e} of the output's magnitude, "
        f"{check('solver pass: same outputs', f'max rel diff {worst:.1e}', worst <= TOLERANCE)} (<= {TOLERANCE:g})"
    )
    alike = identifications(base)
    print(f"identify: {check('identify: the same iterations', 'every case' if alike else 'not all', alike)}")


if __name__ == "__main__":
    main(*(int(a) for a in sys.argv[1:2]))
