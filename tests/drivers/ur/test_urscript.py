"""URScript output of `trackcal compensate --program` for a robot whose controller is a UR (drivers/ur/program.py),
the KRL program for the KR C2: the same rows, the same 1e-4 deg rounding, selected by the robot config's controller."""

import math
import re
import subprocess

import pytest

from tests.helpers import TRACKCAL
from trackcal.drivers.families import families
from trackcal.drivers.ur.program import UrScriptError, urscript_text

MOVEJ = re.compile(r"^  movej\(\[([^\]]*)\], a=([0-9.]+), v=([0-9.]+)\)$")


def test_movej_lines_in_radians_with_the_scaled_manual_defaults():
    q = [[-16.0, -49.0, 59.0, -19.0, -104.0, -12.0], [0.0, -90.0, 90.0, -90.0, -90.0, 0.0]]
    text = urscript_text("calib_moves", q, speed_pct=20, points=["A", "B"])
    lines = text.splitlines()
    assert lines[0] == "def calib_moves():" and lines[-1] == "end" and text.endswith("end\n")
    moves = [MOVEJ.match(line) for line in lines if line.strip().startswith("movej")]
    assert len(moves) == 2 and all(moves)
    for m, row in zip(moves, q, strict=True):
        rad = [float(v) for v in m.group(1).split(",")]
        assert rad == pytest.approx([math.radians(v) for v in row], abs=5e-11)  # 10 decimals of a radian
        # URScript manual: movej(q, a=1.4, v=1.05): 20 % of each
        assert float(m.group(2)) == pytest.approx(0.28) and float(m.group(3)) == pytest.approx(0.21)
    assert "# A: -16.0000, -49.0000" in text


@pytest.mark.parametrize(
    ("name", "q", "speed"),
    [
        ("9x", [[0] * 6], 10),
        ("a b", [[0] * 6], 10),
        ("p", [[0] * 5], 10),
        ("p", [[math.nan] * 6], 10),
        ("p", [[0] * 6], 0),
        ("p", [[0] * 6], 101),
    ],
)
def test_refused(name, q, speed):
    with pytest.raises(UrScriptError):
        urscript_text(name, q, speed)


def test_each_family_carries_its_program():
    """compensate picks the writer of the family the robot config names (drivers/families.py), by no name of its own."""
    programs = {name: f.program.language for name, f in families().items()}
    assert programs == {"abb": "RAPID", "krc2": "KRL", "krc4": "KRL", "ur": "URScript"}
    assert list(families()["abb"].program.texts("p", [[0.0] * 6])) == ["p.mod"]
    assert list(families()["ur"].program.texts("p", [[0.0] * 6])) == ["p.script"]
    assert list(families()["krc2"].program.texts("p", [[0.0] * 6])) == ["p.src", "p.dat"]


def test_compensate_writes_urscript_for_the_ur_cell_and_krl_for_the_kr270(tmp_path):
    def cli(*args, check=True):
        out = subprocess.run([*TRACKCAL, *args], capture_output=True, text=True, cwd=tmp_path)
        assert not check or out.returncode == 0, out.stderr
        return out

    targets = tmp_path / "t.csv"
    for cell, q0, files in (
        ("ur10", "-16,-49,59,-19,-104,-12", ["P.script"]),
        ("kr270", "76.7,-56.9,89.3,45.1,76,57.2", ["P.src", "P.dat"]),
    ):
        cli("simulate", "--cell", cell, "--poses", "12", "--seed", "2", "--out", f"{cell}.csv")
        cli("identify", f"{cell}.csv", "--cell", cell, "--out", f"{cell}.json")
        targets.write_text(f"name,q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg\nA,{q0}\n")
        d = tmp_path / cell
        d.mkdir()
        # 12 random poses leave some of the KR-270's 18 parameters poorly determined: the model is marked unusable
        # (calib.model_trust), accepted here for the program it writes
        cli(
            "compensate",
            str(targets),
            "--model",
            f"{cell}.json",
            "--out",
            str(d / "c.csv"),
            "--program",
            "P",
            "--accept-poor",
        )
        assert sorted(p.name for p in d.iterdir()) == sorted(["c.csv", *files])
    rows = (tmp_path / "ur10" / "c.csv").read_text().splitlines()
    assert len(rows) == 2
    assert "\n  # A: " in (tmp_path / "ur10" / "P.script").read_text()  # the target's own name, not a KRL name
    bad = cli(
        "compensate",
        str(targets),
        "--model",
        "ur10.json",
        "--out",
        str(tmp_path / "x.csv"),
        "--program",
        "9",
        check=False,
    )
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and not (tmp_path / "x.csv").exists()
