"""`batch identify | diagnose | iso9283` on typed options: many campaigns on a process pool or a Dask cluster.

    trackcal batch identify|diagnose INPUT ... --out DIR [--cell C] [--params ...] [--scheduler tcp://...]
    trackcal batch iso9283 SESSION_OR_FOLDER ... --model model.json --out DIR [--scheduler tcp://...]

An INPUT is a measurement table (CSV; its cell from `--cell`), a session folder (its exported table and its stored
cell), a folder holding either, or a folder of robot folders holding either (`fleet/ROBOT/CAMPAIGN`: the campaigns
of one robot, named by its folder; otherwise the robot is the cell's, a cell holding one robot). Each campaign's
result goes to DIR under a key: the sha256 of the table's bytes (an ISO session: of its measurements and plan), the
cell's, the task and its options. A result already in DIR is not computed again, so a killed batch, run again, does
only what is left; a campaign that fails is reported with its one line and does not stop the others (its error is
not kept: run again, it is tried again), also when its pool worker dies (`worker died: signal 9`, map_chunks); a
lost Dask scheduler ends the batch in one line, the results written kept. Work is sent in chunks of several
campaigns (`map_chunks`, shared with the Monte-Carlo runs of campaign.jobs.montecarlo), so that a worker's start-up
(numpy, scipy, pinocchio) is paid once per chunk, on a local process pool by default or on a Dask cluster
(`--scheduler`), through the same executor `trackcal plan` uses.

The summary adds to each result its robot, its date (a session's first event, a table's file modification time),
and the parameter that changed most against its uncertainty: against the previous campaign of the same robot
(calib.history's difference of two estimates) or, for a robot's first campaign, against the nominal.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import signal
import time
from collections.abc import Callable, Generator, Iterator
from concurrent.futures import FIRST_COMPLETED, CancelledError, Executor, Future, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from trackcal.calib.errors import CalibError
from trackcal.calib.history import compare_estimates
from trackcal.calib.identify.noise import DEFAULT_WEIGHTING
from trackcal.calib.io.files import read_json, read_yaml, write_json
from trackcal.calib.model_file import load_model
from trackcal.campaign.errors import CampaignError, InputError, OptionError
from trackcal.campaign.jobs.diagnose import DiagnoseOptions, run_diagnose
from trackcal.campaign.jobs.history import model_estimate, session_start
from trackcal.campaign.jobs.identify import IdentifyOptions, identify_table
from trackcal.campaign.jobs.iso9283 import session_figures
from trackcal.campaign.jobs.plan import executor_for
from trackcal.campaign.jobs.pool import chunk_marks, how_it_died, run_marked, sealed
from trackcal.campaign.jobs.scheduler import SchedulerLost
from trackcal.campaign.session.session import PLAN_DOC, SessionFiles
from trackcal.campaign.session.store import DB_NAME, SessionStore

TASKS = ("identify", "diagnose", "iso9283")
CHUNK = 4  # campaigns per task sent to a worker
PROGRESS_EVERY_S = 1.0  # how often progress is reported while no chunk finishes


@dataclass(frozen=True)
class Campaign:
    label: str
    table: str  # the measurement table; an ISO session: the session folder
    cell: str
    robot: str


@dataclass(frozen=True)
class BatchOptions:
    task: str
    inputs: list[str]
    out: str
    cell: str | None = None
    params: str | None = None
    weighting: str = DEFAULT_WEIGHTING
    scheduler: str | None = None
    chunk: int = CHUNK
    model: str | None = None  # iso9283: the model whose station estimate gives the base frame


def _session(d: Path, robot: str | None, iso: bool) -> Campaign:
    files = SessionFiles(d)
    if iso:
        return Campaign(str(d), str(d), str(files.cell), robot or _cell_name(files.cell))
    if not files.table.exists():
        raise InputError(f"{d}: the session has no exported table (its campaign has not ended: `trackcal resume`)")
    return Campaign(str(d), str(files.table), str(files.cell), robot or _cell_name(files.cell))


def _cell_name(cell: str | Path) -> str:
    """A cell's name: the `name` its file gives (else the file's stem), or the name given."""
    if not str(cell).endswith((".yaml", ".yml")):
        return str(cell)
    with contextlib.suppress(InputError):  # an unreadable cell fails its campaign, with its line, later
        name = read_yaml(cell, InputError).get("name")
        if isinstance(name, str) and name:
            return name
    return Path(cell).stem


def find_campaigns(inputs: list[str], cell: str | None, iso: bool = False) -> list[Campaign]:
    """The campaigns of the inputs, in the order given (a folder's entries sorted by name); `iso`: sessions only."""
    out = []

    def table(p: Path, robot: str | None) -> Campaign:
        if iso:
            raise InputError(f"{p}: an ISO 9283 test is a session folder (`trackcal run --plan iso.json`), not a table")
        if cell is None:
            raise OptionError("{0} is needed for the table {path} (a session knows its cell)", "cell", path=p)
        return Campaign(str(p), str(p), cell, robot or _cell_name(cell))

    def folder(p: Path, robot: str | None) -> list[Campaign]:
        found = []
        for child in sorted(p.iterdir()):
            if (child / DB_NAME).exists():
                found.append(_session(child, robot, iso))
            elif child.suffix == ".csv" and child.is_file():
                found.append(table(child, robot))
            elif child.is_dir() and robot is None:  # a robot's folder
                found.extend(folder(child, child.name))
        return found

    for text in inputs:
        p = Path(text)
        if (p / DB_NAME).exists():
            out.append(_session(p, None, iso))
        elif p.is_dir():
            out.extend(folder(p, None))
        elif p.is_file():
            out.append(table(p, None))
        else:
            raise InputError(f"{p}: no such table, session or folder")
    if not out:
        raise InputError(f"no campaign found in {', '.join(inputs)}")
    return out


def _iso_digest(h, directory: Path) -> None:
    """What an ISO session's figures depend on: its plan and its measurements."""
    store = SessionStore.open(directory, readonly=True)
    try:
        h.update(store.documents().get(PLAN_DOC, "").encode())
        for e in store.events("measurement"):
            h.update(json.dumps(e.data, sort_keys=True).encode())
    finally:
        store.close()


def result_key(c: Campaign, opts: BatchOptions) -> str:
    """sha256 of what the result depends on: the table's (ISO: the session's) and the cell's bytes, the task and its
    options (ISO: the model's bytes)."""
    h = hashlib.sha256()
    if opts.task == "iso9283":
        _iso_digest(h, Path(c.table))
        h.update(Path(opts.model).read_bytes() if opts.model else b"")
    else:
        h.update(Path(c.table).read_bytes())
    cell_path = Path(c.cell)
    h.update(cell_path.read_bytes() if cell_path.is_file() else c.cell.encode())
    h.update(json.dumps([opts.task, opts.params, opts.weighting]).encode())
    return h.hexdigest()


def _iso_row(c: Campaign, opts: BatchOptions, key: str) -> dict:
    figures = session_figures(Path(c.table), load_model(opts.model))
    write_json(Path(opts.out) / f"{key}.iso9283.json", figures.to_doc(), InputError)
    return {
        "targets": figures.conditions["targets"],
        "cycles": figures.poses[0].n,
        "ap_max_mm": max(p.ap.value for p in figures.poses),
        "rp_max_mm": max(p.rp.value for p in figures.poses),
        "ad_mm": None if figures.ad is None else figures.ad.value,
    }


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or "(no message)"
    return text if isinstance(exc, CalibError | CampaignError) else f"{type(exc).__name__}: {text}"


def run_one(c: Campaign, opts: BatchOptions, key: str) -> dict:
    """One campaign's result row (written to DIR/KEY.json), or its error line."""
    out = Path(opts.out)
    t0 = time.process_time()
    try:
        if opts.task == "identify":
            doc = identify_table(
                IdentifyOptions(
                    data=c.table,
                    cell=c.cell,
                    out=str(out / f"{key}.model.json"),
                    params=opts.params,
                    weighting=opts.weighting,
                )
            ).doc
            row = {"fit": doc["fit"], "fit_ratio": doc["fit_ratio"], "residual_rms_mm": doc["residual_rms_mm"]}
        elif opts.task == "diagnose":
            v = run_diagnose(
                DiagnoseOptions(
                    data=c.table,
                    cell=c.cell,
                    json=str(out / f"{key}.verdict.json"),
                    params=opts.params,
                    weighting=opts.weighting,
                    threads=1,
                    out=str(out / f"{key}.model.json"),
                )
            ).verdict
            row = {
                "cause": v["cause"],
                "causes": [x["cause"] for x in v["causes"]],
                "holdout_geometric_mm": v["holdout"]["rms_geometric_mm"],
                "holdout_extended_mm": v["holdout"]["rms_extended_mm"],
            }
        else:
            row = _iso_row(c, opts, key)
    except Exception as exc:  # noqa: BLE001 - one campaign's failure, whatever it is, must not stop the others
        return {"campaign": c.label, "key": key, "error": _one_line(exc)}
    row = {"campaign": c.label, "key": key, "task": opts.task, "cell": c.cell, "cpu_s": time.process_time() - t0, **row}
    write_json(out / f"{key}.json", row, InputError)
    return row


def lost_chunk(items: list[tuple[Campaign, str]], out: Path, how: str) -> list[dict]:
    """The rows of a chunk whose worker died: the results it wrote before, an error line for the others."""
    rows = []
    for c, key in items:
        row = None
        with contextlib.suppress(OSError, ValueError):
            row = json.loads((out / f"{key}.json").read_text())
        rows.append(row or {"campaign": c.label, "key": key, "error": f"worker died: {how}"})
    return rows


def run_chunk(items: list[tuple[Campaign, str]], opts: BatchOptions) -> list[dict]:
    return [run_one(c, opts, key) for c, key in items]


# progress(done, running, failed, total, seconds_left or None)
Progress = Callable[[int, int, int, int, float | None], None]


def _slots(ex: Executor) -> int:
    """How many tasks the executor runs at once: a process pool's workers, a Dask cluster's threads."""
    workers = getattr(ex, "_max_workers", None)  # concurrent.futures.ProcessPoolExecutor
    if workers:
        return int(workers)
    client = getattr(ex, "_client", None)  # distributed.cfexecutor.ClientExecutor
    with contextlib.suppress(Exception):  # a cluster that cannot say: one task at a time
        return max(1, sum(client.nthreads().values()))
    return 1


# a pool that breaks while none of its workers died on its own (each ended by the pool's SIGTERM): the running chunks
# are run again on a new pool, so many times in a row at most
BLIND_REBUILDS = 3


def _dead_workers(processes: dict) -> dict[int, str]:
    """pid -> how it died, of the pool's workers that died on their own (the pool ends the others with SIGTERM)."""
    return {
        pid: how_it_died(p.exitcode)
        for pid, p in processes.items()
        if how_it_died(p.exitcode) and p.exitcode != -signal.SIGTERM
    }


# how a chunk whose Dask workers died is reported (distributed's KilledWorker: no signal is known)
KILLED_WORKERS = "every Dask worker that ran it died (KilledWorker: killed, out of memory?)"


def _lost(lost: Callable[[list, str], list] | None, chunk: list, how: str) -> list:
    """The rows of a chunk whose worker died (`lost`), or without `lost` a CampaignError."""
    if lost is None:
        raise CampaignError(f"a worker died ({how}: out of memory?) and its runs are lost")
    return lost(chunk, how)


def _after_a_broken_pool(
    pending: dict[Future, int],
    todo: dict[int, list],
    marks,
    processes: dict,
    lost: Callable[[list, str], list] | None,
    count: Callable[[list], list],
) -> Generator[list, None, int]:
    """map_chunks once its process pool has shut down (every worker's exit code is known): yields the chunks that
    finished before it broke, then each dead worker's chunk through `lost`, taking them out of `todo`; returns how
    many chunks a dead worker was running."""
    for fut, i in pending.items():  # finished before the pool broke
        if fut.done() and not isinstance(fut.exception(), BrokenProcessPool):
            del todo[i]
            yield count(fut.result())
    dead = _dead_workers(processes)
    culprits = [i for i in todo if marks[i] in dead]
    for i in culprits:
        yield count(_lost(lost, todo.pop(i), dead[marks[i]]))
    return len(culprits)


def _take_finished(
    finished: set[Future],
    pending: dict[Future, int],
    todo: dict[int, list],
    lost: Callable[[list, str], list] | None,
    count: Callable[[list], list],
) -> Generator[list, None, bool]:
    """map_chunks' round of finished futures: yields each one's chunk of results (through `count`), taking it out
    of `pending` and `todo`; a chunk whose Dask workers all died is lost (KILLED_WORKERS); a cancelled future (the
    client gave up on the scheduler) ends the round. Returns whether the process pool broke."""
    broken = False
    for fut in finished:
        try:
            rows = fut.result()
        except BrokenProcessPool:
            broken = True
            continue
        except CancelledError:  # the client gave up on the scheduler
            break
        except Exception as exc:
            if type(exc).__name__ != "KilledWorker":  # distributed's, without importing it
                raise
            # Dask ran the chunk again on a restarted worker (its allowed failures) and each died
            yield count(_lost(lost, todo.pop(pending.pop(fut)), KILLED_WORKERS))
            continue
        del todo[pending.pop(fut)]
        yield count(rows)
    return broken


def map_chunks(
    fn: Callable[..., list],
    chunks: list[list],
    args: tuple,
    scheduler: str | None,
    failed: Callable[[object], bool] = lambda r: False,
    progress: Progress | None = None,
    lost: Callable[[list, str], list] | None = None,
) -> Iterator[list]:
    """fn(chunk, *args) for every chunk, on executor_for(scheduler); each chunk's list of results as it finishes.
    Progress counts items: done, running (the chunks being computed: those a process pool says run, or on a cluster
    that does not say, the first of those not finished, as many as the cluster runs at once), failed (`failed` of
    a result), and the time left at the rate so far.

    A pool worker that dies (killed: an out-of-memory kill is SIGKILL) costs the chunk it was running:
    `lost(chunk, "signal 9")` gives that chunk's results (without `lost`: a CampaignError); the pool is made again
    and the other chunks go on. On Dask a killed worker's chunk is run again on another (or the restarted) worker,
    as many times as the scheduler allows; after that it is lost the same way (KILLED_WORKERS). A Dask scheduler
    that is killed, or silent for SCHEDULER_TIMEOUT_S (stopped), ends
    the map with SchedulerLost; what was yielded stays yielded."""
    total = sum(len(c) for c in chunks)
    done = bad = 0
    start = time.monotonic()

    def report(pending: dict[Future, int], slots: int) -> None:
        if not progress:
            return
        running = sum(len(todo[pending[f]]) for f in pending if f.running())
        if not running and pending:
            running = sum(len(todo[i]) for i in list(pending.values())[:slots])
        left = None if not done else (time.monotonic() - start) / done * (total - done)
        progress(done, running, bad, total, left)

    def count(rows: list) -> list:
        nonlocal done, bad
        done += len(rows)
        bad += sum(1 for r in rows if failed(r))
        return rows

    todo = dict(enumerate(chunks))  # index -> chunk, until its results are yielded
    blind = 0
    while todo:
        marks = None if scheduler else chunk_marks(len(chunks))
        broken = False
        with executor_for(scheduler, marks) as ex:
            watch = ex.watch if scheduler else None  # executor_for's scheduler.WatchedExecutor
            try:
                pending = {ex.submit(run_marked, sealed(fn, i, chunk, args)): i for i, chunk in todo.items()}
                processes = getattr(ex, "_processes", None)  # a process pool's pid -> Process, kept after it ends
                slots = _slots(ex)  # asked once: a scheduler that stops answering would not answer again
                report(pending, slots)
                while pending and not broken:
                    finished, _ = wait(list(pending), timeout=PROGRESS_EVERY_S, return_when=FIRST_COMPLETED)
                    broken = yield from _take_finished(finished, pending, todo, lost, count)
                    why = watch.lost() if watch else None
                    if why or (watch and any(f.cancelled() for f in pending)):
                        raise SchedulerLost(
                            f"the Dask scheduler {scheduler} was lost mid-run: "
                            f"{why or 'the client gave up reconnecting'}"
                        )
                    report(pending, slots)
            finally:
                if watch:
                    watch.close()
        if not broken:
            continue
        culprits = yield from _after_a_broken_pool(pending, todo, marks, processes or {}, lost, count)
        blind = 0 if culprits else blind + 1
        if blind > BLIND_REBUILDS:
            raise CampaignError(
                f"the process pool's workers keep being ended ({BLIND_REBUILDS + 1} times in a row, "
                "none of them on its own): something on this machine stops them"
            )


@dataclass
class BatchResult:
    rows: list[dict]  # in the inputs' order: computed now, found in DIR, or failed; with robot, date, worst change
    computed: int
    reused: int
    failed: list[dict] = field(default_factory=list)


def campaign_date(c: Campaign) -> tuple[datetime, str]:
    """(when the campaign ran, how that is known): a session's first event, else the table file's modification."""
    folder = Path(c.table) if Path(c.table).is_dir() else Path(c.table).parent
    if (folder / DB_NAME).exists():
        with contextlib.suppress(InputError):
            return session_start(folder), "campaign start"
    return datetime.fromtimestamp(Path(c.table).stat().st_mtime, UTC), "file modified"


def _estimate(path: Path) -> tuple[list[str], np.ndarray, np.ndarray, int, dict] | None:
    """(names, values, covariance, dof, units) of a model.json, or None without a covariance."""
    try:
        doc = read_json(path, InputError)
        names, values, cov, dof = model_estimate(doc, path)
        return names, values, cov, dof, {n: doc["parameters"][n].get("unit", "") for n in names}
    except (InputError, ValueError, KeyError, TypeError):
        return None


def worst_change(this: tuple, previous: tuple | None, previous_label: str | None) -> dict | None:
    """The parameter whose change is largest against its standard deviation: against the previous estimate of the
    same robot (sigma from the sum of both covariances, calib.history), else against nominal (the estimate's own
    deviation and sigma)."""
    names, values, cov, dof, units = this
    if previous is not None:
        with contextlib.suppress(CalibError):
            c = compare_estimates(previous[0], previous[1], previous[2], previous[3], names, values, cov, dof)
            i = int(np.argmax(np.abs(c.difference) / c.sigma))
            return {
                "parameter": c.names[i],
                "change": float(c.difference[i]),
                "sigma": float(c.sigma[i]),
                "unit": units.get(c.names[i], ""),
                "against": f"previous ({previous_label})",
                "robot_changed": c.changed,
            }
    sigma = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    if not len(sigma) or not np.all(sigma > 0):
        return None
    i = int(np.argmax(np.abs(values) / sigma))
    return {
        "parameter": names[i],
        "change": float(values[i]),
        "sigma": float(sigma[i]),
        "unit": units.get(names[i], ""),
        "against": "nominal",
        "robot_changed": None,
    }


def annotate(campaigns: list[Campaign], rows: list[dict], out: Path) -> None:
    """Each row's robot, date and worst parameter change (robots' campaigns in date order)."""
    dated = []
    for c, row in zip(campaigns, rows, strict=True):
        when, source = campaign_date(c)
        row.update(robot=c.robot, date=when.isoformat(), date_source=source)
        dated.append((when, c, row))
    last: dict[str, tuple] = {}
    for _, c, row in sorted(dated, key=lambda t: (t[1].robot, t[0])):
        est = None if "error" in row else _estimate(out / f"{row['key']}.model.json")
        if est is None:
            row["worst_change"] = None
            continue
        prev = last.get(c.robot)
        row["worst_change"] = worst_change(est, prev[0] if prev else None, prev[1] if prev else None)
        last[c.robot] = (est, c.label)


def batch(opts: BatchOptions, progress: Progress | None = None) -> BatchResult:
    if opts.task not in TASKS:
        raise OptionError("{0}: choose one of {tasks}", "task", tasks=", ".join(TASKS))
    if opts.chunk < 1:
        raise OptionError("{0} must be at least 1", "chunk")
    if opts.task == "iso9283":
        if not opts.model:
            raise OptionError("{0} is needed: the model whose station estimate gives the base frame", "model")
        if not Path(opts.model).is_file():
            raise InputError(f"{opts.model}: no such model")
    campaigns = find_campaigns(opts.inputs, opts.cell, iso=opts.task == "iso9283")
    out = Path(opts.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"{out}: cannot create the results folder ({exc.strerror})") from None
    keys = [result_key(c, opts) for c in campaigns]
    found = {}
    for k in keys:
        path = out / f"{k}.json"
        if path.exists():
            with contextlib.suppress(OSError, ValueError):  # unreadable: computed again
                found[k] = json.loads(path.read_text())
    todo = list(dict(((k, c) for c, k in zip(campaigns, keys, strict=True) if k not in found)).items())
    chunks = [[(c, k) for k, c in todo[i : i + opts.chunk]] for i in range(0, len(todo), opts.chunk)]
    results: dict[str, dict] = dict(found)
    failed: dict[str, dict] = {}
    try:
        for chunk_rows in map_chunks(
            run_chunk,
            chunks,
            (opts,),
            opts.scheduler,
            lambda r: "error" in r,
            progress,
            lambda chunk, how: lost_chunk(chunk, out, how),
        ):
            for row in chunk_rows:
                if "error" in row:
                    failed[row["key"]] = row
                else:
                    results[row["key"]] = row
    except SchedulerLost as exc:
        written = sum(1 for k, _ in todo if (out / f"{k}.json").exists())
        raise SchedulerLost(
            f"{exc}; results written are kept ({written} of {len(todo)} in {out}): run the same "
            "batch again to do the rest"
        ) from None
    rows = [dict(results.get(k) or failed[k], campaign=c.label) for c, k in zip(campaigns, keys, strict=True)]
    annotate(campaigns, rows, out)
    return BatchResult(rows, len(todo) - len(failed), len(found), [r for r in rows if "error" in r])
