"""Program filtering (issue 38): the time per target of `trackcal filter`'s work on a long program, against the cost
of the inverse kinematics it is made of, and the peak memory; measured in one run.

    python -m bench.bench_filter [--language krl|urscript] [--targets 10000] [--seed 1]

KRL (the issue's case): a KR C4 program for the KR-270, BENCH.src with its BENCH.dat: the tool and base set inline
($TOOL, $BASE), N E6POS targets declared in the .dat (X Y Z A B C, S and T written from the joints they were made at,
the status and turn the reader checks: drivers.kuka.krl_values.status_turn), moved to by PTP and LIN in turn.
URScript: a program of N `movel(pose_trans(fixture, p[...]))` targets for the UR10 (a fixture frame and a 200 mm tool).
The targets are random reachable poses; the model is identified from a simulated campaign of the robot's twin. The
program is read (the tokenizer and parser), filtered (calib.program_filter.filter_targets: the multi-start nominal IK,
the choice of the solution, the calibrated model's IK, the accuracy of every target and its place against the
measured space) and written back. Reported: each stage's time per target, the whole against one Gauss-Newton IK solve
per target (calib.model.inverse.reach_points from a start 0.2 rad away: the unit the filter's IK is made of) and the
peak resident memory of this process (VmHWM).
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
from trackcal.drivers.kuka.krl_reader import read_krl
from trackcal.drivers.kuka.krl_values import abc_of, rot_zyx
from trackcal.drivers.ur.urscript_reader import pose_matrix, pose_values, read_urscript
from trackcal.mocks.twin import Twin, simulate_campaign

FIXTURE = [-0.9, -0.1, 0.05, 0.0, 0.0, 0.3]
TOOL = [0.0, 0.05, 0.2, 0.0, 0.0, 0.0]
GOAL_MS = 50.0  # a 10,000-target program filtered in under ten minutes of one core


KRL_TOOL = (0.0, 50.0, 200.0, 0.0, 0.0, 0.0)  # X Y Z A B C (mm, deg): a 200 mm spindle
KRL_BASE = (1200.0, -400.0, 300.0, 30.0, 0.0, 0.0)  # a fixture 1.2 m out, turned 30 deg


def urscript_program(cell, q: np.ndarray) -> dict[str, str]:
    """The script of targets at the nominal joints q (N, n) rad."""
    kin = Kinematics(cell.chain, [])
    rel = np.linalg.inv(pose_matrix(FIXTURE)) @ flange_poses(kin, q) @ pose_matrix(TOOL)
    lines = [
        f"  movel(pose_trans(fixture, p[{', '.join(f'{v:.6f}' for v in pose_values(p))}]), a=0.5, v=0.1)" for p in rel
    ]
    head = [
        f"def bench():\n  set_tcp(p[{', '.join(map(str, TOOL))}])",
        f"  fixture = p[{', '.join(map(str, FIXTURE))}]",
    ]
    return {"bench.script": "\n".join([*head, *lines, "end"]) + "\n"}


def krl_frame(xyzabc) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = rot_zyx(*xyzabc[3:]), xyzabc[:3]
    return out


def status_turn_of(q_deg: np.ndarray) -> tuple[int, int]:
    """(S, T) of joints (deg), as drivers.kuka.krl_values.status_turn checks them: T bit i set where A(i+1) < 0; S bit
    2 for A5 < 0, bit 1 for A3 >= 0, bit 0 clear (the basic area)."""
    t = sum(1 << i for i in range(6) if q_deg[i] < 0)
    return (4 if q_deg[4] < 0 else 0) | (2 if q_deg[2] >= 0 else 0), t


def krl_program(cell, q: np.ndarray) -> dict[str, str]:
    """BENCH.src and BENCH.dat of targets at the nominal joints q (N, n) rad (module docstring)."""
    kin = Kinematics(cell.chain, [])
    rel = np.linalg.inv(krl_frame(KRL_BASE)) @ flange_poses(kin, q) @ krl_frame(KRL_TOOL)
    frame = ",".join(f"{k} {v}" for k, v in zip("XYZABC", KRL_TOOL, strict=True))
    base = ",".join(f"{k} {v}" for k, v in zip("XYZABC", KRL_BASE, strict=True))
    moves = [f"{'PTP' if i % 2 == 0 else 'LIN'} XP{i + 1}" for i in range(len(q))]
    src = "\n".join(["DEF BENCH( )", f"$TOOL={{{frame}}}", f"$BASE={{{base}}}", *moves, "END"]) + "\n"
    decls = []
    for i, (p, qi) in enumerate(zip(rel, np.degrees(q), strict=True)):
        a, b, c = abc_of(p[:3, :3], (0.0, 0.0, 0.0))
        s, t = status_turn_of(qi)
        decls.append(
            f"DECL E6POS XP{i + 1}={{X {p[0, 3]:.3f},Y {p[1, 3]:.3f},Z {p[2, 3]:.3f},A {a:.4f},B {b:.4f},"
            f"C {c:.4f},S {s},T {t},E1 0.0,E2 0.0,E3 0.0,E4 0.0,E5 0.0,E6 0.0}}"
        )
    return {"BENCH.src": src, "BENCH.dat": "\n".join(["DEFDAT BENCH PUBLIC", *decls, "ENDDAT"]) + "\n"}


LANGUAGES = {"krl": ("kr270", krl_program, read_krl), "urscript": ("ur10", urscript_program, read_urscript)}


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
    ap.add_argument("--language", choices=sorted(LANGUAGES), default="krl")
    ap.add_argument("--targets", type=int, default=10000)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    robot, make, reader = LANGUAGES[args.language]
    cell = load_cell(robot)
    twin = Twin(cell, seed=args.seed)
    poses = np.degrees(random_feasible_poses(design_for_cell(cell, []), 30, np.random.default_rng(args.seed)))
    model = model_from_doc(run_identify(cell, simulate_campaign(twin, poses), irreducible_params(cell.chain)[0]).doc)
    q = random_feasible_poses(design_for_cell(cell, []), args.targets, np.random.default_rng(args.seed + 1))
    files = make(cell, q)
    n = args.targets
    t0 = time.process_time()
    read = reader(files)
    t1 = time.process_time()
    res = filter_targets(model, read.targets, np.degrees(q[0]))
    t2 = time.process_time()
    read.write({i: v for i, v in enumerate(res.values) if v is not None}, {})
    t3 = time.process_time()
    unit = ik_unit_cost(cell, q)
    per = (t3 - t0) / n
    size = sum(map(len, files.values())) / 1e6
    print(
        f"{n} targets ({size:.1f} MB of {read.language}, {robot}), {int(res.ok.sum())} filtered, "
        f"{int(res.extrapolated.sum())} outside the measured space: read {1e3 * (t1 - t0) / n:.3f} ms, filter "
        f"{1e3 * (t2 - t1) / n:.2f} ms, write {1e3 * (t3 - t2) / n:.3f} ms per target; one IK solve "
        f"{1e3 * unit:.3f} ms per target: the whole is {per / unit:.0f}x one solve; peak memory "
        f"{peak_rss_mb():.0f} MB"
    )
    met = check(f"filter ({read.language}): ms per target", f"{1e3 * per:.2f}", 1e3 * per < GOAL_MS)
    print(f"goal: under {GOAL_MS:g} ms per target: {met}")


if __name__ == "__main__":
    main()
