"""The hardware mode: the hardware config (campaign/cells/hardware.py, configs/hardware/README.md), `trackcal mock`
and `trackcal run --hardware` against it in separate processes, as on the shop floor with the real cell."""

import json
import os
import re
import signal
import socket
import sqlite3
import subprocess
import time
from pathlib import Path

import pytest
import yaml

from tests.helpers import ROOT, TRACKCAL, count_measurements
from trackcal.calib.io.table import read_table
from trackcal.campaign.cells.hardware import load_hardware
from trackcal.campaign.engine.steps import plan_steps
from trackcal.campaign.errors import InputError

EXAMPLE = ROOT / "configs" / "hardware" / "example-cell.yaml"

GOOD = {
    "tracker": {"protocol": "emscon", "host": "192.168.0.10", "port": 700, "timeout_s": 10},
    "robot": {
        "protocol": "krc2",
        "controller_host": "192.168.0.5",
        "eki": {"host": "192.168.0.2", "port": 54600},
        "rsi": {"protocol": "tcp", "host": "192.168.0.2", "port": 49152},
    },
    "plc": {"protocol": "modbus", "host": "192.168.0.20", "port": 502, "unit_id": 1, "timeout_s": 1},
    "meteo": {"protocol": "serial", "port": "/dev/ttyUSB0", "baudrate": 9600},
}


def variant(path: str, value):
    """GOOD with the key at `path` (dotted) set to value (or removed when value is DELETE)."""
    doc = json.loads(json.dumps(GOOD))
    *parents, last = path.split(".")
    node = doc
    for p in parents:
        node = node[p]
    if value is DELETE:
        del node[last]
    else:
        node[last] = value
    return doc


DELETE = object()

BAD = [  # (document or raw YAML text, what the message must say after "FILE: ")
    (variant("tracker", DELETE), r"tracker: missing \(the tracker section is required\)"),
    (variant("robot", DELETE), r"robot: missing"),
    ({**GOOD, "trackr": {}}, r"trackr: unknown key \(did you mean tracker\?\)"),
    ({**GOOD, "camera": {}}, r"camera: unknown key \(known keys: tracker, robot, plc, meteo\)"),
    (variant("tracker.timeout", 5), r"tracker\.timeout: unknown key \(did you mean timeout_s\?\)"),
    (variant("plc.unit", 1), r"plc\.unit: unknown key \(did you mean unit_id\?\)"),
    (variant("tracker.port", "700"), r"tracker\.port: expected an integer in 1\.\.65535, got '700'"),
    # trust: the controller's address and this PC's listening address are named, never defaulted
    (variant("robot.controller_host", DELETE), r"robot\.controller_host: missing \(required\)"),
    (variant("robot.eki.host", DELETE), r"robot\.eki\.host: missing \(required\)"),
    (variant("robot.rsi.host", DELETE), r"robot\.rsi\.host: missing \(required\)"),
    (variant("tracker.port", True), r"tracker\.port: expected an integer"),
    (variant("tracker.port", 70000), r"tracker\.port: 70000 out of range 1\.\.65535"),
    (variant("robot.eki.port", 0), r"robot\.eki\.port: 0 out of range 1\.\.65535"),
    (variant("plc.port", -502), r"plc\.port: -502 out of range"),
    (variant("plc.unit_id", 300), r"plc\.unit_id: 300 out of range 0\.\.255"),
    (variant("robot.rsi.port", DELETE), r"robot\.rsi\.port: missing \(required\)"),
    (variant("robot.eki", DELETE), r"robot\.eki: missing \(required\)"),
    (variant("robot.eki", 54600), r"robot\.eki: expected a mapping of host, port"),
    (variant("robot.rsi.protocl", "tcp"), r"robot\.rsi\.protocl: unknown key \(did you mean protocol\?\)"),
    (variant("tracker.protocol", "leica"), r"tracker\.protocol: unknown protocol 'leica' \(supported: emscon\)"),
    (variant("tracker.protocol", DELETE), r"tracker\.protocol: missing"),
    (
        variant("robot.protocol", "fanuc"),
        r"robot\.protocol: unknown protocol 'fanuc' \(supported: abb, krc2, krc4, ur\)",
    ),
    (variant("robot.rsi.protocol", "serial"), r"robot\.rsi\.protocol: unknown protocol 'serial' \(supported: tcp, udp"),
    (variant("robot.rsi.passive", "yes"), r"robot\.rsi\.passive: expected true or false, got 'yes'"),
    (variant("robot.rsi.cycle_s", 0), r"robot\.rsi\.cycle_s: expected a positive number, got 0"),
    (variant("plc.protocol", "profinet"), r"plc\.protocol: unknown protocol 'profinet' \(supported: modbus\)"),
    (variant("meteo.protocol", 5), r"meteo\.protocol: unknown protocol 5"),
    (variant("tracker.host", ""), r"tracker\.host: expected a host name or IP address, got ''"),
    (variant("tracker.host", ["192.168.0.10"]), r"tracker\.host: expected a host name"),
    (variant("plc.host", DELETE), r"plc\.host: missing"),
    (variant("meteo.port", 9600), r"meteo\.port: expected a serial device path or pyserial URL, got 9600"),
    (variant("meteo.baudrate", 96.5), r"meteo\.baudrate: expected an integer"),
    (variant("tracker.timeout_s", 0), r"tracker\.timeout_s: expected a positive number, got 0"),
    (variant("robot.connect_timeout_s", "60 s"), r"robot\.connect_timeout_s: expected a positive number"),
    (variant("plc.poll_s", -0.1), r"plc\.poll_s: expected a positive number"),
    (variant("tracker", "192.168.0.10"), r"tracker: expected a mapping of protocol, host, port"),
    ([GOOD], r"expected a mapping of keys at the top level, got list"),
    ("", r"expected a mapping of keys at the top level, got NoneType"),
    ("tracker: {host: [1, 2\nrobot: {}\n", r"not valid YAML \(line \d+\)"),
]


@pytest.mark.parametrize(("doc", "message"), BAD, ids=[m.split(":")[0].replace("\\", "") for _, m in BAD])
def test_bad_hardware_files_are_named_with_the_key(tmp_path, doc, message):
    path = tmp_path / "cell.yaml"
    path.write_text(doc if isinstance(doc, str) else yaml.safe_dump(doc))
    with pytest.raises(InputError, match=rf"^{re.escape(str(path))}: {message}"):
        load_hardware(path)


def test_unreadable_file(tmp_path):
    with pytest.raises(InputError, match=r"nothing\.yaml: no such file"):
        load_hardware(tmp_path / "nothing.yaml")


def test_defaults_are_the_drivers_and_optional_sections(tmp_path):
    path = tmp_path / "cell.yaml"
    path.write_text(
        yaml.safe_dump(
            {
                "tracker": {"protocol": "emscon", "host": "at901"},
                "robot": {
                    "protocol": "krc2",
                    "controller_host": "krc2",
                    "eki": {"host": "pc", "port": 54600},
                    "rsi": {"host": "pc", "port": 49152},
                },
            }
        )
    )
    hw = load_hardware(path)
    # drivers.emscon.client.EmsconTracker and drivers.kuka.client.KukaKrc2 defaults; emScon TPI port 700
    assert hw.tracker == {
        "protocol": "emscon",
        "host": "at901",
        "port": 700,
        "timeout_s": 5.0,
        "measure_timeout_s": 60.0,
        "motion_timeout_s": 120.0,
        "search_timeout_s": 10.0,
        "samples_per_second": 1000.0,
    }
    assert hw.robot["eki"] == {"host": "pc", "port": 54600}
    # RSI: the shipped configs/krc2/trackcal_rsi.xml (UDP, passive) and the KR C2's 12 ms cycle
    assert hw.robot["rsi"] == {"protocol": "udp", "passive": True, "cycle_s": 0.012, "host": "pc", "port": 49152}
    assert hw.robot["connect_timeout_s"] == 60.0 and hw.robot["move_timeout_s"] == 300.0
    assert hw.plc is None and hw.meteo is None  # the operator is asked on the console
    assert "console" in hw.describe()["operator"]


def test_shipped_example_is_valid():
    hw = load_hardware(EXAMPLE)
    assert hw.tracker["host"] == "192.168.0.10" and hw.robot["rsi"]["port"] == 49152
    assert hw.plc["unit_id"] == 1 and hw.meteo["port"] == "/dev/ttyUSB0"


# ---------------------------------------------------------------- the command line


def run(*args, check=True, timeout=120):
    return subprocess.run([*TRACKCAL, *args], capture_output=True, text=True, check=check, timeout=timeout, cwd=ROOT)


@pytest.fixture(scope="module")
def plan(tmp_path_factory):
    """A small plan: 3 configurations, 2 stations x 3 reference points. The seed is one whose poses keep every
    reference point strictly inside the cell box after the plan's rounding to 4 decimals."""
    path = tmp_path_factory.mktemp("plan") / "plan.json"
    run(
        "plan",
        "--cell",
        "kr270",
        "--configs",
        "3",
        "--repeat",
        "1",
        "--starts",
        "50",
        "--refined",
        "1",
        "--seed",
        "1",
        "--json",
        str(path),
    )
    return path


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_run_with_a_broken_hardware_file_makes_no_session(plan, tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(variant("tracker.port", 70000)))
    out = run(
        "run",
        "--cell",
        "kr270",
        "--plan",
        str(plan),
        "--hardware",
        str(bad),
        "--session",
        str(tmp_path / "s"),
        check=False,
    )
    assert out.returncode == 2 and "Traceback" not in out.stderr
    assert f"{bad}: tracker.port: 70000 out of range" in out.stderr
    assert not (tmp_path / "s").exists()
    out = run(
        "run",
        "--cell",
        "kr270",
        "--plan",
        str(plan),
        "--hardware",
        str(EXAMPLE),
        "--effect",
        "backlash",
        "--session",
        str(tmp_path / "s"),
        check=False,
    )
    assert out.returncode == 2 and "--effect and --sim-speed are for --sim only" in out.stderr


def test_unreachable_tracker_names_it_and_resume_uses_the_session_copy(plan, tmp_path):
    port = free_port()  # nothing listens there
    hw = tmp_path / "cell.yaml"
    doc = {"tracker": {"protocol": "emscon", "host": "127.0.0.1", "port": port, "timeout_s": 2}, "robot": GOOD["robot"]}
    hw.write_text(yaml.safe_dump(doc))
    d = tmp_path / "s"
    out = run("run", "--cell", "kr270", "--plan", str(plan), "--hardware", str(hw), "--session", str(d), check=False)
    assert out.returncode == 2 and "Traceback" not in out.stderr, out.stderr
    assert f"cannot connect the tracker (emScon 127.0.0.1:{port})" in out.stderr
    assert (d / "config" / "hardware.yaml").read_text() == hw.read_text()  # the session keeps its copy
    hw.unlink()  # resume needs no argument and not the original file
    out = run("resume", str(d), check=False)
    assert out.returncode == 2 and f"127.0.0.1:{port}" in out.stderr and "Traceback" not in out.stderr
    assert "config/hardware.yaml" in out.stderr  # where to fix it


def measure_steps(cell, plan: Path) -> int:
    return sum(s.kind == "measure" for s in plan_steps(cell, json.loads(plan.read_text())))


# slow: the README runs `trackcal mock` and `run --hardware` in separate processes by default (its UR block); this is
# the same for the KR C2 mock, 20 s
@pytest.mark.slow
def test_mock_and_run_hardware_in_separate_processes(kr270, plan, mock_cell, tmp_path):
    proc, hw = mock_cell
    assert load_hardware(hw).plc is not None  # the mock writes the schema it is read with
    d = tmp_path / "session"
    out = run(
        "run",
        "--cell",
        "kr270",
        "--plan",
        str(plan),
        "--hardware",
        str(hw),
        "--session",
        str(d),
        "--no-analysis",
        timeout=150,
    )
    assert out.returncode == 0, out.stderr
    assert (d / "config" / "hardware.yaml").read_bytes() == hw.read_bytes()
    # the operator was asked through the PLC alone: 2 stations, 3 reference points each, a resume after each
    with sqlite3.connect(d / "session.sqlite") as db:
        prompts = [json.loads(r[0])["kind"] for r in db.execute("SELECT data FROM events WHERE kind='prompt'")]
        skipped = [r for r in db.execute("SELECT data FROM events WHERE kind='warning'") if "skipped here" in r[0]]
        warned = [r[0] for r in db.execute("SELECT data FROM events WHERE kind='warning'") if "serial" in r[0]]
        (identity,) = [json.loads(r[0]) for r in db.execute("SELECT data FROM events WHERE kind='identity'")]
    # who measured (#39): the twin's tracker says its serial over emScon, the one the mock's hardware file states
    assert identity["tracker"]["serial"] == str(load_hardware(hw).tracker["serial"]) and not warned
    assert identity["tracker"]["source"] == "read from the device"
    assert identity["robot"]["source"] == "from the hardware file"  # a KR C2: EKI and RSI cannot ask it
    assert prompts.count("change_station") == 2 and prompts.count("move_reflector") == 6
    assert prompts.count("resume") == 8
    run("export", str(d), "--csv", str(tmp_path / "t.csv"))
    table = read_table(tmp_path / "t.csv")
    assert len(table) == measure_steps(kr270, plan) - len(skipped) and len(table) > 0
    assert not skipped  # every planned point is visible from its station on this twin (seed 3)
    # resume of the finished campaign needs nothing but the session (it reads its copy of the hardware file)
    out = run("resume", str(d), "--no-analysis")
    assert "already complete" in out.stdout
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=15)
    assert proc.returncode == 0, stderr
    assert "Traceback" not in stderr and "stopping" in stdout


@pytest.mark.slow
def test_kill_9_then_resume_against_the_same_mock_gives_the_sim_table(kr270, plan, mock_cell, tmp_path):
    """The controller of `trackcal mock` starts afresh for the resumed process; the campaign ends with the rows,
    joints and positions of `run --sim` with the same seed (the same twin, the same protocols, in-process)."""
    proc, hw = mock_cell
    d = tmp_path / "session"
    run_proc = subprocess.Popen(
        [
            *TRACKCAL,
            "run",
            "--cell",
            "kr270",
            "--plan",
            str(plan),
            "--hardware",
            str(hw),
            "--session",
            str(d),
            "--no-analysis",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        cwd=ROOT,
    )
    n = measure_steps(kr270, plan)
    deadline = time.monotonic() + 120
    while count_measurements(d / "session.sqlite") < n // 2 and time.monotonic() < deadline:
        assert run_proc.poll() is None
        time.sleep(0.01)
    os.kill(run_proc.pid, signal.SIGKILL)
    run_proc.wait()
    stored = count_measurements(d / "session.sqlite")
    assert 0 < stored < n
    out = run("resume", str(d), "--no-analysis", timeout=150)
    assert out.returncode == 0, out.stderr
    run("export", str(d), "--csv", str(tmp_path / "hw.csv"))
    run(
        "run",
        "--cell",
        "kr270",
        "--plan",
        str(plan),
        "--sim",
        "--seed",
        "3",
        "--session",
        str(tmp_path / "sim"),
        "--no-analysis",
        timeout=150,
    )
    run("export", str(tmp_path / "sim"), "--csv", str(tmp_path / "sim.csv"))
    a, b = read_table(tmp_path / "hw.csv"), read_table(tmp_path / "sim.csv")
    assert a.pose == b.pose and a.point == b.point and a.station == b.station
    assert (a.q_deg == b.q_deg).all()
    assert (a.xyz[:stored] == b.xyz[:stored]).all()  # measured before the kill: the same noise draws
    # a point measured by the tracker but not yet stored at the kill is measured again with a new draw of the
    # tracker noise (~0.015 mm RMS, calib.noise.TrackerNoise); nothing else changes
    assert abs(a.xyz - b.xyz).max() < 0.2
    proc.send_signal(signal.SIGINT)
    assert proc.wait(timeout=15) == 0


# slow: the session lock (tests/test_store.py) and the robot claims (tests/test_ur_claim.py) are checked by default;
# this whole two-process campaign takes about 30 s
@pytest.mark.slow
def test_second_campaign_on_a_busy_mock_is_refused_and_the_first_keeps_its_table(kr270, plan, mock_cell, tmp_path):
    """Issue 27, item 8: "two campaigns on one `trackcal mock`: the second leaves an empty session behind, the
    first's tracker noise is no longer the deterministic stream of its seed". The controller connects to one
    server (configs/krc2/XmlApiConfig.xml: one IP and PORT), so the cell serves one campaign: the second finds the
    robot's EKI port held, is refused with one line before it makes a session or touches a device, and the first
    ends with the table of `run --sim` with the same seed (3, the mock_cell fixture's)."""
    proc, hw = mock_cell
    a, b = tmp_path / "a", tmp_path / "b"
    first = subprocess.Popen(
        [
            *TRACKCAL,
            "run",
            "--cell",
            "kr270",
            "--plan",
            str(plan),
            "--hardware",
            str(hw),
            "--session",
            str(a),
            "--no-analysis",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        cwd=ROOT,
    )
    try:
        deadline = time.monotonic() + 120  # bounds a hang only
        while count_measurements(a / "session.sqlite") < 1 and time.monotonic() < deadline:
            assert first.poll() is None, first.stderr.read()
            time.sleep(0.01)
        assert count_measurements(a / "session.sqlite") >= 1  # the first campaign is running
        out = run(
            "run", "--cell", "kr270", "--plan", str(plan), "--hardware", str(hw), "--session", str(b), check=False
        )
        assert out.returncode == 2 and "Traceback" not in out.stderr, out.stderr
        assert len(out.stderr.splitlines()) == 1 and "the cell is busy" in out.stderr, out.stderr
        assert not b.exists()
        _, err = first.communicate(timeout=150)
        assert first.returncode == 0, err
    finally:
        if first.poll() is None:
            first.kill()
            first.wait()
    run("export", str(a), "--csv", str(tmp_path / "hw.csv"))
    run(
        "run",
        "--cell",
        "kr270",
        "--plan",
        str(plan),
        "--sim",
        "--seed",
        "3",
        "--session",
        str(tmp_path / "sim"),
        "--no-analysis",
        timeout=150,
    )
    run("export", str(tmp_path / "sim"), "--csv", str(tmp_path / "sim.csv"))
    got, want = read_table(tmp_path / "hw.csv"), read_table(tmp_path / "sim.csv")
    assert got.pose == want.pose and got.point == want.point and got.station == want.station
    assert (got.q_deg == want.q_deg).all() and (got.xyz == want.xyz).all()
    proc.send_signal(signal.SIGINT)
    assert proc.wait(timeout=15) == 0
