"""The ABB cells on the hardware path (issue 40): `trackcal mock --cell irb120` (and irb6700: the larger arm) (the
twin behind the mock ABB controller in a process of its own, Robot Web Services on loopback) and `trackcal run
--hardware` against it, as on the shop floor: the same seed measures the same rows as `run --sim`. And the hardware
file's ABB section."""

import json
import re
import signal

import pytest
import yaml

from tests.helpers import ROOT, mock_process
from tests.helpers import exported_table as table
from tests.helpers import run_trackcal as run
from trackcal.campaign.cells.hardware import load_hardware
from trackcal.campaign.errors import InputError

# the test pose of configs/cells/irb120.yaml and irb6700.yaml: every nest faces a station
Q0 = (0.0, 10.0, 10.0, 0.0, 40.0, 0.0)
SEED = 4


@pytest.mark.slow  # minutes on a shared 2-core machine: settle windows and operator prompts run on the wall clock
@pytest.mark.parametrize("cell", ["irb120", "irb6700"])
def test_one_pose_over_the_mock_abb_controller_measures_the_sim_rows(tmp_path, cell):
    plan = tmp_path / "plan.json"
    plan.write_text(json.dumps({"poses_deg": [list(Q0)], "repeat": 1}))
    hw = tmp_path / "H.yaml"
    with mock_process(cell, SEED, hw, timeout_s=90.0, sim_speed=10.0) as proc:
        hardware = load_hardware(hw)
        assert hardware.robot["protocol"] == "abb" and hardware.family.title == "ABB"
        run(
            "run",
            "--cell",
            cell,
            "--plan",
            str(plan),
            "--hardware",
            str(hw),
            "--session",
            str(tmp_path / "h"),
            "--no-analysis",
        )
        proc.send_signal(signal.SIGINT)
        _, stderr = proc.communicate(timeout=30)
        assert proc.returncode == 0 and "Traceback" not in stderr, stderr
    run(
        "run",
        "--cell",
        cell,
        "--plan",
        str(plan),
        "--sim",
        "--seed",
        str(SEED),
        "--session",
        str(tmp_path / "s"),
        "--no-analysis",
    )
    got, want = table(tmp_path / "h", tmp_path / "h.csv"), table(tmp_path / "s", tmp_path / "s.csv")
    assert len(got.pose) >= 6  # both stations see the three nests at the test pose
    assert got.pose == want.pose and got.point == want.point and got.station == want.station
    assert (got.q_deg == want.q_deg).all() and (got.xyz == want.xyz).all()


def test_the_abb_section_needs_the_controllers_address_and_takes_its_credentials(tmp_path):
    doc = yaml.safe_load((ROOT / "configs" / "hardware" / "example-cell.yaml").read_text())
    path = tmp_path / "h.yaml"
    cases = (
        ({"protocol": "abb"}, "robot.host: missing (required)"),
        ({"protocol": "abb", "host": "192.168.0.7", "user": 3}, "robot.user: expected a non-empty text"),
        ({"protocol": "abb", "host": "192.168.0.7", "eki": {}}, "robot.eki: unknown key"),
        (
            {"protocol": "abb", "host": "192.168.0.7", "egm": {"host": "192.168.0.2"}},
            "robot.egm.port: missing (required)",
        ),
    )
    for robot, message in cases:
        path.write_text(yaml.safe_dump({**doc, "robot": robot}))
        with pytest.raises(InputError, match=re.escape(message)):
            load_hardware(path)
    path.write_text(yaml.safe_dump({**doc, "robot": {"protocol": "abb", "host": "192.168.0.7"}}))
    hardware = load_hardware(path)
    # the defaults: RWS on HTTP port 80 as "Default User" / robotics (the Robot Web Services manual's sample calls)
    assert hardware.robot["port"] == 80 and hardware.robot["user"] == "Default User"
    assert hardware.robot["password"] == "robotics"
    assert "192.168.0.7" in hardware.describe()["robot"] and "egm" not in hardware.robot
    path.write_text(
        yaml.safe_dump(
            {**doc, "robot": {"protocol": "abb", "host": "192.168.0.7", "egm": {"host": "192.168.0.2", "port": 6510}}}
        )
    )
    hardware = load_hardware(path)
    assert hardware.robot["egm"] == {"host": "192.168.0.2", "port": 6510} and hardware.robot["egm_stale_s"] == 1.0
    assert "192.168.0.2:6510" in hardware.describe()["robot"]
