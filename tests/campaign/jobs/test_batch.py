"""trackcal batch: the same results as one campaign at a time, on a process pool and on Dask; a killed batch
resumes without redoing what it finished; a campaign that fails is reported and stops nothing; the summary's robot,
date and worst parameter change; the ISO 9283 figures of many sessions; the Monte-Carlo checks on the same engine."""

import json
import os
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from tests.helpers import TRACKCAL
from trackcal.calib.doe.poses import random_poses
from trackcal.calib.io.table import write_table
from trackcal.campaign.cli.blas import limited_blas
from trackcal.campaign.jobs import batch as batch_job
from trackcal.campaign.jobs.batch import BatchOptions, batch, find_campaigns, result_key, run_chunk
from trackcal.campaign.jobs.diagnose import DiagnoseOptions, run_diagnose
from trackcal.campaign.jobs.identify import IdentifyOptions, identify_table
from trackcal.campaign.jobs.iso9283 import CompareOptions, compare
from trackcal.campaign.jobs.montecarlo import (
    BAND,
    LEVEL,
    CoverageOptions,
    Rho0Options,
    coverage,
    coverage_counts,
    coverage_seed,
    rho0,
)
from trackcal.campaign.jobs.simulate import SimulateOptions, parse_effects, simulate
from trackcal.mocks.twin import Twin, simulate_campaign


@pytest.fixture(scope="module")
def tables(tmp_path_factory):
    d = tmp_path_factory.mktemp("batch")
    for seed in range(1, 6):
        subprocess.run(
            [
                *TRACKCAL,
                "simulate",
                "--cell",
                "kr270",
                "--poses",
                "20",
                "--seed",
                str(seed),
                "--out",
                str(d / f"t{seed}.csv"),
            ],
            check=True,
            capture_output=True,
        )
    return d


def _parameters(path) -> dict:
    return json.loads(path.read_text())["parameters"]


def test_batch_equals_one_by_one(tables, tmp_path):
    out = tmp_path / "res"
    result = batch(BatchOptions(task="identify", inputs=[str(tables)], out=str(out), cell="kr270", chunk=2))
    assert (result.computed, result.reused, result.failed) == (5, 0, [])
    for row in result.rows:
        alone = identify_table(IdentifyOptions(data=row["campaign"], cell="kr270", out=str(tmp_path / "alone.json")))
        assert _parameters(out / f"{row['key']}.model.json") == alone.doc["parameters"]  # bit for bit
        assert row["residual_rms_mm"] == alone.doc["residual_rms_mm"]


@pytest.fixture(scope="module")
def cluster():
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cl:
        yield cl.scheduler_address


def test_dask_gives_the_pool_results(tables, tmp_path, cluster):
    """`--scheduler` of a LocalCluster of 2 worker processes: the same models as the process pool, bit for bit."""
    done = subprocess.run(
        [
            *TRACKCAL,
            "batch",
            "identify",
            str(tables),
            "--cell",
            "kr270",
            "--out",
            str(tmp_path / "dask"),
            "--scheduler",
            cluster,
        ],
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stderr
    pool = batch(BatchOptions(task="identify", inputs=[str(tables)], out=str(tmp_path / "pool"), cell="kr270"))
    assert sorted(p.name for p in (tmp_path / "dask").glob("*.model.json")) == sorted(
        f"{r['key']}.model.json" for r in pool.rows
    )
    for r in pool.rows:
        assert _parameters(tmp_path / "dask" / f"{r['key']}.model.json") == _parameters(
            tmp_path / "pool" / f"{r['key']}.model.json"
        )


@pytest.fixture(scope="module")
def caused(tmp_path_factory):
    """Three KR-270 twin campaigns of 30 poses: no hidden effect, backlash, encoder scale, 0.05 mm each (the causes
    and size of bench.bench_batch, whose diagnoses find them)."""
    d = tmp_path_factory.mktemp("caused")
    for i, effect in enumerate(["", "backlash:0.05", "encoder_scale:0.05"]):
        effects = parse_effects([effect] if effect else None)
        simulate(SimulateOptions(cell="kr270", out=str(d / f"c{i}.csv"), poses=30, seed=1000 + i, effects=effects))
    return d


def test_dask_gives_the_pool_verdicts(caused, tmp_path, cluster):
    """batch diagnose on a LocalCluster of 2 worker processes, one campaign per task: the same verdict.json as the
    process pool's for each campaign, bit for bit, and the verdicts differ between the campaigns (a mix-up shows).
    On one BLAS thread, as `trackcal batch` runs (a Dask nanny starts its workers so: distributed's
    nanny.pre-spawn-environ); with numpy's default of two, the pool's structure p-values differed in their last
    bits."""

    def run(where: str):
        scheduler = cluster if where == "dask" else None
        opts = BatchOptions("diagnose", [str(caused)], str(tmp_path / where), "kr270", scheduler=scheduler, chunk=1)
        return batch(opts)

    with limited_blas():
        runs = {where: run(where) for where in ("pool", "dask")}
    assert [(r.computed, r.failed) for r in runs.values()] == [(3, []), (3, [])]
    verdicts = {
        where: [json.loads((tmp_path / where / f"{r['key']}.verdict.json").read_text()) for r in result.rows]
        for where, result in runs.items()
    }
    assert verdicts["dask"] == verdicts["pool"]
    assert len({v["cause"] for v in verdicts["pool"]}) > 1


def test_a_failed_campaign_is_reported_and_the_others_done(tables, tmp_path):
    (tmp_path / "in").mkdir()
    for name in ("t1.csv", "t2.csv"):
        (tmp_path / "in" / name).write_bytes((tables / name).read_bytes())
    (tmp_path / "in" / "broken.csv").write_text("seq,t_s,pose\n1,0,a\n")
    done = subprocess.run(
        [*TRACKCAL, "batch", "identify", str(tmp_path / "in"), "--cell", "kr270", "--out", str(tmp_path / "res")],
        capture_output=True,
        text=True,
    )
    assert done.returncode == 2
    failed = [line for line in done.stdout.splitlines() if line.startswith("failed: ")]
    assert len(failed) == 1 and "broken.csv" in failed[0]
    assert len(list((tmp_path / "res").glob("*.model.json"))) == 2


def test_a_killed_batch_resumes_without_redoing(tables, tmp_path):
    """kill -9 of a batch once its first result is written; run again: what was written is reused, the rest is
    computed, every campaign has its result."""
    out = tmp_path / "res"
    proc = subprocess.Popen(
        [*TRACKCAL, "batch", "diagnose", str(tables), "--cell", "kr270", "--out", str(out)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    deadline = time.monotonic() + 300
    while not list(out.glob("*[0-9a-f].json")) and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    kept = {p.name: p.read_bytes() for p in out.glob("*[0-9a-f].json")}
    assert kept, "the batch was killed before its first result"
    again = batch(BatchOptions(task="diagnose", inputs=[str(tables)], out=str(out), cell="kr270"))
    assert again.reused == len(kept) and again.computed == 5 - len(kept) and not again.failed
    assert all((out / name).read_bytes() == data for name, data in kept.items())  # not redone
    assert len(list(out.glob("*.verdict.json"))) == 5 and all("cause" in r for r in again.rows)


def test_diagnose_batch_equals_one_by_one(tables, tmp_path):
    """The verdict of each campaign of a batch diagnose is the one `trackcal diagnose` gives it alone: cause and
    held-out figures, bit for bit."""
    inputs = [str(tables / "t3.csv")]
    result = batch(BatchOptions(task="diagnose", inputs=inputs, out=str(tmp_path / "res"), cell="kr270"))
    assert not result.failed
    for row in result.rows:
        alone = run_diagnose(DiagnoseOptions(data=row["campaign"], cell="kr270", json=str(tmp_path / "v.json"))).verdict
        assert row["cause"] == alone["cause"]
        assert row["holdout_geometric_mm"] == alone["holdout"]["rms_geometric_mm"]
        assert row["holdout_extended_mm"] == alone["holdout"]["rms_extended_mm"]


def test_a_campaign_that_raises_anything_is_its_one_line(tables, tmp_path, monkeypatch):
    """Not only trackcal's own errors: an unexpected exception of one campaign (here a ValueError with a two-line
    message) is that campaign's one line, with its type, and the next campaign of the chunk is still done."""
    opts = BatchOptions(task="identify", inputs=[str(tables)], out=str(tmp_path), cell="kr270")
    real = batch_job.identify_table

    def flaky(o):
        if o.data.endswith("t1.csv"):
            raise ValueError("a bug\nin two lines")
        return real(o)

    monkeypatch.setattr(batch_job, "identify_table", flaky)
    campaigns = find_campaigns([str(tables / "t1.csv"), str(tables / "t2.csv")], "kr270")
    bad, good = run_chunk([(c, result_key(c, opts)) for c in campaigns], opts)
    assert bad["error"] == "ValueError: a bug in two lines"
    assert "fit" in good and (tmp_path / f"{good['key']}.json").exists()
    assert not (tmp_path / f"{bad['key']}.json").exists()  # a failure is not kept: run again, it is tried again


def _campaign(cell, path, noise_seed: int, dq2_shift_deg: float = 0.0, mtime: float = 0.0) -> None:
    """A 30-pose table of one twin robot (seed 11) with its own poses and noise; dq2 knocked by `dq2_shift_deg`."""
    twin = Twin(cell, seed=11)
    twin.seed = noise_seed  # the robot stays, the noise stream changes (tests/test_history.py)
    twin.true_dev[[p.name for p in twin.params].index("dq2")] += np.radians(dq2_shift_deg)
    table = simulate_campaign(twin, np.degrees(random_poses(cell, 30, np.random.default_rng(noise_seed))))
    write_table(table, str(path))
    os.utime(path, (mtime, mtime))


def test_summary_names_robot_date_and_worst_change(kr270, tmp_path):
    """A fleet folder of robot folders: robot A's dq2 knocked by 0.003 deg between its two campaigns (about 20
    standard deviations of a 30-pose estimate, tests/test_history.py) is the worst change of its second campaign,
    against the previous one, and the robot changed; robot B, unchanged, did not change (5 % false alarms, so a
    fixed seed is a fixed outcome); each robot's first campaign is compared against nominal; dates are the tables'
    file times and order the campaigns, whatever their names."""
    fleet = tmp_path / "fleet"
    (fleet / "A").mkdir(parents=True)
    (fleet / "B").mkdir()
    day = 86400.0
    _campaign(kr270, fleet / "A" / "z-first.csv", 1, mtime=1.79e9)
    _campaign(kr270, fleet / "A" / "a-second.csv", 2, dq2_shift_deg=0.003, mtime=1.79e9 + 120 * day)
    _campaign(kr270, fleet / "B" / "one.csv", 3, mtime=1.79e9)
    _campaign(kr270, fleet / "B" / "two.csv", 4, mtime=1.79e9 + 90 * day)
    result = batch(BatchOptions(task="identify", inputs=[str(fleet)], out=str(tmp_path / "res"), cell="kr270"))
    rows = {Path(r["campaign"]).name: r for r in result.rows}
    assert {r["robot"] for r in result.rows} == {"A", "B"}
    assert rows["a-second.csv"]["date"] > rows["z-first.csv"]["date"]
    assert all(r["date_source"] == "file modified" for r in result.rows)
    for first in ("z-first.csv", "one.csv"):
        assert rows[first]["worst_change"]["against"] == "nominal"
    knocked = rows["a-second.csv"]["worst_change"]
    assert knocked["against"] == f"previous ({fleet / 'A' / 'z-first.csv'})"
    assert knocked["parameter"] == "dq2" and knocked["robot_changed"]
    assert knocked["change"] == pytest.approx(0.003, abs=4 * knocked["sigma"])
    steady = rows["two.csv"]["worst_change"]
    assert steady["against"].startswith("previous") and not steady["robot_changed"]


@pytest.fixture(scope="module")
def iso_sessions(tmp_path_factory):
    d = tmp_path_factory.mktemp("iso")

    def run(*argv):
        done = subprocess.run([*TRACKCAL, *argv], cwd=d, capture_output=True, text=True)
        assert done.returncode == 0, done.stderr

    run("simulate", "--cell", "kr270", "--poses", "20", "--seed", "1", "--out", "t.csv")
    run("identify", "t.csv", "--cell", "kr270", "--out", "model.json")
    run(
        "iso9283",
        "plan",
        "--cell",
        "kr270",
        "--cycles",
        "2",
        "--vap-cycles",
        "0",
        "--load",
        "unloaded",
        "--velocities",
        "100",
        "--json",
        "iso.json",
    )
    run(
        "run", "--sim", "--cell", "kr270", "--plan", "iso.json", "--seed", "1", "--session", "tests/s1", "--no-analysis"
    )
    return d


def test_batch_iso9283_equals_compare(iso_sessions, tmp_path):
    """The figures of an ISO session in a batch are those of `iso9283 compare`; run again, nothing is redone; a table
    is no ISO test (one line)."""
    d = iso_sessions
    opts = BatchOptions(task="iso9283", inputs=[str(d / "tests")], out=str(tmp_path), model=str(d / "model.json"))
    result = batch(opts)
    assert (result.computed, result.reused, result.failed) == (1, 0, [])
    tests, _ = compare(CompareOptions(sessions=[str(d / "tests" / "s1")], model=str(d / "model.json")))
    for row, t in zip(result.rows, tests, strict=True):
        assert row["ap_max_mm"] == max(p.ap.value for p in t.poses)
        assert row["rp_max_mm"] == max(p.rp.value for p in t.poses)
        assert row["targets"] == "nominal" and row["cycles"] == 2
    assert batch(opts).reused == 1
    table = subprocess.run(
        [*TRACKCAL, "batch", "iso9283", str(d / "t.csv"), "--model", str(d / "model.json"), "--out", str(tmp_path)],
        capture_output=True,
        text=True,
    )
    assert table.returncode == 2 and table.stderr.count("\n") == 1 and "session folder" in table.stderr


def test_coverage_counts_by_hand():
    """Three seeds, two parameters: the counts, and the band of Binomial(3, 0.95) at 99.9 %: [1, 3]
    (P(X = 0) = 0.05^3 = 1.25e-4 < 0.0005)."""
    rows = [
        {"names": ["a", "b"], "inside": [True, True], "joint": True},
        {"names": ["a", "b"], "inside": [True, False], "joint": True},
        {"names": ["a", "b"], "inside": [True, False], "joint": False},
    ]
    c = coverage_counts(rows)
    assert (c.inside, c.joint, c.n, c.band) == ([3, 1], 2, 3, (1, 3))
    assert c.honest
    c = coverage_counts([{**r, "inside": [False, False]} for r in rows])
    assert not c.honest and "a, b fell outside" in c.sentence


def test_coverage_on_the_batch_engine(kr270, tmp_path):
    """A few seeds through the process pool: each seed is what it is alone (any chunking), and the counts are in the
    binomial band of honest intervals (the many-seed check is the slow test below and tests/test_uncertainty.py)."""
    opts = CoverageOptions(cell="kr270", seeds=6, first_seed=100, poses=30, chunk=4, json=str(tmp_path / "c.json"))
    c = coverage(opts)
    alone = [coverage_seed(opts, s) for s in range(100, 106)]
    assert c.inside == np.sum([r["inside"] for r in alone], axis=0).tolist()
    assert c.joint == sum(r["joint"] for r in alone)
    lo, hi = stats.binom.interval(BAND, 6, LEVEL)
    assert all(lo <= k <= hi for k in [*c.inside, c.joint]), c.sentence
    assert json.loads((tmp_path / "c.json").read_text())["honest"] == c.honest


@pytest.mark.slow
def test_coverage_over_many_seeds_is_95_percent():
    """400 seeds: every parameter's count and the joint region's within the 99.9 % band of Binomial(400, 0.95),
    [364, 393] (a count outside it has probability < 0.1 % per count with honest intervals)."""
    c = coverage(CoverageOptions(cell="kr270", seeds=400, first_seed=7000))
    assert c.band == (364, 393)
    assert c.honest, c.sentence


@pytest.mark.slow  # a statistical acceptance check, among make test's slowest (issue 37): make test-slow
def test_monte_carlo_rho0_on_pool_and_dask(tmp_path, cluster):
    """plan's criterion by simulation through the batch engine: the same runs on the process pool and on Dask (each
    run has its own generator), and the mean squared TCP error agrees with rho0^2 within 4 standard errors
    (tests/test_doe.py's check of calib.doe.design.monte_carlo_rho0)."""
    plan = tmp_path / "plan.json"
    subprocess.run(
        [
            *TRACKCAL,
            "plan",
            "--cell",
            "kr270",
            "--configs",
            "6",
            "--repeat",
            "3",
            "--starts",
            "10",
            "--refined",
            "1",
            "--json",
            str(plan),
        ],
        check=True,
        capture_output=True,
    )
    pool = rho0(Rho0Options(plan=str(plan), cell="kr270", runs=120, seed=3, chunk=50))
    dask = rho0(Rho0Options(plan=str(plan), cell="kr270", runs=120, seed=3, chunk=70, scheduler=cluster))
    assert pool.monte_carlo_mm == dask.monte_carlo_mm
    assert pool.rho0_mm == pytest.approx(json.loads(plan.read_text())["rho0_mm"], rel=1e-3)  # poses rounded to 1e-4 deg
    assert abs(pool.z) < 4 and pool.agrees
    done = subprocess.run(
        [*TRACKCAL, "batch", "rho0", str(tmp_path / "nope.json"), "--cell", "kr270"], capture_output=True, text=True
    )
    assert done.returncode == 2 and done.stderr.count("\n") == 1
