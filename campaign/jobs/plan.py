"""`plan` on typed options: search or evaluate a measurement plan for a cell (calib.doe behind an executor)."""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import logging
import os
import warnings
from collections.abc import Callable, Iterator
from concurrent.futures import Executor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from trackcal.calib.doe.design import (
    CRITERIA,
    SCREEN_CHUNK,
    Design,
    DesignError,
    design_for_cell,
    optimize_plan,
)
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.identify.unknowns import campaign_params
from trackcal.calib.io.files import atomic_open, finite_or_null, write_json, writing
from trackcal.calib.io.table import joint_columns, read_joint_rows
from trackcal.calib.model.cell import Cell, load_cell
from trackcal.calib.model.chain import ChainError
from trackcal.calib.model.params import Param, param_by_name
from trackcal.campaign.errors import InputError, OptionError
from trackcal.campaign.jobs.limits import check_memory, check_table_rows
from trackcal.campaign.jobs.pool import local_pool
from trackcal.campaign.jobs.scheduler import SchedulerWatch, WatchedExecutor


@dataclass(frozen=True)
class PlanOptions:
    """What `trackcal plan` is asked: the design (parameters, test pose, noise, visibility) and the search."""

    params: str | None = None  # comma-separated robot parameters; None: those identify fits (the irreducible set)
    test_pose: str | None = None  # "Q1,..,Qn" in degrees; None: the cell's test pose
    sigma_mm: float | None = None  # noise="iid": one coordinate's noise; None: 0.01
    # the cell's tracker model (the AT901 by default): identify, diagnose and run weigh a campaign by it, and rho0
    # is the test-pose error of the estimate they compute; "iid" (sigma_mm) is the paper's i.i.d. case
    noise: str = "iid"  # the tracker model plans poses at the edge of a station's view: README, `trackcal plan`
    visibility: bool = True
    configs: int | None = None  # None: chosen from the cell (`plan_size`)
    repeat: int | None = None  # None: 1 when configs are chosen or given
    criterion: str = "rho0"
    starts: int = 1000
    refined: int = 4
    seed: int = 0
    scheduler: str | None = None  # Dask scheduler address; None: a local process pool


def plan_params(cell: Cell, names: str | None) -> list[Param]:
    """The `params` option, else the robot parameters a campaign identifies (identify's default: the irreducible
    set). A plan is scored for every unknown of the campaign: these, every station and every reference point."""
    if not names:
        return campaign_params(cell.chain)
    try:
        return [param_by_name(cell.chain, n.strip()) for n in names.split(",") if n.strip()]
    except ChainError as exc:
        raise OptionError("{0}: {exc}", "params", exc=exc) from None


def parse_test_pose(cell: Cell, text: str | None) -> np.ndarray:
    if text is None:
        if cell.test_pose is None:
            raise OptionError(
                "cell {cell} has no test_pose_deg: give {0}=Q1,..,Q{dof}",
                "test_pose",
                cell=cell.name,
                dof=cell.chain.dof,
            )
        return cell.test_pose
    try:
        q = np.array([float(v) for v in text.split(",")])
    except ValueError:
        raise OptionError(
            "{0}: expected {dof} comma-separated angles in degrees", "test_pose", dof=cell.chain.dof
        ) from None
    if q.shape != (cell.chain.dof,) or not np.all(np.isfinite(q)):
        raise OptionError("{0}: expected {dof} angles, got {text!r}", "test_pose", dof=cell.chain.dof, text=text)
    return np.radians(q)


# Distinct configurations a default plan has per unknown of the campaign, counted in equations: each configuration
# gives x, y, z of every reference point (from at least one station). Three equations per unknown leave the fit
# 2 K degrees of freedom, so the noise level the campaign estimates from its residuals (and scales every stated
# uncertainty by) has a relative standard deviation of sqrt(2 / 2K) = 1/sqrt(K) in variance, half that in sigma:
# 8 % for the KR-270's 39 unknowns.
EQUATIONS_PER_UNKNOWN = 3


def plan_size(design: Design, configs: int | None, repeat: int | None) -> tuple[int, int, str]:
    """(configurations, repeats, why): the given ones, or the plan a customer should measure. With stations and
    points unknown, distinct poses come before repeats: a repeat only averages the noise of a pose already
    measured, where a new pose also separates parameters the others leave correlated (rho0 of a plan repeated k
    times is rho0 / sqrt(k), paper section 6.3; a new pose usually does better)."""
    u = design.unknowns
    if configs is not None:
        return configs, 1 if repeat is None else repeat, "as asked"
    per_config = 3 * len(design.tool)
    chosen = -(-EQUATIONS_PER_UNKNOWN * u.size // per_config)
    repeat = 1 if repeat is None else repeat
    free = (
        " and ".join(f"{n} {what}" for n, what in ((u.n_stations, "stations"), (u.n_points, "reference points")) if n)
        or "no stations or points"
    )
    why = (
        f"{chosen} configurations x {repeat}: the campaign identifies {u.size} unknowns ({u.k} robot parameters, "
        f"{free}), each configuration gives {per_config} coordinates, and {EQUATIONS_PER_UNKNOWN} equations per "
        "unknown let the noise be estimated to 8 % or better; distinct poses before repeats, since a repeat only "
        "averages noise where a new pose also separates the parameters"
    )
    return chosen, repeat, why


# How far inside a station's acceptance cone a planned (point, station) pair must be, and how far outside an unseen
# one: the plan is made on the nominal cell, the campaign sees from where the tracker really stands. A station set up
# 20 mm off per axis (the digital twin's placement error, mocks/twin.py) turns the direction to a reflector 2.5 m away
# by atan(20 sqrt(2) / 2500) = 0.65 deg (1 sigma, the two axes across the line of sight), 1.9 deg at 3 sigma; the
# robot's own errors add ~0.05 deg. Without it, the default plan (its stations unknown, so it wants rows from both)
# put P3 at the edge of S2's cone: the demo skipped 29 of 86 measurements there.
PLAN_VISIBILITY_MARGIN_DEG = 2.0


def build_design(cell: Cell, opts: PlanOptions) -> Design:
    if opts.sigma_mm is not None and opts.sigma_mm <= 0:
        raise OptionError("{0} must be positive", "sigma_mm")
    if opts.sigma_mm is not None and opts.noise != "iid":
        raise OptionError(
            "{0} is the i.i.d. noise of one coordinate: give {1} iid with it (the tracker model has its own)",
            "sigma_mm",
            "noise",
        )
    noise = TrackerNoise.of(cell.tracker) if opts.noise == "tracker" else None
    return design_for_cell(
        cell,
        plan_params(cell, opts.params),
        parse_test_pose(cell, opts.test_pose),
        sigma_mm=opts.sigma_mm if opts.sigma_mm is not None else 0.01,
        noise=noise,
        visibility=opts.visibility,
        visibility_margin_deg=PLAN_VISIBILITY_MARGIN_DEG,
    )


# how long `--scheduler` waits for a Dask scheduler to answer (distributed.Client's connect timeout)
SCHEDULER_TIMEOUT_S = 10
CLOSE_TIMEOUT_S = 2  # how long a client's goodbye to its scheduler may take


@contextlib.contextmanager
def executor_for(scheduler: str | None, started=None) -> Iterator[Executor]:
    """A local process pool by default (campaign.jobs.pool: its workers die with this process; `started`, a
    pool.chunk_marks, records which worker takes which chunk); a Dask distributed cluster when given its scheduler
    address, watched (scheduler.WatchedExecutor: its maps end in SchedulerLost once the scheduler is lost)."""
    if scheduler:
        try:
            from distributed import Client  # optional dependency (trackcal[dask]): only with a scheduler
        except ImportError:
            raise OptionError("{0} needs Dask: pip install 'trackcal[dask]'", "scheduler") from None
        try:
            client = Client(scheduler, timeout=f"{SCHEDULER_TIMEOUT_S}s")
        except (OSError, TimeoutError) as exc:
            raise OptionError(
                "{0} {scheduler}: cannot reach the Dask scheduler ({exc})", "scheduler", scheduler=scheduler, exc=exc
            ) from None
        except Exception as exc:  # noqa: BLE001 - whatever a server that is no Dask scheduler makes distributed raise
            # e.g. an HTTP server's "HTTP/1.1 404" read as a frame length: numpy asked for 3.07 EiB (MemoryError)
            raise OptionError(
                "{0} {scheduler}: no Dask scheduler answers there (the server's reply is not Dask's protocol: {kind})",
                "scheduler",
                scheduler=scheduler,
                kind=type(exc).__name__,
            ) from None
        # a lost scheduler is our one line, not distributed's log of tracebacks (its loggers have levels of their
        # own, dask's logging config: their handlers, on the `distributed` logger, are silenced)
        handlers = logging.getLogger("distributed").handlers
        levels = [h.level for h in handlers]
        for h in handlers:
            h.setLevel(logging.CRITICAL + 1)
        watched = WatchedExecutor(client.get_executor(), SchedulerWatch(client, SCHEDULER_TIMEOUT_S), scheduler)
        try:
            with warnings.catch_warnings():
                # each plan task carries the design and its candidate pool (a few MB): distributed's advice to load
                # data with Dask is not the user's to act on, and not a line of our output
                warnings.filterwarnings("ignore", message="Sending large graph", category=UserWarning)
                yield watched
        finally:
            watched.watch.close()
            with contextlib.suppress(Exception):  # a scheduler that does not answer cannot be told goodbye
                client.close(timeout=CLOSE_TIMEOUT_S)
            for h, level in zip(handlers, levels, strict=True):
                h.setLevel(level)
    else:
        with local_pool(WORKERS, started) as pool:
            yield pool


def read_plan_csv(path: str, dof: int) -> np.ndarray:
    """A plan given as rows of joint angles (repeated rows are repetitions), rad."""
    return np.radians(read_joint_rows(path, dof, what="poses")[0])


def write_plan_csv(path: Path, poses_rad: np.ndarray, repeat: int) -> None:
    with writing(path, InputError), atomic_open(path, "w", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(joint_columns(poses_rad.shape[1]))
        for _ in range(repeat):
            for q in np.degrees(poses_rad):
                w.writerow([f"{v:.4f}" for v in q])


# calib.doe scores a plan whose information matrix is singular as infinitely bad
NOT_IDENTIFIABLE = "not identifiable: the plan's information matrix is singular"


def unknowns_doc(design: Design) -> dict:
    """What rho0 was computed for: the campaign's unknowns and the quantity it predicts."""
    u = design.unknowns
    return {
        "robot_params": u.k,
        "stations": u.n_stations,
        "points": u.n_points,
        "total": u.size,
        "rho0_is": "the predicted 1-sigma 3-D uncertainty of the reference points' centroid at the test pose, in "
        "the first station's frame (what identify and the report state after the campaign)",
    }


def evaluate_doc(design: Design, poses: np.ndarray) -> dict:
    """Criteria of a plan given as rows (repeated rows are repetitions)."""
    crit = finite_or_null(design.criteria(poses), NOT_IDENTIFIABLE)
    feasible = design.feasible(poses)
    return {
        **crit,
        "measurements": len(poses),
        "params": [p.name for p in design.params],
        "unknowns": unknowns_doc(design),
        "infeasible_rows": [int(i) + 2 for i in np.flatnonzero(~feasible)],
    }


# calib.doe.design.optimize_plan's pool: max(POOL, configs + 1) random feasible poses
POOL = 2000
WORKERS = min(os.cpu_count() or 1, 8)  # the local process pool's size (executor_for)
# Measured (KR-270, 10 starts, 1 refinement in one process, peak RSS above the imports): 63 MB at 24
# configurations, 81 MB at 48; the 18 MB between them, quadratic, is 9 copies of the 8-byte constraint Jacobian
# (24 rows x 6 columns per configuration squared: 1728 x 1152 bytes x 9 = 17.9 MB); at 96 it predicts 153 MB,
# measured 148 MB
REFINE_COPIES = 9


def plan_bytes(design: Design, opts: PlanOptions) -> dict[str, float]:
    """Peak memory of a plan search by its stages, bytes, from the arrays optimize_plan makes (float64):
    screening holds the information matrices of SCREEN_CHUNK plans of `configs` poses at a time (chunk x configs x
    K x K, K the campaign's unknowns: 39 on the KR-270) and the pool indices of every screened plan; the pool's
    poses and matrices are held once, and each refinement task holds its plan's pool indices and its two results
    (configs x dof), plus the pool's matrices when a Dask cluster serialises every task; each worker's refinement
    holds the constraint Jacobian (configs x points x (6 box faces + stations) rows, configs x dof columns)
    REFINE_COPIES times (ours, SLSQP's copies and work arrays): quadratic in configs; and the rows' Jacobian and
    its derivative by the joints (configs x points x stations x 3 x K x (dof + 2)), linear."""
    k, m, dof = design.unknowns.size, opts.configs, design.chain.dof
    pool = 8.0 * max(POOL, m + 1) * (k * k + dof)
    task = 8.0 * m * (1 + 2 * dof) + 256 + (pool if opts.scheduler else 0.0)
    stations = max(1, len(design.trackers))
    rows = len(design.tool) * (6 + len(design.trackers))
    row_jacobians = 8.0 * m * len(design.tool) * stations * 3 * k * (dof + 2)
    return {
        "screening": 8.0 * (min(opts.starts, SCREEN_CHUNK) * m * k * k + opts.starts * m),
        "tasks": pool + task * min(opts.refined, opts.starts),  # the best screened plans are refined
        "refinement": WORKERS * (REFINE_COPIES * 8.0 * (m * rows) * (m * dof) + row_jacobians),
    }


def check_plan_size(design: Design, opts: PlanOptions) -> None:
    """Refuse a search the machine cannot hold, naming the option that makes it large, before any allocation;
    and a plan whose campaign's table could not be read back."""
    configs, repeat, _ = plan_size(design, opts.configs, opts.repeat)
    opts = dataclasses.replace(opts, configs=configs, repeat=repeat)
    if opts.configs < 1 or opts.repeat < 1:
        raise OptionError("{0} and {1} must be at least 1", "configs", "repeat")
    if opts.starts < 1 or opts.refined < 1:
        raise OptionError("{0} and {1} must be at least 1", "starts", "refined")
    need = plan_bytes(design, opts)
    largest = max(need, key=need.get)

    def total(**change: int) -> float:
        return sum(plan_bytes(design, dataclasses.replace(opts, **change)).values())

    if opts.starts / 1000 > opts.configs / 6:  # the count further above its default (the best screened are refined)
        check_memory("starts", opts.starts, lambda n: total(starts=n, refined=min(opts.refined, n)), "screened plan")
    if largest == "tasks":
        check_memory("refined", opts.refined, lambda n: total(refined=n), "refined plan")
    check_memory("configs", opts.configs, lambda n: total(configs=n), "configuration")
    rows = opts.configs * opts.repeat * len(design.tool) * max(1, len(design.trackers))
    if opts.repeat >= opts.configs:
        check_table_rows("repeat", opts.repeat, rows, design.chain.dof, "repetitions")
    check_table_rows("configs", opts.configs, rows, design.chain.dof, "configurations")


def search_doc(design: Design, opts: PlanOptions, progress: Callable[[int, int], None] | None = None) -> dict:
    configs, repeat, why = plan_size(design, opts.configs, opts.repeat)
    opts = dataclasses.replace(opts, configs=configs, repeat=repeat)
    check_plan_size(design, opts)
    if opts.criterion not in CRITERIA:
        raise OptionError("{0} must be one of {criteria}", "criterion", criteria=", ".join(CRITERIA))
    try:
        with executor_for(opts.scheduler) as ex:
            plan = optimize_plan(
                design,
                opts.configs,
                opts.repeat,
                opts.criterion,
                starts=opts.starts,
                refined=opts.refined,
                seed=opts.seed,
                executor=ex,
                progress=progress,
            )
    except DesignError as exc:
        raise InputError(str(exc)) from None
    criteria = finite_or_null(plan.criteria, NOT_IDENTIFIABLE)
    return {
        **{k: v for k, v in criteria.items() if k.startswith("rho0_")},
        "poses_deg": np.degrees(plan.poses).round(4).tolist(),
        "repeat": plan.repeat,
        "criterion": plan.criterion,
        "params": [p.name for p in design.params],
        "test_pose_deg": np.degrees(design.q0).tolist(),
        "sigma_mm": design.sigma_mm,
        "noise": "tracker" if design.noise is not None else "iid",
        "visibility": bool(design.trackers),
        "criteria": criteria,
        "starts": plan.starts,
        "refined": plan.refined,
        "unknowns": unknowns_doc(design),
        "why": why,
    }


@dataclass
class PlanOutcome:
    doc: dict  # plan.json (search) or the plan's criteria (evaluate)
    evaluated: bool  # the doc evaluates a given plan


def plan(
    cell_ref: str,
    opts: PlanOptions,
    json_out: str,
    evaluate: str | None = None,
    csv_out: str | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> PlanOutcome:
    """`trackcal plan`: search a plan (its poses also as rows in `csv_out`), or evaluate the plan of the CSV
    `evaluate`; the document written to `json_out`."""
    cell = load_cell(cell_ref)
    design = build_design(cell, opts)
    if evaluate:
        doc = evaluate_doc(design, read_plan_csv(evaluate, cell.chain.dof))
    else:
        doc = search_doc(design, opts, progress)
        if csv_out:
            write_plan_csv(Path(csv_out), np.radians(np.array(doc["poses_deg"])), doc["repeat"])
    if opts.noise == "tracker":  # the instrument rho0 was computed for
        doc["tracker"] = cell.tracker.to_doc()
    write_json(json_out, doc, InputError)
    return PlanOutcome(doc, evaluated=bool(evaluate))
