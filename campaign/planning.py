"""`trackcal plan`: search or evaluate a measurement plan for a cell (calib.doe behind an executor)."""

from __future__ import annotations

import contextlib
import csv
import os
from collections.abc import Callable, Iterator
from concurrent.futures import Executor, ProcessPoolExecutor
from pathlib import Path

import numpy as np

from calib.cell import Cell
from calib.doe import CRITERIA, Design, design_for_cell, optimize_plan
from calib.noise import TrackerNoise
from calib.params import Param, irreducible_params, param_by_name

from .jobs import UsageError


def plan_params(cell: Cell, names: str | None) -> list[Param]:
    """--params, else the cell's plan_params, else the irreducible set plus dq1 (base and tool known)."""
    chosen = names.split(",") if names else cell.plan_params
    if not chosen:
        return [param_by_name(cell.chain, "dq1"), *irreducible_params(cell.chain)[0]]
    try:
        return [param_by_name(cell.chain, n.strip()) for n in chosen if n.strip()]
    except ValueError as exc:
        raise UsageError(f"--params: {exc}") from None


def parse_test_pose(cell: Cell, text: str | None) -> np.ndarray:
    if text is None:
        if cell.test_pose is None:
            raise UsageError(f"cell {cell.name} has no test_pose_deg: give --test-pose=Q1,..,Q{cell.chain.dof}")
        return cell.test_pose
    try:
        q = np.array([float(v) for v in text.split(",")])
    except ValueError:
        raise UsageError(f"--test-pose: expected {cell.chain.dof} comma-separated angles in degrees") from None
    if q.shape != (cell.chain.dof,) or not np.all(np.isfinite(q)):
        raise UsageError(f"--test-pose: expected {cell.chain.dof} angles, got {text!r}")
    return np.radians(q)


def build_design(cell: Cell, args) -> Design:
    if args.sigma_mm is not None and args.sigma_mm <= 0:
        raise UsageError("--sigma-mm must be positive")
    noise = TrackerNoise() if args.noise == "tracker" else None
    return design_for_cell(
        cell, plan_params(cell, args.params), parse_test_pose(cell, args.test_pose),
        sigma_mm=args.sigma_mm if args.sigma_mm is not None else 0.01, noise=noise, visibility=not args.no_visibility,
    )  # fmt: skip


@contextlib.contextmanager
def executor_for(scheduler: str | None) -> Iterator[Executor]:
    """A local process pool by default; a Dask distributed cluster when given its scheduler address."""
    if scheduler:
        try:
            from distributed import Client
        except ImportError:
            raise UsageError("--scheduler needs Dask: pip install 'trackcal[dask]'") from None
        try:
            client = Client(scheduler, timeout="10s")
        except (OSError, TimeoutError) as exc:
            raise UsageError(f"--scheduler {scheduler}: cannot reach the Dask scheduler ({exc})") from None
        try:
            yield client.get_executor()
        finally:
            client.close()
    else:
        with ProcessPoolExecutor(max_workers=min(os.cpu_count() or 1, 8)) as pool:
            yield pool


def read_plan_csv(path: str, dof: int) -> np.ndarray:
    cols = [f"q{j + 1}_deg" for j in range(dof)]
    try:
        with open(path, newline="") as fh:
            rows = list(csv.DictReader(fh))
    except OSError as exc:
        raise UsageError(f"{path}: cannot read ({exc.strerror})") from None
    if not rows:
        raise UsageError(f"{path}: no poses")
    missing = [c for c in cols if c not in rows[0]]
    if missing:
        raise UsageError(f"{path}: row 1: missing column(s) {', '.join(missing)}")
    out = []
    for i, row in enumerate(rows):
        try:
            out.append([float(row[c]) for c in cols])
        except (TypeError, ValueError):
            raise UsageError(f"{path}: row {i + 2}: joint values must be numbers") from None
    q = np.radians(np.array(out))
    if not np.all(np.isfinite(q)):
        raise UsageError(f"{path}: joint values must be finite")
    return q


def write_plan_csv(path: Path, poses_rad: np.ndarray, repeat: int) -> None:
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow([f"q{j + 1}_deg" for j in range(poses_rad.shape[1])])
        for _ in range(repeat):
            for q in np.degrees(poses_rad):
                w.writerow([f"{v:.4f}" for v in q])


def evaluate_doc(design: Design, poses: np.ndarray) -> dict:
    """Criteria of a plan given as rows (repeated rows are repetitions)."""
    crit = design.criteria(poses)
    feasible = design.feasible(poses)
    return {
        **crit,
        "measurements": len(poses),
        "params": [p.name for p in design.params],
        "infeasible_rows": [int(i) + 2 for i in np.flatnonzero(~feasible)],
    }


def search_doc(design: Design, args, progress: Callable[[int, int], None] | None = None) -> dict:
    if args.configs < 1 or args.repeat < 1:
        raise UsageError("--configs and --repeat must be at least 1")
    if args.criterion not in CRITERIA:
        raise UsageError(f"--criterion must be one of {', '.join(CRITERIA)}")
    try:
        with executor_for(args.scheduler) as ex:
            plan = optimize_plan(
                design, args.configs, args.repeat, args.criterion, starts=args.starts, refined=args.refined,
                seed=args.seed, executor=ex, progress=progress,
            )  # fmt: skip
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    return {
        "rho0_mm": plan.criteria["rho0_mm"],
        "poses_deg": np.degrees(plan.poses).round(4).tolist(),
        "repeat": plan.repeat,
        "criterion": plan.criterion,
        "params": [p.name for p in design.params],
        "test_pose_deg": np.degrees(design.q0).tolist(),
        "sigma_mm": design.sigma_mm,
        "noise": "tracker" if design.noise is not None else "iid",
        "visibility": bool(design.trackers),
        "criteria": plan.criteria,
        "starts": plan.starts,
        "refined": plan.refined,
    }
