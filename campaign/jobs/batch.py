"""`batch identify | diagnose` on typed options: many campaigns on a process pool or a Dask cluster.

    trackcal batch identify|diagnose INPUT ... --out DIR [--cell C] [--params ...] [--scheduler tcp://...]

An INPUT is a measurement table (CSV; its cell from `--cell`), a session folder (its exported table and its stored
cell), or a folder holding either (one level down). Each campaign's result goes to DIR under a key: the sha256 of
the table's bytes, the cell's, the task and its options. A result already in DIR is not computed again, so a killed
batch, run again, does only what is left; a campaign that fails is reported with its one line and does not stop the
others (its error is not kept: run again, it is tried again). Work is sent in chunks of several campaigns, so that a
worker's start-up (numpy, scipy, pinocchio) is paid once per chunk, on a local process pool by default or on a Dask
cluster (`--scheduler`), through the same executor `trackcal plan` uses.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import time
from collections.abc import Callable
from concurrent.futures import as_completed
from dataclasses import dataclass, field
from pathlib import Path

from trackcal.calib.errors import CalibError
from trackcal.calib.identify.noise import DEFAULT_WEIGHTING
from trackcal.calib.io.files import write_json
from trackcal.campaign.errors import CampaignError, InputError, OptionError
from trackcal.campaign.jobs.diagnose import DiagnoseOptions, run_diagnose
from trackcal.campaign.jobs.identify import IdentifyOptions, identify_table
from trackcal.campaign.jobs.plan import executor_for
from trackcal.campaign.session.session import SessionFiles
from trackcal.campaign.session.store import DB_NAME

TASKS = ("identify", "diagnose")
CHUNK = 4  # campaigns per task sent to a worker


@dataclass(frozen=True)
class Campaign:
    label: str
    table: str
    cell: str


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


def _session(d: Path) -> Campaign:
    files = SessionFiles(d)
    if not files.table.exists():
        raise InputError(f"{d}: the session has no exported table (its campaign has not ended: `trackcal resume`)")
    return Campaign(str(d), str(files.table), str(files.cell))


def find_campaigns(inputs: list[str], cell: str | None) -> list[Campaign]:
    """The campaigns of the inputs, in the order given (a folder's entries sorted by name)."""
    out = []

    def table(p: Path) -> Campaign:
        if cell is None:
            raise OptionError("{0} is needed for the table {path} (a session knows its cell)", "cell", path=p)
        return Campaign(str(p), str(p), cell)

    for text in inputs:
        p = Path(text)
        if (p / DB_NAME).exists():
            out.append(_session(p))
        elif p.is_dir():
            for child in sorted(p.iterdir()):
                if (child / DB_NAME).exists():
                    out.append(_session(child))
                elif child.suffix == ".csv" and child.is_file():
                    out.append(table(child))
        elif p.is_file():
            out.append(table(p))
        else:
            raise InputError(f"{p}: no such table, session or folder")
    if not out:
        raise InputError(f"no campaign found in {', '.join(inputs)}")
    return out


def result_key(c: Campaign, opts: BatchOptions) -> str:
    """sha256 of what the result depends on: the table's and the cell's bytes, the task and its options."""
    h = hashlib.sha256()
    h.update(Path(c.table).read_bytes())
    cell_path = Path(c.cell)
    h.update(cell_path.read_bytes() if cell_path.is_file() else c.cell.encode())
    h.update(json.dumps([opts.task, opts.params, opts.weighting]).encode())
    return h.hexdigest()


def run_one(c: Campaign, opts: BatchOptions, key: str) -> dict:
    """One campaign's result row (written to DIR/KEY.json), or its error line."""
    out = Path(opts.out)
    t0 = time.process_time()
    try:
        if opts.task == "identify":
            doc = identify_table(IdentifyOptions(data=c.table, cell=c.cell, out=str(out / f"{key}.model.json"),
                                                 params=opts.params, weighting=opts.weighting)).doc  # fmt: skip
            row = {"fit": doc["fit"], "fit_ratio": doc["fit_ratio"], "residual_rms_mm": doc["residual_rms_mm"]}
        else:
            v = run_diagnose(DiagnoseOptions(data=c.table, cell=c.cell, json=str(out / f"{key}.verdict.json"),
                                             params=opts.params, weighting=opts.weighting,
                                             out=str(out / f"{key}.model.json"))).verdict  # fmt: skip
            row = {"cause": v["cause"], "causes": [x["cause"] for x in v["causes"]],
                   "holdout_geometric_mm": v["holdout"]["rms_geometric_mm"],
                   "holdout_extended_mm": v["holdout"]["rms_extended_mm"]}  # fmt: skip
    except (CalibError, CampaignError) as exc:
        return {"campaign": c.label, "key": key, "error": str(exc)}
    row = {"campaign": c.label, "key": key, "task": opts.task, "cell": c.cell, "cpu_s": time.process_time() - t0,
           **row}  # fmt: skip
    write_json(out / f"{key}.json", row, InputError)
    return row


def run_chunk(items: list[tuple[Campaign, str]], opts: BatchOptions) -> list[dict]:
    return [run_one(c, opts, key) for c, key in items]


@dataclass
class BatchResult:
    rows: list[dict]  # in the inputs' order: computed now, found in DIR, or failed
    computed: int
    reused: int
    failed: list[dict] = field(default_factory=list)


# progress(done, running, failed, total, seconds_left or None)
Progress = Callable[[int, int, int, int, float | None], None]


def batch(opts: BatchOptions, progress: Progress | None = None) -> BatchResult:
    if opts.task not in TASKS:
        raise OptionError("{0}: choose one of {tasks}", "task", tasks=", ".join(TASKS))
    if opts.chunk < 1:
        raise OptionError("{0} must be at least 1", "chunk")
    campaigns = find_campaigns(opts.inputs, opts.cell)
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
    todo = [(c, k) for c, k in zip(campaigns, keys, strict=True) if k not in found]
    chunks = [todo[i : i + opts.chunk] for i in range(0, len(todo), opts.chunk)]
    results: dict[str, dict] = dict(found)
    failed: list[dict] = []
    done, start = 0, time.monotonic()
    if progress:
        progress(0, min(len(todo), len(chunks) * opts.chunk), 0, len(todo), None)
    if chunks:
        with executor_for(opts.scheduler) as ex:
            futures = [ex.submit(run_chunk, chunk, opts) for chunk in chunks]
            for fut in as_completed(futures):
                for row in fut.result():
                    done += 1
                    if "error" in row:
                        failed.append(row)
                    else:
                        results[row["key"]] = row
                if progress:
                    rate = (time.monotonic() - start) / done
                    progress(done, len(todo) - done, len(failed), len(todo), rate * (len(todo) - done))
    rows = [results.get(k) or next(f for f in failed if f["key"] == k) for k in keys]
    return BatchResult(rows, len(todo) - len(failed), len(found), failed)
