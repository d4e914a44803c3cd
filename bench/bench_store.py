"""Cost of storing one campaign event, and of checking a session, on the disk of the temporary directory.

Ours: `SessionStore.append` as a campaign uses it: rollback journal (journal_mode=DELETE), synchronous=FULL,
sha256 chained to the previous event, so that every committed event is in session.sqlite itself. Baselines,
measured in the same run on the same disk: the store before (WAL, synchronous=FULL, no chain: the event sat
in the -wal file until a checkpoint) and WAL with a checkpoint after every commit (the other way to get every
event into the main file). A real campaign stores about one event per second (a measurement every 20-30 s,
with its ~20 device calls and step events), so the budget is 1000 ms per event. Also printed: `verify`
(integrity check + hash chain) per stored event, what resume, export and check pay at their start.
"""

from __future__ import annotations

import json
import sqlite3
import statistics
import tempfile
import time
from pathlib import Path

from trackcal.campaign.session.store import SessionStore

N = 300
EVENT = {
    "device": "tracker",
    "op": "measure",
    "args": [],
    "result": {
        "__type__": "TrackerMeasurement",
        "x_mm": 3136.7512,
        "y_mm": -1184.0931,
        "z_mm": 1620.4407,
        "std_x_mm": 0.0142,
        "std_y_mm": 0.0139,
        "std_z_mm": 0.0151,
    },
}


def _ours(directory: Path) -> list[float]:
    store = SessionStore.create(directory, {"mode": "bench"}, {"plan.json": "{}"})
    times = []
    for i in range(N):
        t0 = time.perf_counter()
        store.append("call", EVENT, step=i, t_campaign=float(i))
        times.append(time.perf_counter() - t0)
    store.close()
    return times


def _wal(directory: Path, checkpoint: bool) -> list[float]:
    conn = sqlite3.connect(str(directory / "wal.sqlite"), isolation_level=None)
    conn.execute("PRAGMA journal_mode=WAL")
    conn.execute("PRAGMA synchronous=FULL")
    conn.execute(
        "CREATE TABLE events(id INTEGER PRIMARY KEY AUTOINCREMENT, t_wall REAL, t_campaign REAL, "
        "step INTEGER, kind TEXT, data TEXT)"
    )
    times = []
    for i in range(N):
        t0 = time.perf_counter()
        conn.execute(
            "INSERT INTO events(t_wall, t_campaign, step, kind, data) VALUES (?, ?, ?, ?, ?)",
            (time.time(), float(i), i, "call", json.dumps(EVENT, sort_keys=True)),
        )
        if checkpoint:
            conn.execute("PRAGMA wal_checkpoint(PASSIVE)")
        times.append(time.perf_counter() - t0)
    conn.close()
    return times


def _ms(times: list[float]) -> str:
    q = statistics.quantiles(times, n=20)
    return f"median {statistics.median(times) * 1e3:6.2f} ms, p95 {q[18] * 1e3:6.2f} ms"


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        print(f"disk of {root}; {N} events each")
        ours = _ours(root / "ours")
        wal = _wal(root, checkpoint=False)
        (root / "wal.sqlite").unlink()
        walck = _wal(root, checkpoint=True)
        m = statistics.median(ours)
        print(f"  ours (journal DELETE, FULL, chained): {_ms(ours)}  = {m * 100:.2f} % of a 1 s event budget")
        print(f"  before (WAL, FULL, no checkpoint):    {_ms(wal)}  ours / before = {m / statistics.median(wal):.1f}x")
        print(
            f"  WAL + checkpoint per commit:          {_ms(walck)}  ours / this = {m / statistics.median(walck):.1f}x"
        )
        t0 = time.perf_counter()
        SessionStore.open(root / "ours", readonly=True).verify()
        print(f"  verify (integrity check + chain):     {(time.perf_counter() - t0) / N * 1e6:6.1f} us per event")


if __name__ == "__main__":
    main()
