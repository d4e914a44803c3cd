"""Input bounds (issue 42): a DH value is a finite number within a physical range, never text; a URDF deeper than a
robot's is refused before pinocchio reads it; an import map reads each thing from a column of its own. Each mistake
is one line and exit 2."""

import pytest
import yaml

from trackcal.calib.model.chain import MAX_URDF_JOINTS, ChainError, chain_from_dict, chain_from_urdf
from trackcal.campaign.cli import main

# configs/robots/ur10-dh.yaml's first row: UR10 DH (Universal Robots' DH page), d1 = 127.3 mm, alpha1 = 90 deg
ROW = {"a_mm": 0, "alpha_deg": 90, "d_mm": 127.3}


@pytest.mark.parametrize(
    ("key", "value", "message"),
    [
        ("d_mm", 1e308, r"d_mm: 1e\+308 mm is outside \+-20000 mm"),  # 1e308 mm: a link longer than the universe
        ("a_mm", -25000.0, r"a_mm: -25000 mm is outside \+-20000 mm"),  # 25 m: no arm (the largest reach under 5 m)
        ("alpha_deg", 720.0, r"alpha_deg: 720 deg is outside \+-360 deg"),
        ("theta_offset_deg", -1e9, r"theta_offset_deg: -1e\+09 deg is outside \+-360 deg"),
        ("d_mm", "12", r"d_mm: expected a number, got the string '12'"),
        ("alpha_deg", "90", r"alpha_deg: expected a number, got the string '90'"),
        ("sign", "-1", r"sign: expected a number, got the string '-1'"),
    ],
)
def test_a_dh_value_out_of_range_or_in_quotes_is_refused(key, value, message):
    with pytest.raises(ChainError, match=r"robot.yaml: dh.rows\[0\]." + message):
        chain_from_dict({"dh": {"rows": [ROW | {key: value}]}}, "robot.yaml")


def test_a_dh_flange_out_of_range_is_refused_and_yaml_exponents_are_numbers():
    with pytest.raises(ChainError, match=r"flange.translation_mm\[2\]: 1e\+300 mm is outside"):
        chain_from_dict({"dh": {"rows": [ROW], "flange": {"translation_mm": [0, 0, 1e300]}}}, "robot.yaml")
    # PyYAML (YAML 1.1) reads `1.273e2` as a float but `9e1` as a string: both are the number they write
    doc = yaml.safe_load("dh: {rows: [{a_mm: 0, alpha_deg: 9e1, d_mm: 1.273e2}]}")
    assert isinstance(doc["dh"]["rows"][0]["alpha_deg"], str)
    chain = chain_from_dict(doc, "robot.yaml")
    assert chain.dof == 1


def deep_urdf(n: int) -> str:
    """A serial chain of n revolute joints, 0.1 m apart."""
    out = ['<robot name="deep">', '<link name="l0"/>']
    for i in range(n):
        out += [
            f'<link name="l{i + 1}"/>',
            f'<joint name="j{i + 1}" type="revolute"><parent link="l{i}"/>'
            f'<child link="l{i + 1}"/><origin xyz="0 0 0.1"/><axis xyz="0 0 1"/>'
            '<limit lower="-1" upper="1" effort="1" velocity="1"/></joint>',
        ]
    return "\n".join([*out, "</robot>"])


def test_a_urdf_deeper_than_a_robot_is_one_line(tmp_path, capsys):
    """5000 joints took the process down in pinocchio's parser (a segmentation fault): refused before it reads."""
    path = tmp_path / "deep.urdf"
    path.write_text(deep_urdf(5000))
    with pytest.raises(ChainError, match=f"5000 joints, more than the {MAX_URDF_JOINTS}"):
        chain_from_urdf(str(path))
    assert main(["plan", "--cell", str(path), "--json", str(tmp_path / "plan.json")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "5000 joints" in err, err
    path.write_text(deep_urdf(6))  # a robot's depth still loads
    assert chain_from_urdf(str(path)).dof == 6


@pytest.mark.parametrize(
    ("columns", "message"),
    [
        (
            {"joints": ["A1", "A1", "A1", "A1", "A1", "A1"], "xyz": ["X", "Y", "Z"]},
            "joint 1 and joint 2 are both read from column 'A1'",
        ),
        (
            {"joints": ["A1", "A2", "A3", "A4", "A5", "A6"], "xyz": ["X", "Y", "A6"]},
            "joint 6 and xyz z are both read from column 'A6'",
        ),
    ],
)
def test_an_import_map_with_two_roles_on_one_column_is_refused(tmp_path, capsys, columns, message):
    (tmp_path / "e.csv").write_text("A1,A2,A3,A4,A5,A6,X,Y,Z\n1,2,3,4,5,6,100,200,300\n")
    (tmp_path / "m.yaml").write_text(yaml.safe_dump({"columns": columns}))
    code = main(
        [
            "import",
            "table",
            str(tmp_path / "e.csv"),
            "--map",
            str(tmp_path / "m.yaml"),
            "--out",
            str(tmp_path / "t.csv"),
        ]
    )
    err = capsys.readouterr().err
    assert code == 2 and message in err and err.count("\n") == 1, err
    assert not (tmp_path / "t.csv").exists()


def test_two_reflectors_on_one_column_are_refused(tmp_path, capsys):
    """layout pose_rows: reflector P2's x read from P1's x column, by name and by position alike."""
    (tmp_path / "e.csv").write_text("A1,A2,X1,Y1,Z1,X2,Y2,Z2\n1,2,100,200,300,110,210,310\n")
    doc = {
        "layout": "pose_rows",
        "positions": "1-based",
        "columns": {"joints": ["A1", "A2"]},
        "points": {"P1": ["X1", "Y1", "Z1"], "P2": [3, "Y2", "Z2"]},
    }
    (tmp_path / "m.yaml").write_text(yaml.safe_dump(doc))
    code = main(
        [
            "import",
            "table",
            str(tmp_path / "e.csv"),
            "--map",
            str(tmp_path / "m.yaml"),
            "--out",
            str(tmp_path / "t.csv"),
        ]
    )
    err = capsys.readouterr().err
    assert code == 2 and "point P1 x and point P2 x are both read from column 3" in err, err
