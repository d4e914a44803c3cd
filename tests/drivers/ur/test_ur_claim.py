"""One campaign per UR arm (issue 21, the KR C2's claim for the UR family): `run --hardware` claims the controller's
address on this PC before it makes a session or touches a device (drivers/ur/client.py UrRtde.claim), so a second
campaign on the same arm is refused in one line, and the claim ends with the process that held it."""

import errno
import json
import subprocess
import sys
import time

import pytest
import yaml

from tests.helpers import ROOT, TRACKCAL, count_measurements, mock_process, stop
from trackcal.drivers.errors import ConnectionLost
from trackcal.drivers.families import families
from trackcal.drivers.ur.client import UrRtde

Q0 = (-16.0, -49.0, 59.0, -19.0, -104.0, -12.0)  # the ur10 cell's test pose (configs/cells/ur10.yaml)


def test_a_second_claim_on_one_address_is_refused_until_the_first_is_closed():
    first, second, other = UrRtde("127.0.0.93"), UrRtde("127.0.0.93"), UrRtde("127.0.0.94")
    try:
        first.claim()
        first.claim()  # idempotent
        with pytest.raises(ConnectionLost, match="another trackcal process on this PC drives") as caught:
            second.claim()
        assert caught.value.__cause__.errno == errno.EADDRINUSE  # what cells/hardware.py calls a busy cell
        other.claim()  # another arm is another claim
        first.close()
        second.claim()
    finally:
        for robot in (first, second, other):
            robot.close()
    assert families()["ur"].claim is not None


def test_a_claim_dies_with_its_process():
    """kill -9 of a campaign leaves no stale claim: the kernel drops the abstract socket with the process."""
    code = (
        "from trackcal.drivers.ur.client import UrRtde; r = UrRtde('127.0.0.95'); r.claim(); "
        "print('held', flush=True); import time; time.sleep(60)"
    )
    holder = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    robot = UrRtde("127.0.0.95")
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(ConnectionLost):
            robot.claim()
        holder.kill()
        holder.wait()
        robot.claim()
    finally:
        robot.close()
        if holder.poll() is None:
            holder.kill()
            holder.wait()


def hardware_file(path, host):
    doc = yaml.safe_load((ROOT / "configs" / "hardware" / "example-cell.yaml").read_text())
    doc["robot"] = {"protocol": "ur", "host": host}
    doc.pop("meteo", None)
    path.write_text(yaml.safe_dump(doc))
    return path


def test_run_on_a_claimed_arm_is_refused_in_one_line_before_it_makes_a_session(tmp_path):
    """The claim comes before any device: here no controller even listens at the address, and the refusal is still
    the busy cell's, with no session left behind."""
    plan = tmp_path / "plan.json"
    plan.write_text(json.dumps({"poses_deg": [list(Q0)], "repeat": 1}))
    hw = hardware_file(tmp_path / "h.yaml", "127.0.0.96")
    holder = UrRtde("127.0.0.96")
    holder.claim()  # as a running campaign holds it
    try:
        out = subprocess.run(
            [
                *TRACKCAL,
                "run",
                "--cell",
                "ur10",
                "--plan",
                str(plan),
                "--hardware",
                str(hw),
                "--session",
                str(tmp_path / "b"),
                "--no-analysis",
            ],
            capture_output=True,
            text=True,
            timeout=120,
            cwd=ROOT,
        )
    finally:
        holder.close()
    assert out.returncode == 2 and "Traceback" not in out.stderr, out.stderr
    assert len(out.stderr.splitlines()) == 1 and "the cell is busy" in out.stderr, out.stderr
    assert not (tmp_path / "b").exists()


@pytest.mark.slow
def test_second_run_against_the_same_mock_ur_while_the_first_runs_is_refused(tmp_path):
    """Two `run --hardware` on one `trackcal mock --cell ur10`: the second is refused in one line while the first
    measures, and the first completes."""
    plan = tmp_path / "plan.json"
    plan.write_text(json.dumps({"poses_deg": [list(Q0), [q + 4 for q in Q0]], "repeat": 1}))
    hw = tmp_path / "H.yaml"
    first = None
    with mock_process("ur10", 3, hw, timeout_s=60.0, stdout=subprocess.DEVNULL, sim_speed=10.0):
        try:
            a, b = tmp_path / "a", tmp_path / "b"
            first = subprocess.Popen(
                [
                    *TRACKCAL,
                    "run",
                    "--cell",
                    "ur10",
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
            deadline = time.monotonic() + 120  # bounds a hang only
            while count_measurements(a / "session.sqlite") < 1 and time.monotonic() < deadline:
                assert first.poll() is None, first.stderr.read()
                time.sleep(0.01)
            assert count_measurements(a / "session.sqlite") >= 1  # the first campaign is running
            out = subprocess.run(
                [
                    *TRACKCAL,
                    "run",
                    "--cell",
                    "ur10",
                    "--plan",
                    str(plan),
                    "--hardware",
                    str(hw),
                    "--session",
                    str(b),
                    "--no-analysis",
                ],
                capture_output=True,
                text=True,
                timeout=120,
                cwd=ROOT,
            )
            assert out.returncode == 2 and len(out.stderr.splitlines()) == 1, out.stderr
            assert "the cell is busy" in out.stderr and not b.exists(), out.stderr
            _, err = first.communicate(timeout=300)
            assert first.returncode == 0, err
        finally:
            if first is not None:
                stop(first)
