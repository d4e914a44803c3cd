"""Monte-Carlo checks on the batch engine (campaign.jobs.batch.map_chunks: a process pool or a Dask cluster).

    trackcal batch coverage --cell C --seeds N [--poses P] [--first-seed S] [--scheduler tcp://...]
    trackcal batch rho0 PLAN.json --cell C --runs N [--seed S] [--scheduler tcp://...]

`coverage`, the honesty check of identification: N simulated campaigns of the twin (each seed its own robot, poses
and noise, as `trackcal simulate --seed`), each identified; per parameter, how often its 95 % interval holds the
twin's true deviation, and how often the joint 95 % region (F test of the whole parameter vector) holds the truth.
With honest intervals each count is Binomial(N, 0.95) exactly (linear-Gaussian theory; the KR-270 problem is linear
to far below the noise at its deviations), so a count outside the binomial band says the intervals are too narrow
or too wide. `rho0`: plan's criterion by simulation: N campaigns of the plan (calib.doe.design.monte_carlo_rho0:
truth at nominal, the plan's noise), each identified as a campaign is (robot parameters, stations and points); the
mean squared error of the points' centroid at the test pose (first station's frame) against rho0^2, whose
Monte-Carlo standard error is sqrt(2 sum lambda_i^2 / N) (|dp|^2 is a sum of chi2(1) weighted by the eigenvalues
lambda_i of G C G^T). Every seed and run draws from its own generator, so the
result does not depend on how the work is split or where it runs.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy import stats

from trackcal.calib.doe.design import Design, monte_carlo_rho0
from trackcal.calib.identify.noise import DEFAULT_WEIGHTING, noise_for
from trackcal.calib.identify.solver import identify
from trackcal.calib.io.files import read_json, write_json
from trackcal.calib.model.cell import load_cell
from trackcal.campaign.errors import InputError, OptionError
from trackcal.campaign.jobs.batch import Progress, map_chunks
from trackcal.campaign.jobs.identify import choose_params
from trackcal.campaign.jobs.limits import check_memory
from trackcal.campaign.jobs.plan import PlanOptions, build_design
from trackcal.campaign.jobs.simulate import SimulateOptions, simulate

COVERAGE_CHUNK = 8  # seeds per task (one identification each, ~0.1 s)
RHO0_CHUNK = 20  # runs per task (one identification each, ~0.1 s)
LEVEL = 0.95  # the intervals' nominal coverage
# a count outside the central BAND of Binomial(n, 0.95) says the intervals are dishonest; with ~20 counts checked
# at once, 99.9 % keeps the chance of a false alarm near 2 %
BAND = 0.999
# what the parent holds per seed (its row: the names and one flag per parameter, 1.6 KiB by sys.getsizeof over the
# row's objects for the KR-270's 18 parameters, doubled for longer names and the transfer) and per run (its index
# and its error in a tuple, 108 bytes), to refuse a count the machine cannot hold
SEED_BYTES = 4096
RUN_BYTES = 200
# the Monte-Carlo mean of |dp|^2 further than this many of its standard errors from rho0^2 disagrees with rho0
RHO0_SIGMAS = 4.0


@dataclass(frozen=True)
class CoverageOptions:
    cell: str
    seeds: int = 200
    first_seed: int = 0
    poses: int = 30
    params: str | None = None
    weighting: str = DEFAULT_WEIGHTING
    scheduler: str | None = None
    chunk: int = COVERAGE_CHUNK
    json: str | None = None


def coverage_seed(opts: CoverageOptions, seed: int) -> dict:
    """One simulated campaign, identified: which intervals hold the truth, and whether the joint region does."""
    cell, twin, table = simulate(SimulateOptions(cell=opts.cell, poses=opts.poses, seed=seed))
    params = choose_params(cell, opts.params)
    res = identify(cell.chain, table, cell.tool_points, params, noise=noise_for(opts.weighting))
    truth = np.array([twin.true_dev[twin.params.index(p)] for p in params])
    err = res.dev - truth
    f = float(err @ np.linalg.solve(res.param_cov(), err) / len(err))
    return {
        "seed": seed,
        "names": [p.name for p in params],
        "inside": (np.abs(err) <= res.param_ci95()).tolist(),
        "joint": bool(f <= stats.f.ppf(LEVEL, len(err), res.dof)),
    }


def coverage_chunk(seeds: list[int], opts: CoverageOptions) -> list[dict]:
    return [coverage_seed(opts, s) for s in seeds]


@dataclass
class Coverage:
    names: list[str]
    n: int
    inside: list[int]  # per parameter: seeds whose interval holds the truth
    joint: int  # seeds whose joint region holds the truth
    band: tuple[int, int]  # the central BAND of Binomial(n, LEVEL)
    p_values: list[float]  # two-sided binomial test of each count (the parameters, then the joint region)
    honest: bool
    sentence: str


def coverage_counts(rows: list[dict]) -> Coverage:
    names = rows[0]["names"]
    n = len(rows)
    inside = np.sum([r["inside"] for r in rows], axis=0).astype(int).tolist()
    joint = sum(r["joint"] for r in rows)
    lo, hi = (int(v) for v in stats.binom.interval(BAND, n, LEVEL))
    counts = [*inside, joint]
    p_values = [float(stats.binomtest(k, n, LEVEL).pvalue) for k in counts]
    outside = [name for name, k in zip([*names, "joint"], counts, strict=True) if not lo <= k <= hi]
    span = f"{min(counts) / n:.1%}-{max(counts) / n:.1%}"
    if outside:
        sentence = (
            f"not honest: over {n} simulated campaigns the truth was inside the 95 % intervals {span} of "
            f"the time, and {', '.join(outside)} fell outside the {BAND:.1%} binomial band "
            f"[{lo}, {hi}]"
        )
    else:
        sentence = (
            f"honest: over {n} simulated campaigns the truth was inside the 95 % intervals {span} of the time, "
            f"every count within the {BAND:.1%} binomial band [{lo}, {hi}] of {n} draws at 95 %"
        )
    return Coverage(names, n, inside, joint, (lo, hi), p_values, not outside, sentence)


def _seeds_chunks(first: int, n: int, chunk: int) -> list[list[int]]:
    ids = list(range(first, first + n))
    return [ids[i : i + chunk] for i in range(0, n, chunk)]


def coverage(opts: CoverageOptions, progress: Progress | None = None) -> Coverage:
    if opts.seeds < 2:
        raise OptionError("{0} must be at least 2", "seeds")
    if opts.chunk < 1 or opts.poses < 1:
        raise OptionError("{0} and {1} must be at least 1", "chunk", "poses")
    check_memory("seeds", opts.seeds, lambda n: n * SEED_BYTES, "seed")
    load_cell(opts.cell)  # a wrong cell is one line here, not one per worker
    rows = []
    for part in map_chunks(
        coverage_chunk,
        _seeds_chunks(opts.first_seed, opts.seeds, opts.chunk),
        (opts,),
        opts.scheduler,
        progress=progress,
    ):
        rows.extend(part)
    rows.sort(key=lambda r: r["seed"])
    result = coverage_counts(rows)
    if opts.json:
        write_json(
            opts.json,
            {
                "cell": opts.cell,
                "seeds": [opts.first_seed, opts.first_seed + opts.seeds - 1],
                "poses": opts.poses,
                "weighting": opts.weighting,
                "level": LEVEL,
                "n": result.n,
                "parameters": {n: k for n, k in zip(result.names, result.inside, strict=True)},
                "joint": result.joint,
                "band": list(result.band),
                "p_values": result.p_values,
                "honest": result.honest,
                "sentence": result.sentence,
            },
            InputError,
        )
    return result


@dataclass(frozen=True)
class Rho0Options:
    plan: str  # plan.json of `trackcal plan`
    cell: str
    runs: int = 1000
    seed: int = 0
    scheduler: str | None = None
    chunk: int = RHO0_CHUNK
    json: str | None = None


def _plan_doc(path: str) -> dict:
    doc = read_json(path, InputError)
    need = ("poses_deg", "repeat", "params", "test_pose_deg", "noise", "sigma_mm", "visibility")
    missing = [k for k in need if k not in doc]
    if missing:
        raise InputError(f"{path}: not a plan of `trackcal plan` (no {', '.join(missing)})")
    return doc


@lru_cache(maxsize=4)
def _design(cell_ref: str, plan_text: str) -> tuple[Design, np.ndarray, int]:
    """The plan's design (its parameters, test pose, noise and visibility), its poses (rad) and repeat: built once
    per worker process."""
    doc = json.loads(plan_text)
    opts = PlanOptions(
        params=",".join(doc["params"]),
        test_pose=",".join(str(v) for v in doc["test_pose_deg"]),
        sigma_mm=doc["sigma_mm"] if doc["noise"] == "iid" else None,
        noise=doc["noise"],
        visibility=bool(doc["visibility"]),
    )
    return build_design(load_cell(cell_ref), opts), np.radians(np.asarray(doc["poses_deg"], float)), int(doc["repeat"])


def rho0_chunk(runs: list[int], cell_ref: str, plan_text: str, seed: int) -> list[tuple[int, float]]:
    """(i, |dp| at the test pose, mm) of each simulated campaign, run i drawing from the generator of (seed, i)."""
    design, q, repeat = _design(cell_ref, plan_text)
    errors = monte_carlo_rho0(design, q, repeat, len(runs), [np.random.default_rng([seed, i]) for i in runs])
    return list(zip(runs, errors.tolist(), strict=True))


@dataclass
class Rho0:
    runs: int
    rho0_mm: float  # the plan's criterion, analytic
    monte_carlo_mm: float  # sqrt of the mean squared TCP error over the runs
    standard_error_mm2: float  # of the mean squared error
    z: float  # (mean |dp|^2 - rho0^2) / its standard error
    agrees: bool
    sentence: str


def rho0(opts: Rho0Options, progress: Progress | None = None) -> Rho0:
    if opts.runs < 2:
        raise OptionError("{0} must be at least 2", "runs")
    if opts.chunk < 1:
        raise OptionError("{0} must be at least 1", "chunk")
    check_memory("runs", opts.runs, lambda n: n * RUN_BYTES, "run")
    doc = _plan_doc(opts.plan)
    plan_text = json.dumps(doc, sort_keys=True)
    design, q, repeat = _design(opts.cell, plan_text)
    errors = []
    for part in map_chunks(
        rho0_chunk,
        _seeds_chunks(0, opts.runs, opts.chunk),
        (opts.cell, plan_text, opts.seed),
        opts.scheduler,
        progress=progress,
    ):
        errors.extend(part)
    e2 = np.square([e for _, e in sorted(errors)])  # in run order: the sum does not depend on the chunks' order
    lam = np.linalg.eigvalsh(design.j0 @ np.linalg.inv(design.information(q, repeat)) @ design.j0.T)
    analytic = design.rho0(q, repeat)
    se = float(np.sqrt(2 * np.sum(lam**2) / len(e2)))
    z = float((e2.mean() - analytic**2) / se)
    agrees = abs(z) < RHO0_SIGMAS
    verdict = "agrees with" if agrees else "disagrees with"
    sentence = (
        f"Monte-Carlo rho0 {np.sqrt(e2.mean()) * 1000:.2f} µm over {len(e2)} simulated campaigns of the plan "
        f"{verdict} the analytic rho0 {analytic * 1000:.2f} µm (mean squared error {z:+.1f} standard errors "
        f"from rho0^2; {RHO0_SIGMAS:g} allowed)"
    )
    result = Rho0(len(e2), analytic, float(np.sqrt(e2.mean())), se, z, agrees, sentence)
    if opts.json:
        write_json(
            opts.json,
            {
                "plan": opts.plan,
                "cell": opts.cell,
                "runs": result.runs,
                "seed": opts.seed,
                "rho0_mm": analytic,
                "monte_carlo_rho0_mm": result.monte_carlo_mm,
                "standard_error_mm2": se,
                "z": z,
                "agrees": agrees,
                "sentence": sentence,
            },
            InputError,
        )
    return result
