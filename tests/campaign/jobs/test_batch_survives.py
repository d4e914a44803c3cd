"""A batch survives its workers (issue 42): a pool worker killed mid-chunk (SIGKILL, as an out-of-memory kill) costs
its own chunk's campaigns one line each and the others are done; pool workers die with the batch process; a Dask
scheduler killed or stopped mid-batch is one line and exit 2, the results already written kept. The campaigns here
are stand-ins (run_one replaced: in the pool's workers, forked from this process, and in the Dask worker by its
preload), so what is timed is the batch's machinery, not an identification."""

import contextlib
import json
import multiprocessing
import os
import signal
import socket
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from tests.helpers import ROOT, TRACKCAL
from trackcal.campaign.cli import main
from trackcal.campaign.jobs import batch as batch_job
from trackcal.campaign.jobs import scheduler as scheduler_job
from trackcal.campaign.jobs.batch import BatchOptions, batch
from trackcal.campaign.jobs.scheduler import SchedulerLost

# run_one of a stand-in campaign (tests only): its row written at once; the table's text says what else it does
STAND_IN = """
import os, signal, time
from pathlib import Path
from trackcal.calib.io.files import write_json
from trackcal.campaign.errors import InputError

def stand_in(c, opts, key):
    text = Path(c.table).read_text()
    if "die" in text:
        os.kill(os.getpid(), signal.SIGKILL)  # as the kernel's out-of-memory killer does
    if "hang" in text:
        time.sleep(3600)
    row = {"campaign": c.label, "key": key, "task": opts.task, "cell": c.cell, "fit": "good", "fit_ratio": 1.0,
           "residual_rms_mm": 0.01, "cpu_s": 0.0}
    write_json(Path(opts.out) / f"{key}.json", row, InputError)
    return row
"""
_stand_in: dict = {}
exec(STAND_IN, _stand_in)  # noqa: S102 - the same text the Dask worker's preload runs
stand_in = _stand_in["stand_in"]


def _tables(d: Path, what: dict[str, str]) -> Path:
    d.mkdir()
    for name, text in what.items():
        (d / f"{name}.csv").write_text(f"{name} {text}\n")  # distinct bytes: distinct result keys
    return d


fork_only = pytest.mark.skipif(
    multiprocessing.get_start_method() != "fork", reason="the stand-in reaches the pool's workers by fork"
)


@fork_only
def test_a_killed_worker_costs_its_chunk_and_the_others_are_done(tmp_path, monkeypatch, capsys):
    """Chunks of 2: t2 kills its worker (SIGKILL) after t1, of the same chunk, wrote its result. t1's result is
    kept, t2 is its one line "worker died: signal 9", the pool is made again and t3..t6 are done."""
    monkeypatch.setattr(batch_job, "run_one", stand_in)
    tables = _tables(tmp_path / "in", {"t1": "ok", "t2": "die", "t3": "ok", "t4": "ok", "t5": "ok", "t6": "ok"})
    result = batch(
        BatchOptions(task="identify", inputs=[str(tables)], out=str(tmp_path / "res"), cell="kr270", chunk=2)
    )
    rows = {Path(r["campaign"]).stem: r for r in result.rows}
    assert [Path(r["campaign"]).stem for r in result.failed] == ["t2"]
    assert rows["t2"]["error"] == "worker died: signal 9"
    assert all(rows[t]["fit"] == "good" for t in ("t1", "t3", "t4", "t5", "t6"))
    assert (result.computed, result.reused) == (5, 0)
    # the command line (chunks of batch.CHUNK = 4: t1..t4): one line for each campaign the dead worker did not
    # finish, exit 2, no traceback
    code = main(["batch", "identify", str(tables), "--cell", "kr270", "--out", str(tmp_path / "cli")])
    out, err = capsys.readouterr()
    assert code == 2 and "Traceback" not in out + err
    assert [line for line in out.splitlines() if line.startswith("failed: ")] == [
        f"failed: {tables / f't{i}.csv'}: worker died: signal 9" for i in range(2, batch_job.CHUNK + 1)
    ]


def _gone(pid: int) -> bool:
    """Exited: no such process, or a zombie nobody reaped (its parent died)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "Z"
    except OSError:
        return True


@pytest.mark.skipif(not Path("/proc/self/task").exists(), reason="reads /proc")
def test_pool_workers_die_with_the_batch(tmp_path):
    """kill -9 of the batch process alone while its workers run (each in a campaign that would take an hour): every
    worker exits (within 30 s; the kernel's parent-death signal takes milliseconds)."""
    tables = _tables(tmp_path / "in", {"t1": "hang", "t2": "hang", "t3": "hang"})
    script = textwrap.dedent(f"""
        import sys
        {textwrap.indent(STAND_IN, "        ").strip()}
        from trackcal.campaign.cli import main
        from trackcal.campaign.jobs import batch
        batch.run_one = stand_in
        sys.exit(main(["batch", "identify", {str(tables)!r}, "--cell", "kr270", "--out", {str(tmp_path / "res")!r}]))
    """)
    proc = subprocess.Popen(
        [sys.executable, "-c", script], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True
    )
    try:
        children = Path(f"/proc/{proc.pid}/task/{proc.pid}/children")
        deadline = time.monotonic() + 120
        workers: list[int] = []
        while len(workers) < 2 and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
            workers = [int(p) for p in children.read_text().split()]
        assert len(workers) >= 2, "the batch's pool did not start"
        time.sleep(0.5)  # the workers are in their campaigns
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        deadline = time.monotonic() + 30
        while not all(_gone(w) for w in workers) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert [w for w in workers if not _gone(w)] == [], "pool workers outlived the batch"
    finally:
        os.killpg(proc.pid, signal.SIGKILL)  # the workers are in its session: nothing left behind


# ------------------------------------------------------------------------------------------------------ Dask
def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _accepts(port: int) -> bool:
    with socket.socket() as s:
        return s.connect_ex(("127.0.0.1", port)) == 0


def _dask(*args: str, log: Path, env: dict[str, str] | None = None) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "distributed.cli.dask_" + args[0], *args[1:]],
        cwd=ROOT,
        stdout=log.open("w"),
        stderr=subprocess.STDOUT,
        start_new_session=True,
        env={**os.environ, **(env or {})},
    )


@pytest.fixture
def dask_cluster(tmp_path):
    """A `dask scheduler` and a `dask worker` (1 thread, the stand-in campaigns preloaded) in processes of their own
    on loopback."""
    with _cluster(tmp_path, STAND_IN + "\nfrom trackcal.campaign.jobs import batch\nbatch.run_one = stand_in\n") as c:
        yield c


@contextlib.contextmanager
def _cluster(tmp_path: Path, preloaded: str, nanny: bool = False, env: dict[str, str] | None = None):
    """A `dask scheduler` (its environment plus `env`) and a `dask worker` (1 thread, `preloaded` run by the worker
    at its start; under a nanny that starts it again when it dies, if `nanny`); yields the scheduler's process and
    address."""
    distributed = pytest.importorskip("distributed")
    port = _free_port()
    preload = tmp_path / "stand_in_preload.py"
    preload.write_text(preloaded)
    scheduler = _dask(
        "scheduler",
        "--host",
        "127.0.0.1",
        "--port",
        str(port),
        "--no-dashboard",
        log=tmp_path / "scheduler.log",
        env=env,
    )
    deadline = time.monotonic() + 60
    while not _accepts(port):
        assert scheduler.poll() is None and time.monotonic() < deadline, (tmp_path / "scheduler.log").read_text()
        time.sleep(0.1)
    worker = _dask(
        "worker",
        f"tcp://127.0.0.1:{port}",
        *([] if nanny else ["--no-nanny"]),
        "--nthreads",
        "1",
        "--no-dashboard",
        "--preload",
        str(preload),
        log=tmp_path / "worker.log",
    )
    try:
        # the tests start once the worker serves: a chunk sent to a worker still starting under its nanny, which the
        # chunk then killed, failed the nanny's start and ended `dask worker` (no worker again: on a loaded machine the
        # batch was quicker than the worker, issue 37)
        with distributed.Client(f"tcp://127.0.0.1:{port}", timeout=60) as client:
            client.wait_for_workers(1, timeout=120)
        yield scheduler, f"tcp://127.0.0.1:{port}"
    finally:
        for p in (scheduler, worker):
            with contextlib.suppress(ProcessLookupError):
                os.killpg(p.pid, signal.SIGCONT)
                os.killpg(p.pid, signal.SIGKILL)
            p.wait()


@pytest.mark.parametrize(
    "how", [signal.SIGKILL, pytest.param(signal.SIGSTOP, marks=pytest.mark.slow)], ids=["killed", "stopped"]
)  # stopped: 10 s of silence at least
def test_a_lost_scheduler_is_one_line_and_keeps_the_results(tmp_path, dask_cluster, how):
    """t1 is written, t2 hangs (an hour): then the scheduler is killed, or stopped (it keeps its connections and
    never answers). The batch ends in one line and exit 2 within 60 s (it waits the 10 s `--scheduler` waits to
    connect, campaign.jobs.plan, plus a probe's second), t1's result kept as it was."""
    scheduler, address = dask_cluster
    tables = _tables(tmp_path / "in", {"t1": "ok", "t2": "hang", "t3": "ok"})
    out = tmp_path / "res"
    proc = subprocess.Popen(
        [*TRACKCAL, "batch", "identify", str(tables), "--cell", "kr270", "--out", str(out), "--scheduler", address],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    try:
        deadline = time.monotonic() + 120
        while not list(out.glob("*.json")) and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        kept = {p.name: p.read_bytes() for p in out.glob("*.json")}
        assert len(kept) == 1 and json.loads(next(iter(kept.values())))["campaign"].endswith("t1.csv")
        os.kill(scheduler.pid, how)
        t0 = time.monotonic()
        _, err = proc.communicate(timeout=60)
        assert time.monotonic() - t0 < 60
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 2 and err.count("\n") == 1, err
    assert f"the Dask scheduler {address} was lost mid-run" in err and f"kept (1 of 3 in {out})" in err, err
    assert {p.name: p.read_bytes() for p in out.glob("*.json")} == kept


def test_a_cluster_left_without_a_worker_ends_the_batch_in_one_line(tmp_path, dask_cluster, monkeypatch):
    """t2 kills the cluster's one worker (no nanny: nothing starts it again) after t1 was written; the scheduler still
    answers, saying it has no worker. The batch ends (SchedulerLost: one line and exit 2 on the command line) once
    the scheduler has had no worker for scheduler.NO_WORKER_S (here 1 s), t1's result kept; it waited for ever."""
    distributed = pytest.importorskip("distributed")
    _, address = dask_cluster
    with distributed.Client(address, timeout="60s") as client:
        client.wait_for_workers(1, timeout=120)  # the bound counts from the batch's start: its worker is there
    monkeypatch.setattr(scheduler_job, "NO_WORKER_S", 1.0)
    tables = _tables(tmp_path / "in", {"t1": "ok", "t2": "die", "t3": "ok"})
    out = tmp_path / "res"
    with pytest.raises(SchedulerLost, match="has had no worker for") as lost:
        batch(BatchOptions(task="identify", inputs=[str(tables)], out=str(out), cell="kr270", scheduler=address))
    assert "kept (1 of 3" in str(lost.value) and "\n" not in str(lost.value)
    assert [json.loads(p.read_text())["campaign"] for p in out.glob("*.json")] == [str(tables / "t1.csv")]


# slow: its worker is started again twice by its nanny (a process that imports numpy, scipy, pinocchio each time):
# about a minute on a loaded 2-core machine. It once waited past its 600 s: a nanny that fails to start its worker
# again leaves the cluster without one, and the batch waited for one for ever; now it gives up after
# scheduler.NO_WORKER_S (test_a_cluster_left_without_a_worker_ends_the_batch_in_one_line)
@pytest.mark.slow
def test_a_dask_worker_that_dies_costs_its_chunk_and_the_others_are_done(tmp_path):
    """t2 kills its Dask worker (SIGKILL, as the kernel's out-of-memory killer does) every time it runs; its nanny
    starts the worker again and the scheduler runs the chunk again (once: allowed-failures 1 here, Dask's
    distributed.scheduler.allowed-failures), then gives up (KilledWorker). The chunk's campaigns not finished are one
    line each, t1's result (written before) kept, the next chunk done; exit 2, no traceback (it was KilledWorker's
    traceback, exit 1, the other campaigns lost)."""
    tables = _tables(tmp_path / "in", {"t1": "ok", "t2": "die", "t3": "ok", "t4": "ok", "t5": "ok", "t6": "ok"})
    preload = STAND_IN + "\nfrom trackcal.campaign.jobs import batch\nbatch.run_one = stand_in\n"
    # worker-saturation 1: the scheduler sends the worker one chunk per thread, so the next chunk is not on it when it
    # dies (Dask counts the death against every task the worker held)
    once = {
        "DASK_DISTRIBUTED__SCHEDULER__ALLOWED_FAILURES": "1",
        "DASK_DISTRIBUTED__SCHEDULER__WORKER_SATURATION": "1.0",
    }
    with _cluster(tmp_path, preload, nanny=True, env=once) as (_, address):
        out = subprocess.run(
            [
                *TRACKCAL,
                "batch",
                "identify",
                str(tables),
                "--cell",
                "kr270",
                "--out",
                str(tmp_path / "res"),
                "--scheduler",
                address,
            ],
            capture_output=True,
            text=True,
            timeout=600,
        )
    assert out.returncode == 2 and "Traceback" not in out.stdout + out.stderr, out.stderr
    failed = [line for line in out.stdout.splitlines() if line.startswith("failed: ")]
    assert failed == [
        f"failed: {tables / f't{i}.csv'}: worker died: {batch_job.KILLED_WORKERS}"
        for i in range(2, batch_job.CHUNK + 1)
    ], out.stdout
    written = sorted(json.loads(p.read_text())["campaign"] for p in (tmp_path / "res").glob("*.json"))
    assert [Path(c).stem for c in written] == ["t1", "t5", "t6"]


# the plan's start task (calib.doe.design._exchanged_refined, which the client sends by reference) replaced in the Dask
# worker: it says it started, then computes for an hour
PLAN_STAND_IN = """
import time
from pathlib import Path
from trackcal.calib.doe import design

def hang(task):
    Path({mark!r}).write_text("started")
    time.sleep(3600)

design._exchanged_refined = hang  # the task each start is (calib.doe.design.optimize_plan)
"""


@pytest.mark.parametrize(
    "how", [signal.SIGKILL, pytest.param(signal.SIGSTOP, marks=pytest.mark.slow)], ids=["killed", "stopped"]
)  # stopped: 10 s of silence at least
def test_a_plan_whose_scheduler_is_lost_is_one_line(tmp_path, how):
    """`plan --scheduler`: once the worker computes, the scheduler is killed or stopped. The plan ends in one line and
    exit 2 within 60 s (the 10 s `--scheduler` waits, campaign.jobs.plan, plus a probe's second), writing nothing;
    it waited for ever on a stopped scheduler, and a killed one ended in CancelledError's traceback."""
    mark, out = tmp_path / "started", tmp_path / "plan.json"
    with _cluster(tmp_path, PLAN_STAND_IN.format(mark=str(mark))) as (scheduler, address):
        proc = subprocess.Popen(
            [
                *TRACKCAL,
                "plan",
                "--cell",
                "kr270",
                "--configs",
                "4",
                "--starts",
                "20",
                "--json",
                str(out),
                "--scheduler",
                address,
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
            start_new_session=True,
        )
        try:
            deadline = time.monotonic() + 120
            while not mark.exists() and proc.poll() is None and time.monotonic() < deadline:
                time.sleep(0.05)
            assert mark.exists(), proc.stderr.read() if proc.poll() is not None else "the worker never started"
            os.kill(scheduler.pid, how)
            _, err = proc.communicate(timeout=60)
        finally:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 2 and err.count("\n") == 1, err
    assert f"the Dask scheduler {address} was lost mid-run" in err and not out.exists(), err
