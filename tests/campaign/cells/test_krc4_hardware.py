"""The KR C4 cell on the hardware path: `trackcal mock --cell kr210-krc4` (the twin behind the mock KR C4, in a process
of its own) and `trackcal run --hardware` against it, as on the shop floor: the same seed measures the same rows as
`run --sim`; the hardware file's robot section is the krc4 family's."""

import json
import re

import pytest
import yaml

from tests.helpers import ROOT, mock_process
from tests.helpers import exported_table as table
from tests.helpers import run_trackcal as run
from trackcal.campaign.cells.hardware import load_hardware
from trackcal.campaign.errors import InputError

# a pose of `trackcal plan --cell kr210-krc4 --configs 3 --seed 1` where both stations see the three nests
POSE = (-91.3111, -58.4328, 106.4285, 12.1082, 85.7149, -79.1803)
SEED = 3


# slow: ~45 s on a loaded 2-core machine (a 4 ms RSI cycle answered over loopback, 16 operator prompts); the client and
# the mock are checked by default in tests/drivers/krc4 and tests/mocks/servers/test_krc4_ros_rsi.py
@pytest.mark.slow
def test_one_pose_over_the_mock_kr_c4_measures_the_sim_rows(tmp_path):
    plan = tmp_path / "plan.json"
    plan.write_text(json.dumps({"poses_deg": [list(POSE)], "repeat": 1}))
    hw = tmp_path / "H.yaml"
    with mock_process("kr210-krc4", SEED, hw, timeout_s=60.0, sim_speed=200.0):
        hardware = load_hardware(hw)
        assert hardware.robot["protocol"] == "krc4" and hardware.family.title == "KR C4"
        assert hardware.robot["rsi"]["cycle_s"] == 0.004 and hardware.robot["rsi"]["passive"] is False
        run(
            "run",
            "--cell",
            "kr210-krc4",
            "--plan",
            str(plan),
            "--hardware",
            str(hw),
            "--session",
            str(tmp_path / "h"),
            "--no-analysis",
        )
    run(
        "run",
        "--cell",
        "kr210-krc4",
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
    assert len(got.pose) >= 6  # both stations see the three nests at this pose
    assert got.pose == want.pose and got.point == want.point and got.station == want.station
    assert (got.q_deg == want.q_deg).all() and (got.xyz == want.xyz).all()


@pytest.mark.parametrize(
    "robot, message",
    [
        (
            {"protocol": "krc4", "eki": {}, "rsi": {"host": "192.168.1.10", "port": 49152}},
            "robot.controller_host: missing (required)",
        ),
        (
            {
                "protocol": "krc4",
                "controller_host": "192.168.1.20",
                "eki": {"host": "192.168.1.10"},
                "rsi": {"host": "192.168.1.10", "port": 49152},
            },
            "robot.eki.host: unknown key",
        ),
        (
            {
                "protocol": "krc4",
                "controller_host": "192.168.1.20",
                "eki": {},
                "rsi": {"protocol": "tcp", "host": "192.168.1.10", "port": 49152},
            },
            "robot.rsi.protocol: unknown key",
        ),
    ],
)
def test_a_krc4_section_names_the_controller_and_no_kr_c2_keys(tmp_path, robot, message):
    """The controller serves EKI (its address is required, trackcal has no EKI host of its own) and RSI on KSS 8 is
    UDP (no protocol key)."""
    doc = yaml.safe_load((ROOT / "configs" / "hardware" / "example-cell.yaml").read_text())
    path = tmp_path / "h.yaml"
    path.write_text(yaml.safe_dump({**doc, "robot": robot}))
    with pytest.raises(InputError, match=re.escape(message)):
        load_hardware(path)


def test_the_defaults_are_the_shipped_kss8_files(tmp_path):
    doc = yaml.safe_load((ROOT / "configs" / "hardware" / "example-cell.yaml").read_text())
    path = tmp_path / "h.yaml"
    robot = {
        "protocol": "krc4",
        "controller_host": "192.168.1.20",
        "eki": {},
        "rsi": {"host": "192.168.1.10", "port": 49152},
    }
    path.write_text(yaml.safe_dump({**doc, "robot": robot}))
    r = load_hardware(path).robot
    # configs/krc4/TrackcalEki.xml INTERNAL/PORT 54600; trackcal_rsi_ethernet.xml ONLYSEND FALSE; IPO_FAST 4 ms
    assert r["eki"]["port"] == 54600 and r["rsi"]["passive"] is False and r["rsi"]["cycle_s"] == 0.004
