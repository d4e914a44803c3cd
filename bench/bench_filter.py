"""Program filtering (issue 38): the time per target of `trackcal filter`'s work on a long program, against the cost
of the inverse kinematics it is made of, and the peak memory; measured in one run.

    python -m bench.bench_filter [--targets 10000] [--seed 1]

A URScript program of N `movel(pose_trans(fixture, p[...]))` targets at random reachable poses of the UR10 (a fixture
frame and a 200 mm tool) is read (the tokenizer and parser), filtered with a model identified from a simulated
campaign of the UR10 twin (calib.program_filter.filter_targets: the multi-start nominal IK, the choice of the solution,
the calibrated model's IK, the accuracy of every target) and written back. Reported: each stage's time per target,
the whole against one Gauss-Newton IK solve per target (calib.model.inverse.reach_points from a start 0.2 rad away:
the unit the filter's IK is made of) and the peak resident memory of this process (VmHWM).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from bench.goals import check
from bench.memory import peak_rss_mb
from trackcal.calib.doe.design import design_for_cell, random_feasible_poses
from trackcal.calib.model.cell import load_cell
from trackcal.calib.model.inverse import reach_points
from trackcal.calib.model.kinematics import Kinematics
from trackcal.calib.model.params import irreducible_params
from trackcal.calib.model_file import model_from_doc
from trackcal.calib.program_filter import IK_TOL_MM, LEVER_MM, filter_targets, flange_points, flange_poses
from trackcal.campaign.jobs.identify import run_identify
from trackcal.drivers.ur.urscript_reader import pose_matrix, pose_values, read_urscript
from trackcal.mocks.twin import Twin, simulate_campaign

FIXTURE = [-0.9, -0.1, 0.05, 0.0, 0.0, 0.3]
TOOL = [0.0, 0.05, 0.2, 0.0, 0.0, 0.0]
GOAL_MS = 50.0  # a 10,000-target program filtered in under ten minutes of one core


def program(cell, n: int, seed: int) -> tuple[str, np.ndarray]:
    """The script's text and its targets' nominal joints (rad)."""
    q = random_feasible_poses(design_for_cell(cell, []), n, np.random.default_rng(seed))
    kin = Kinematics(cell.chain, [])
    rel = np.linalg.inv(pose_matrix(FIXTURE)) @ flange_poses(kin, q) @ pose_matrix(TOOL)
    lines = [f"  movel(pose_trans(fixture, p[{', '.join(f'{v:.6f}' for v in pose_values(p))}]), a=0.5, v=0.1)"
             for p in rel]  # fmt: skip
    head = [f"def bench():\n  set_tcp(p[{', '.join(map(str, TOOL))}])",
            f"  fixture = p[{', '.join(map(str, FIXTURE))}]"]
    return "\n".join([*head, *lines, "end"]) + "\n", q


def ik_unit_cost(cell, q: np.ndarray) -> float:
    """Seconds per target of one batched Gauss-Newton IK solve from a start 0.2 rad away."""
    kin = Kinematics(cell.chain, [])
    tools = np.array([[0.0, 0.0, 0.0], [LEVER_MM, 0.0, 0.0], [0.0, LEVER_MM, 0.0]])
    start = q + np.random.default_rng(0).uniform(-0.2, 0.2, q.shape)
    t0 = time.process_time()
    reach_points(kin, tools, flange_points(flange_poses(kin, q)), start, None, None, IK_TOL_MM, 40)
    return (time.process_time() - t0) / len(q)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--targets", type=int, default=10000)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    cell = load_cell("ur10")
    twin = Twin(cell, seed=args.seed)
    poses = np.degrees(random_feasible_poses(design_for_cell(cell, []), 30, np.random.default_rng(args.seed)))
    model = model_from_doc(run_identify(cell, simulate_campaign(twin, poses), irreducible_params(cell.chain)[0]).doc)
    text, q = program(cell, args.targets, args.seed + 1)
    n = args.targets
    t0 = time.process_time()
    read = read_urscript({"bench.script": text})
    t1 = time.process_time()
    res = filter_targets(model, read.targets, np.degrees(q[0]))
    t2 = time.process_time()
    read.write({i: v for i, v in enumerate(res.values) if v is not None}, {})
    t3 = time.process_time()
    unit = ik_unit_cost(cell, q)
    per = (t3 - t0) / n
    print(f"{n} targets ({len(text) / 1e6:.1f} MB of URScript), {int(res.ok.sum())} filtered: read "
          f"{1e3 * (t1 - t0) / n:.3f} ms, filter {1e3 * (t2 - t1) / n:.2f} ms, write {1e3 * (t3 - t2) / n:.3f} ms "
          f"per target; one IK solve {1e3 * unit:.3f} ms per target: the whole is {per / unit:.0f}x one solve; "
          f"peak memory {peak_rss_mb():.0f} MB")  # fmt: skip
    met = check("filter: ms per target", f"{1e3 * per:.2f}", 1e3 * per < GOAL_MS)
    print(f"goal: under {GOAL_MS:g} ms per target: {met}")


if __name__ == "__main__":
    main()
