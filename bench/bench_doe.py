"""Does the DOE pay off against the truth? At equal measurement count, the TCP error at the cell's test pose of a
campaign identified from the rho0 plan (`trackcal plan`'s criterion, over the campaign's unknowns), from random
feasible poses and from a D-optimal plan, against the digital twin's truth.

For each cell (KR-270, UR10) and number of configurations M (6, 12, 24, each measured once, every reference point
from every station that sees it): the rho0 and the D-optimal plan are searched once (i.i.d. 10 um, `trackcal
plan`'s default noise; the search budget is --starts / --refined / --pool); then for every twin seed (its own true
robot deviations, station placements, reference points and noise) the three campaigns are simulated on the twin,
interleaved, and identified as `identify` does (irreducible robot parameters, stations and points, weighted by the
cell's tracker model). The error is |model - truth| of the reference points' centroid at the test pose in the first
station's frame (the quantity plan's rho0 predicts and the report states). Printed: the medians over seeds (µm),
the mean number of measurements of each campaign, the ratios random / rho0 and D / rho0 (above 1: the plan
wins), and the rho0 each plan reaches (the random campaigns': their median): the D-optimal plan's rho0 below the
rho0 plan's would say the search lost on its own criterion. A campaign that cannot be identified (too few poses
for 39 unknowns) counts as infinitely far.

    python -m bench.bench_doe [--seeds 12] [--starts 300] [--refined 4] [--pool 1000] [--cells kr270,ur10]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from bench.goals import check
from trackcal.calib.doe.design import optimize_plan, random_feasible_poses
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.identify.solver import IdentificationError, identify
from trackcal.calib.identify.unknowns import campaign_params
from trackcal.calib.model.cell import load_cell
from trackcal.calib.model.kinematics import Kinematics
from trackcal.campaign.jobs.plan import PlanOptions, build_design
from trackcal.mocks.twin import Twin, simulate_campaign

CONFIGS = (6, 12, 24)


def test_pose_error(cell, poses_deg: np.ndarray, seed: int) -> tuple[float, int]:
    """(|model - truth| at the test pose, mm; measurements) of one simulated campaign of the poses on twin `seed`."""
    twin = Twin(cell, seed=seed)
    table = simulate_campaign(twin, poses_deg)
    params = campaign_params(cell.chain)
    try:
        res = identify(cell.chain, table, cell.tool_points, params, TrackerNoise.of(cell.tracker))
    except IdentificationError:
        return float("inf"), len(table)
    station = res.station_ids[0]
    q0 = np.degrees(cell.test_pose)
    twin.move_to(q0)
    truth = np.mean([twin.exact(q0, p, station) for p in res.point_ids], axis=0)
    tool = np.array([res.points[p] for p in res.point_ids])
    q = np.repeat(cell.test_pose[None], len(tool), axis=0)
    model = res.stations[station].apply(Kinematics(cell.chain, params).points(q, tool, res.dev).mean(axis=0))
    return float(np.linalg.norm(model - truth)), len(table)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=12)
    ap.add_argument("--starts", type=int, default=300)
    ap.add_argument("--refined", type=int, default=4)
    ap.add_argument("--pool", type=int, default=1000)
    ap.add_argument("--cells", default="kr270,ur10")
    ap.add_argument("--configs", default=",".join(str(m) for m in CONFIGS))
    args = ap.parse_args(argv)
    print(
        f"{'cell':6s} {'M':>3s} {'rho0 plan µm':>12s} {'random µm':>10s} {'D-opt µm':>9s} {'meas.':>13s} "
        f"{'random/rho0':>11s} {'D/rho0':>7s} {'rho0 of each µm':>19s} {'search s':>8s}"
    )
    for name in args.cells.split(","):
        cell = load_cell(name)
        design = build_design(cell, PlanOptions())
        for m in (int(v) for v in args.configs.split(",")):
            t0 = time.perf_counter()
            plans = {
                c: optimize_plan(design, m, 1, c, starts=args.starts, refined=args.refined, seed=0, pool_size=args.pool)
                for c in ("rho0", "D")
            }
            search = time.perf_counter() - t0
            errors: dict[str, list[float]] = {"rho0": [], "random": [], "D": []}
            rho0_random = []
            counts: dict[str, list[int]] = {k: [] for k in errors}
            for seed in range(args.seeds):  # interleaved: the three campaigns of one twin in turn
                rand = random_feasible_poses(design, m, np.random.default_rng(1000 + seed))
                rho0_random.append(design.rho0(rand))
                for key, q in (("rho0", plans["rho0"].poses), ("random", rand), ("D", plans["D"].poses)):
                    e, n = test_pose_error(cell, np.degrees(q), seed)
                    errors[key].append(e)
                    counts[key].append(n)
            med = {k: float(np.median(v)) for k, v in errors.items()}
            meas = "/".join(f"{np.mean(counts[k]):.0f}" for k in ("rho0", "random", "D"))
            ratio_r, ratio_d = med["random"] / med["rho0"], med["D"] / med["rho0"]
            reached = "/".join(
                f"{v * 1000:.2f}"
                for v in (design.rho0(plans["rho0"].poses), np.median(rho0_random), design.rho0(plans["D"].poses))
            )
            verdict = check(
                f"DOE pays off: {name} M={m}, rho0 plan closer to the truth than random and D-optimal",
                f"median {med['rho0'] * 1000:.1f} vs {med['random'] * 1000:.1f} and {med['D'] * 1000:.1f} µm",
                min(ratio_r, ratio_d) > 1,
            )
            print(
                f"{name:6s} {m:3d} {med['rho0'] * 1000:12.1f} {med['random'] * 1000:10.1f} {med['D'] * 1000:9.1f} "
                f"{meas:>13s} {ratio_r:11.2f} {ratio_d:7.2f} {reached:>19s} "
                f"{search:8.0f}  {verdict}",
                flush=True,
            )


if __name__ == "__main__":
    main()
