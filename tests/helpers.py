"""What several test modules share: the command line, campaigns on the twin, plans, in-process cells, fault
injection. Fixtures live in conftest.py; no test module imports another."""

import contextlib
import re
import signal
import socket
import sqlite3
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from trackcal.calib.diagnose.fits import Fit, fit_cause
from trackcal.calib.diagnose.joint_map import harmonic_names, map_extension
from trackcal.calib.diagnose.joint_map_fit import HeldOutMap
from trackcal.calib.doe.design import design_for_cell, random_feasible_poses
from trackcal.calib.doe.poses import random_poses
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.identify.solver import Identification, Problem, State, identify
from trackcal.calib.identify.unknowns import campaign_params
from trackcal.calib.io.table import MeasurementTable, read_table
from trackcal.calib.model.cell import Cell
from trackcal.calib.model.kinematics import Kinematics
from trackcal.calib.model.params import Param, irreducible_params
from trackcal.campaign.engine.engine import Live
from trackcal.campaign.jobs.simulate import SimulateOptions, simulate
from trackcal.campaign.session.session import measured_keys
from trackcal.mocks.cell import World
from trackcal.mocks.inproc import InprocCellIO, InprocRobot, InprocTracker, SimOperator
from trackcal.mocks.twin import Twin, simulate_campaign

ROOT = Path(__file__).resolve().parents[1]
TRACKCAL = [sys.executable, "-m", "trackcal.campaign.cli"]  # the command line, in a process of its own


# The README's tables, for checks that a new computation gives the old one's numbers on them (issue 41):
# (cell, poses, seed, effects, the cause the fit extends the model by)
README_TABLES = [
    ("kr270", 30, 1, {}, "none"),  # the README's first table
    ("kr270", 40, 1, {"backlash": 0.04}, "backlash"),  # the README's backlash table, extended by its cause
    ("ur10", 30, 2, {}, "none"),
]
README_TABLE_ARGS = ("cell_name", "poses", "seed", "effects", "cause")


def readme_table_fit(cell_name: str, poses: int, seed: int, effects: dict, cause: str) -> Fit:
    """One of README_TABLES simulated and fitted (the campaign's parameters, the cause's extension)."""
    cell, _, table = simulate(SimulateOptions(cell_name, poses=poses, seed=seed, effects=effects))
    return fit_cause(cell.chain, table, cell.tool_points, campaign_params(cell.chain), TrackerNoise(), cause)


def drawn_kr270_campaign(seed: int, poses: int, drop: list[int]):
    """(cell, table, parameters) of a drawn KR-270 campaign: `simulate`'s table, the campaign's parameters but those
    at the indices `drop`."""
    cell, _, table = simulate(SimulateOptions("kr270", poses=poses, seed=seed))
    return cell, table, [p for i, p in enumerate(campaign_params(cell.chain)) if i not in drop]


def backlash_twin_case(cell: Cell) -> tuple[MeasurementTable, list[Param], Identification]:
    """(table, irreducible parameters, geometric fit) of a 40-pose twin campaign of `cell` with a hidden backlash of
    0.05 deg (the size of bench.bench_diagnose's case): the diagnose CPU and speed tests' case."""
    twin = Twin(cell, seed=5, effects={"backlash": 0.05})
    table = simulate_campaign(twin, np.degrees(random_poses(cell, 40, np.random.default_rng(5))))
    params = irreducible_params(cell.chain)[0]
    return table, params, identify(cell.chain, table, cell.tool_points, params, noise=TrackerNoise())


class DenseRows:
    """A drawn problem's residual and Jacobian rows of given rows (as `ProblemRows` forms them from a Problem), and
    its map's columns of held-out rows as they are in the Jacobian (as `HeldOutMap` gives them, unclamped)."""

    def __init__(self, jm, r, pen):
        self.jm, self.r, self.pen = jm.reshape(len(r) // 3, 3, -1), r.reshape(-1, 3), pen

    def __call__(self, rows):
        return self.r[rows].ravel(), self.jm[rows].reshape(3 * len(rows), -1)

    def normal(self, rows, keep):
        r, j = self(rows)
        return j.T @ j, j.T @ r, r, j[:, keep]

    def piece(self, rows, at=slice(None)):
        return self(rows[at])[1][:, self.pen]

    def times(self, piece, c, idx):
        return piece[:, idx] @ c


def held_columns(held: HeldOutMap, test: np.ndarray, at: slice = slice(None)) -> np.ndarray:
    """(3 n, e) the held-out map's columns of the rows test[at]: its product with the identity, which is exact (each
    sum has one non-zero term, times 1)."""
    return held.times(held.piece(test, at), np.eye(len(held.names)), np.arange(len(held.names)))


def held_out_map(cell: Cell, table: MeasurementTable, geo: Identification, params, arcs: dict, order: int):
    """(HeldOutMap, coefficient names) of the joint error map up to `order` on `arcs` (its features clamped to them),
    linearised at the fit `geo` with the map at zero, the tracker's weighting."""
    names = [nm for j in arcs for nm in harmonic_names(j, order)]
    ext = map_extension(np.radians(table.q_deg), names=names, arcs=arcs)
    problem = Problem(cell.chain, table, geo.points, params, TrackerNoise(), extension=ext)
    state = State(
        geo.dev,
        [geo.stations[s] for s in problem.station_ids],
        np.array([geo.points[p] for p in problem.point_ids]),
        np.zeros(len(names)),
    )
    return HeldOutMap(problem, state, names), names


def run_trackcal(*args, timeout=300, check=True) -> subprocess.CompletedProcess:
    """`trackcal ARGS` in a process of its own (text output captured); with check, asserts it exited 0."""
    out = subprocess.run([*TRACKCAL, *args], capture_output=True, text=True, timeout=timeout, cwd=ROOT)
    if check:
        assert out.returncode == 0, out.stderr
    return out


def exported_table(session, out):
    """The session's table, through `trackcal export SESSION --csv OUT`."""
    run_trackcal("export", str(session), "--csv", str(out))
    return read_table(out)


def kr270_campaign(cell, seed: int, n_poses: int = 30, noise_free: bool = False, **twin_kw):
    """A paper-like campaign: random feasible poses, 3 points, 2 stations, AT901-like noise (twin defaults)."""
    twin = Twin(cell, seed=seed, **twin_kw)
    poses = np.degrees(random_poses(cell, n_poses, np.random.default_rng(seed)))
    return twin, simulate_campaign(twin, poses, noise_free=noise_free)


def truth_of(twin, params):
    return np.array([twin.true_dev[twin.params.index(p)] for p in params])


def feasible_plan(cell, n_poses: int, seed: int, repeat: int) -> dict:
    """A campaign plan (plan.json form) of n random poses satisfying limits, box and visibility."""

    poses = np.degrees(random_feasible_poses(design_for_cell(cell, []), n_poses, np.random.default_rng(seed)))
    return {"poses_deg": poses.round(4).tolist(), "repeat": repeat}


def placed_residuals(cell, table, rows) -> np.ndarray:
    """Measured minus the nominal model placed on the `rows` of a measurement table (one station's block): an
    independent check of campaign/engine/station_fit.py (scipy's Wahba solution on centred points, not Kabsch)."""
    q = np.radians(table.q_deg[rows])
    tool = np.array([cell.tool_points[table.point[i]] for i in rows])
    nominal = Kinematics(cell.chain, []).points(q, tool)
    xyz = table.xyz[rows]
    rot, _ = Rotation.align_vectors(xyz - xyz.mean(axis=0), nominal - nominal.mean(axis=0))
    r = rot.as_matrix()
    return xyz - (nominal @ r.T + xyz.mean(axis=0) - r @ nominal.mean(axis=0))


def inproc_live(cell, seed: int = 3, store=None, operator=None, effects=None):
    """(world, Live) of the twin's cell on the in-process doubles; with `store`, the world knows the
    measurements the session holds (a resume sees the noise an uninterrupted run would); `effects` the twin's."""

    world = World(Twin(cell, seed=seed, effects=effects or {}))
    if store is not None:
        world.restore_counts(measured_keys(store))
    return world, Live(
        InprocTracker(world), InprocRobot(world), operator or SimOperator(world), world.clock, InprocCellIO(world)
    )


def assert_stopped(result, pattern: str) -> None:
    """The run stopped safely (what a resume continues) with a message `pattern` finds (re.search, as
    pytest.raises(match=) did on the stop when it was an exception): "stopped safely at step N: why"."""
    assert result.exit_status == "stopped", result
    assert re.search(pattern, result.message), result.message


def before_call(obj, name: str, n: int, action) -> None:
    """Make obj.name run `action()` just before its n-th call (fault injection at a chosen moment)."""
    original, calls = getattr(obj, name), []

    def wrapped(*args, **kw):
        calls.append(1)
        if len(calls) == n:
            action()
        return original(*args, **kw)

    setattr(obj, name, wrapped)


def wait_for(path: Path, proc: subprocess.Popen, timeout_s: float = 30.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not path.exists():
        assert proc.poll() is None, f"trackcal mock exited early: {proc.communicate()}"
        assert time.monotonic() < deadline, f"{path} not written within {timeout_s} s"
        time.sleep(0.05)


def stop(proc: subprocess.Popen, timeout_s: float = 20.0) -> None:
    """Ctrl-C a process that still runs (a mock, a campaign), killed if it has not ended within timeout_s."""
    if proc.poll() is not None:
        return
    proc.send_signal(signal.SIGINT)
    try:
        proc.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


# The robot stream's freshness limit (wall seconds) in the hardware file `trackcal mock` writes for these tests. The
# mock writes the drivers' default, 1 s, which a real cell keeps easily; a shared 2-core machine under a load of 13
# to 24 starved a process of the test that long (issue 37: the KR C4 test stopped safely with "the RSI stream went
# stale: no frame for 1.0 s"), which the campaign must do, but for the machine's load, not for anything these tests
# check. The stale checks themselves run on the virtual clock (tests/campaign/engine/test_stop_causes.py) and in the
# drivers' tests.
UNHURRIED_STALE_S = 60.0
STALE_KEY = {"krc2": "rsi_stale_s", "krc4": "rsi_stale_s", "ur": "stale_s", "abb": "egm_stale_s"}  # drivers/*/family.py
# The same for the answer deadlines of the cell PLC (Modbus) and the meteo sensor (serial): the mock writes 2 s, and
# under that load the ABB test stopped safely with "meteo /dev/pts/0: no answer to request M5 within 2.0 s" (issue 41's
# CI run). Their timeouts are tested in the drivers' own tests.
UNHURRIED_ANSWER_S = 30.0


def free_udp_port(host: str = "127.0.0.1") -> int:
    """A port free on host for UDP and for TCP both. A robot's RSI/EGM port is UDP, and the KR C4 client also claims
    the robot by listening on TCP at the same number (drivers/krc4/client.py): a UDP port the kernel picks lies in the
    same ephemeral range as other tests' TCP connections, and once was one (make test: "cannot listen for the claim of
    this robot ... Address already in use"). The kernel picks a TCP port no TCP socket holds; UDP is then tried on
    it."""
    while True:
        with (
            socket.socket(socket.AF_INET, socket.SOCK_STREAM) as tcp,
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as udp,
        ):
            tcp.bind((host, 0))
            port = tcp.getsockname()[1]
            try:
                udp.bind((host, port))
            except OSError:
                continue
            return port


@contextlib.contextmanager
def mock_process(
    cell: str, seed: int, hw: Path, timeout_s: float = 30.0, stdout=subprocess.PIPE, sim_speed: float | None = None
) -> Iterator[subprocess.Popen]:
    """`trackcal mock --cell CELL [--sim-speed X]` in its own process, yielded once it has written its hardware file
    `hw` (its robot stream's stale limit then set to UNHURRIED_STALE_S, the PLC's and the meteo's answer deadlines to
    UNHURRIED_ANSWER_S); stopped (`stop`) at the end if still running. Without sim_speed the mock runs in real time
    (its default)."""
    speed = [] if sim_speed is None else ["--sim-speed", repr(sim_speed)]
    proc = subprocess.Popen(
        [*TRACKCAL, "mock", "--cell", cell, "--seed", str(seed), "--write-hardware", str(hw), *speed],
        stdout=stdout,
        stderr=subprocess.PIPE,
        text=True,
        cwd=ROOT,
    )
    try:
        wait_for(hw, proc, timeout_s)
        text = hw.read_text()
        doc = yaml.safe_load(text)
        doc["robot"][STALE_KEY[doc["robot"]["protocol"]]] = UNHURRIED_STALE_S
        for device in ("plc", "meteo"):
            if device in doc:
                doc[device]["timeout_s"] = UNHURRIED_ANSWER_S
        header = "".join(line for line in text.splitlines(keepends=True) if line.startswith("#"))  # the mock's pid
        hw.write_text(header + yaml.safe_dump(doc, sort_keys=False))
        yield proc
    finally:
        stop(proc)


def count_measurements(db: Path) -> int:
    """Measurements stored in a session database so far (0 before it exists)."""
    try:  # mode=rw: never creates the file, and rolls back a write the kill cut short (read-only cannot)
        with sqlite3.connect(f"file:{db}?mode=rw", uri=True, timeout=5) as conn:
            return conn.execute("SELECT count(*) FROM events WHERE kind='measurement'").fetchone()[0]
    except sqlite3.Error:
        return 0
