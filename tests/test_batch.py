"""trackcal batch: the same results as one campaign at a time, on a process pool and on Dask; a killed batch
resumes without redoing what it finished; a campaign that fails is reported and stops nothing."""

import json
import os
import signal
import subprocess
import time

import pytest

from tests.helpers import TRACKCAL
from trackcal.campaign.jobs.batch import BatchOptions, batch
from trackcal.campaign.jobs.identify import IdentifyOptions, identify_table


@pytest.fixture(scope="module")
def tables(tmp_path_factory):
    d = tmp_path_factory.mktemp("batch")
    for seed in range(1, 6):
        subprocess.run([*TRACKCAL, "simulate", "--cell", "kr270", "--poses", "20", "--seed", str(seed), "--out",
                        str(d / f"t{seed}.csv")], check=True, capture_output=True)  # fmt: skip
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


def test_dask_gives_the_pool_results(tables, tmp_path):
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cl:
        dask = batch(BatchOptions(task="identify", inputs=[str(tables)], out=str(tmp_path / "dask"), cell="kr270",
                                  scheduler=cl.scheduler_address))  # fmt: skip
    pool = batch(BatchOptions(task="identify", inputs=[str(tables)], out=str(tmp_path / "pool"), cell="kr270"))
    assert [r["key"] for r in dask.rows] == [r["key"] for r in pool.rows]
    for a, b in zip(dask.rows, pool.rows, strict=True):
        assert _parameters(tmp_path / "dask" / f"{a['key']}.model.json") == _parameters(
            tmp_path / "pool" / f"{b['key']}.model.json")


def test_a_failed_campaign_is_reported_and_the_others_done(tables, tmp_path):
    (tmp_path / "in").mkdir()
    for name in ("t1.csv", "t2.csv"):
        (tmp_path / "in" / name).write_bytes((tables / name).read_bytes())
    (tmp_path / "in" / "broken.csv").write_text("seq,t_s,pose\n1,0,a\n")
    done = subprocess.run([*TRACKCAL, "batch", "identify", str(tmp_path / "in"), "--cell", "kr270", "--out",
                           str(tmp_path / "res")], capture_output=True, text=True)  # fmt: skip
    assert done.returncode == 2
    failed = [line for line in done.stdout.splitlines() if line.startswith("failed: ")]
    assert len(failed) == 1 and "broken.csv" in failed[0]
    assert len(list((tmp_path / "res").glob("*.model.json"))) == 2


def test_a_killed_batch_resumes_without_redoing(tables, tmp_path):
    """kill -9 of a batch once its first result is written; run again: what was written is reused, the rest is
    computed, every campaign has its result."""
    out = tmp_path / "res"
    proc = subprocess.Popen([*TRACKCAL, "batch", "diagnose", str(tables), "--cell", "kr270", "--out", str(out)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)  # fmt: skip
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
