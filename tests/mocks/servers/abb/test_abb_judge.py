"""The judge of the mock ABB controller's fidelity: abb-robot-client 0.4.0 (PyPI, written for real IRC5 controllers
with RobotWare 6), unmodified, in a venv of its own (.venv/judge-abb, built by make setup), drives the mock in its own
process over loopback (tests/thirdparty/abb/judge.py): controller state, operating mode, RAPID execution and tasks,
ROB_1's jointtarget and robtarget, RAPID variables read and written (a move through the TrackcalRws module), RAPID
stopped, its pointer reset and started again, the event log; then a wrong password (401), a busy controller (503)
and a controller that disappears. What it reads must equal the twin's: the mock's own joints and the nominal
IRB 120's forward kinematics."""

from __future__ import annotations

import json
import socket
import subprocess

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tests.helpers import ROOT
from trackcal.calib.model.cell import load_robot
from trackcal.calib.model.kinematics import Kinematics
from trackcal.mocks.servers.abb.process import MockAbbProcess

JUDGE = ROOT / ".venv" / "judge-abb" / "bin" / "python"
SCRIPT = ROOT / "tests" / "thirdparty" / "abb" / "judge.py"
Q0 = (10.0, -20.0, 15.0, 30.0, 40.0, -50.0)
TARGET = (-25.5, 30.25, -40.0, 100.0, -60.0, 200.0)


def judge(url: str, scenario: str, *args: str) -> dict:
    if not JUDGE.exists():
        pytest.fail(f"{JUDGE} missing: make setup builds the judge's venv")
    done = subprocess.run([str(JUDGE), str(SCRIPT), url, scenario, *args], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


def flange_pose(q_deg) -> tuple[np.ndarray, np.ndarray]:
    """(position mm, quaternion w x y z) of ABB's tool0 at q: the IRB 120's nominal chain (configs/robots/irb120.yaml,
    ROS-Industrial's geometry) and tool0 = link 6 turned 90 deg about y (ROS-Industrial abb_irb120_support's tool0)."""
    chain, _ = load_robot("irb120")
    r, o = Kinematics(chain, []).end_frames(np.radians(np.asarray(q_deg, dtype=float))[None, :])
    x, y, z, w = (Rotation.from_matrix(r[0]) * Rotation.from_euler("y", 90, degrees=True)).as_quat()
    quat = np.array([w, x, y, z])
    return o[0], quat if w >= 0 else -quat


@pytest.fixture(scope="module")
def mock():
    with MockAbbProcess(seed=11, args=["--q0-deg", ",".join(map(str, Q0))]) as m:
        yield m


def test_the_judge_reads_and_drives_the_mock_as_the_twin_says(mock):
    url = "http://{}:{}".format(*mock.address)
    out = judge(url, "drive", ",".join(map(str, TARGET)))
    assert "error" not in out, out
    before, after = out["before"], out["after"]
    assert before["ctrlstate"] == "motoron" and before["opmode"] == "AUTO"
    assert before["execution"][0] == "running" and before["tasks"] == ["T_ROB1"]
    assert before["joints"] == pytest.approx(Q0, abs=1e-6)
    assert after["joints"] == pytest.approx(TARGET, abs=1e-6) == mock.state()["q_deg"]
    for read, q in ((before, Q0), (after, TARGET)):
        position, quat = flange_pose(q)
        assert read["trans"] == pytest.approx(position, abs=1e-3)  # the robtarget is shown to 6 significant digits
        assert read["rot"] == pytest.approx(quat, abs=1e-6)
    assert after["done"] == "1" and after["speed_num"] == 100.0
    # RobotWare's event numbers: 10010 Motors OFF state (at boot), 10011 Motors ON state; newest first
    assert [e[0] for e in after["elog"]] == [10011, 10010]
    assert out["stopped"] == "stopped" and out["started"] == "running"


def test_a_wrong_password_is_refused_with_401(mock):
    out = judge("http://{}:{}".format(*mock.address), "password")
    assert out["error"] == "Exception" and "401" in out["text"]


def test_a_busy_controller_answers_503(mock):
    mock.busy(1)
    out = judge("http://{}:{}".format(*mock.address), "busy")
    # abb-robot-client 0.4.0 raises on 503 with the text it has for it (rws.py, _process_response)
    assert out["error"] == "Exception" and "Robot returning" in out["text"]
    assert mock.control("busy 0") == "ok"


def test_a_controller_that_disappears_is_a_connection_error_for_the_judge():
    with MockAbbProcess(seed=12) as gone:
        proc = subprocess.Popen(
            [str(JUDGE), str(SCRIPT), "http://{}:{}".format(*gone.address), "gone"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        assert proc.stdout is not None
        try:
            first = json.loads(proc.stdout.readline())
            assert first["before"] == "motoron"
            gone.kill()
            out, _ = proc.communicate("go\n", timeout=60)
        finally:
            if proc.poll() is None:
                proc.kill()
    assert json.loads(out.strip().splitlines()[-1])["error"] == "ConnectionError"


def test_the_judge_receives_the_egm_stream_as_the_twin_says():
    """abb-robot-client's EGM class (its own egm_pb2, Google protobuf) reads the mock's EgmRobot datagrams (trackcal's
    hand codec): the joints, the planned target, motors on and RAPID running, one sequence number per 4 ms tick."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:  # a free UDP port for the judge to bind
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with MockAbbProcess(seed=13, args=["--q0-deg", ",".join(map(str, Q0)), "--egm", f"127.0.0.1:{port}"]) as m:
        out = judge(str(port), "egm")
        state = m.state()
    assert "error" not in out, out
    assert out["count"] == 50 and out["motors_on"] and out["rapid_running"]
    assert out["joints"] == pytest.approx(Q0, abs=0) == state["q_deg"]
    assert out["planned"] == pytest.approx(Q0, abs=0)  # standing: the planned position is where it stands
    steps = np.diff(out["seqnos"])
    assert (steps >= 1).all()  # increasing: none repeated, none out of order on loopback
