"""The user mistakes issue 12 lists, each through the command line: one line on stderr naming the file and the
key (or row and column), exit 2, nothing else on the console."""

import json
import re
import shutil

import pytest
import yaml

from trackcal.calib.model.cell import CONFIGS
from trackcal.campaign.cli import main


@pytest.fixture
def cell_dir(tmp_path):
    """configs/cells/kr270.yaml with its robot and tool beside it, to be spoiled one key at a time."""
    shutil.copyfile(CONFIGS / "robots" / "kr270.yaml", tmp_path / "robot.yaml")
    shutil.copyfile(CONFIGS / "tools" / "kr270-3point.yaml", tmp_path / "tool.yaml")
    doc = yaml.safe_load((CONFIGS / "cells" / "kr270.yaml").read_text())
    (tmp_path / "cell.yaml").write_text(yaml.safe_dump({**doc, "robot": "robot.yaml", "tool": "tool.yaml"}))
    return tmp_path


def spoil(path, change):
    doc = yaml.safe_load(path.read_text())
    change(doc)
    path.write_text(yaml.safe_dump(doc))


def one_line_error(capfd, argv) -> str:
    assert main([str(a) for a in argv]) == 2
    out, err = capfd.readouterr()
    assert err.count("\n") == 1 and err.startswith("error: ") and "Traceback" not in err, err
    return err


@pytest.mark.parametrize(
    "file, change, message",
    [
        ("cell.yaml", lambda d: d["stations"]["S1"].update(yaw_deg="abc"), r"stations\.S1\.yaw_deg: expected a number"),
        ("cell.yaml", lambda d: d.update(acceptance_deg="wide"), r"acceptance_deg: expected a number, got 'wide'"),
        ("cell.yaml", lambda d: d.update(stations=[1, 2]), r"stations .*: expected a mapping of keys, got \[1, 2\]"),
        ("cell.yaml", lambda d: d["box_mm"].update(min="low"), r"box_mm\.min: expected a list of 3 numbers"),
        ("robot.yaml", lambda d: d.update(joints=5), r"robot\.yaml: joints: expected a list, got 5"),
        ("robot.yaml", lambda d: d["joints"][1].update(limits_deg="all"), r"joints\[1\]\.limits_deg: expected a list"),
        ("tool.yaml", lambda d: d["points"]["P1"].update(xyz_mm=[1, "x", 3]), r"points\.P1\.xyz_mm\[1\]: expected a"),
    ],
)
def test_config_values_of_the_wrong_type(cell_dir, capfd, file, change, message):
    spoil(cell_dir / file, change)
    argv = ["simulate", "--cell", cell_dir / "cell.yaml", "--poses", 2, "--out", cell_dir / "t.csv"]
    err = one_line_error(capfd, argv)
    assert str(cell_dir / file) in err
    assert re.search(message, err), err
    assert not (cell_dir / "t.csv").exists()


@pytest.mark.parametrize("name", ["cell.yaml", "robot.yaml", "tool.yaml"])
def test_a_non_utf8_config_names_the_line(cell_dir, capfd, name):
    path = cell_dir / name
    path.write_bytes(path.read_bytes().replace(b"\n", "\n# K\xf6ln\n".encode("latin-1"), 1))  # line 2
    err = one_line_error(capfd, ["simulate", "--cell", cell_dir / "cell.yaml", "--out", cell_dir / "t.csv"])
    assert f"{path}: line 2: not UTF-8 text (byte 0xf6)" in err


@pytest.mark.parametrize("text", ["", "<robot name='r'><link name='a'/>", "not xml at all"])
def test_a_malformed_urdf_is_one_line_and_pinocchio_stays_quiet(cell_dir, capfd, text):
    (cell_dir / "r.urdf").write_text(text)
    spoil(cell_dir / "cell.yaml", lambda d: d.update(robot="r.urdf"))
    err = one_line_error(capfd, ["simulate", "--cell", cell_dir / "cell.yaml", "--out", cell_dir / "t.csv"])
    assert f"{cell_dir / 'r.urdf'}: " in err  # and nothing of urdfdom's own report on fd 1 or 2 (one_line_error)


@pytest.fixture(scope="module")
def model_json(tmp_path_factory):
    d = tmp_path_factory.mktemp("model")
    assert main(["simulate", "--cell", "kr270", "--poses", "8", "--seed", "3", "--out", str(d / "t.csv")]) == 0
    assert main(["identify", str(d / "t.csv"), "--cell", "kr270", "--out", str(d / "model.json")]) == 0
    (d / "targets.csv").write_text("q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg\n10,-60,80,10,40,0\n")
    return d


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda d: d["parameters"]["px2"].update(value=float("nan")), r"NaN is not JSON"),
        (lambda d: d["stations"]["S1"].update(translation_mm=[0, 0]), r"stations\.S1\.translation_mm: expected a list"),
        (lambda d: d.pop("tool_points"), r"model\.json: tool_points: missing"),
        (lambda d: d["parameters"]["dq2"].pop("value"), r"parameters\.dq2\.value: expected a number, got None"),
        (lambda d: d.update(extension={"cause": "gremlins"}), r"extension\.cause: 'gremlins' is not none or one of"),
        # found by test_cli_fuzz: a null weighting crashed the report with a traceback
        (lambda d: d.update(weighting=None), r"weighting: expected one of tracker, iid, got None"),
        # found by test_cli_fuzz: a negative, textual or missing half-width crashed the report's parameter plot
        (lambda d: d["parameters"]["dq2"].update(ci95=-100), r"parameters\.dq2\.ci95: a half-width cannot be negative"),
        (lambda d: d["parameters"]["dq2"].update(ci95="abc"), r"parameters\.dq2\.ci95: expected a number, got the str"),
        (lambda d: d["parameters"]["dq2"].pop("ci95"), r"parameters\.dq2\.ci95: expected a number, got None"),
        # found by test_cli_fuzz: a null covariance_order crashed the report's diagnosis, a null station half-width
        # its table of stations
        (lambda d: d.update(covariance_order=None), r"covariance_order: expected the list of the covariance's"),
        (
            lambda d: d["stations"]["S1"].update(ci95_translation_mm=None),
            r"stations\.S1\.ci95_translation_mm: expected a list of 3 numbers, got None",
        ),
        (
            lambda d: next(iter(d["tool_points"].values())).update(ci95_mm=[-1.0, 0.0, 0.0]),
            r"tool_points\.\w+\.ci95_mm: a half-width cannot be negative",
        ),
    ],
)
@pytest.mark.parametrize("command", ["predict", "compensate"])
def test_a_bad_model_json(model_json, tmp_path, capfd, change, message, command):
    doc = json.loads((model_json / "model.json").read_text())
    change(doc)
    bad = tmp_path / "model.json"
    bad.write_text(json.dumps(doc))  # json.dumps writes NaN as the non-standard token
    rows = model_json / ("t.csv" if command == "predict" else "targets.csv")
    err = one_line_error(capfd, [command, rows, "--model", bad, "--out", tmp_path / "out.csv"])
    assert str(bad) in err and re.search(message, err), err
    assert not (tmp_path / "out.csv").exists()


@pytest.mark.parametrize(
    "change, message",
    [  # found by test_cli_fuzz's random draws: each made the report (with a verdict) fail with a traceback
        (lambda d: d.update(covariance_order=None), r"covariance_order: expected the list of the covariance's"),
        (lambda d: d["stations"]["S1"].update(ci95_rotation_deg=None), r"stations\.S1\.ci95_rotation_deg: expected"),
    ],
)
def test_a_bad_model_json_in_a_report(model_json, tmp_path, capfd, change, message):
    verdict = model_json / "verdict.json"
    if not verdict.exists():
        assert main(["diagnose", str(model_json / "t.csv"), "--cell", "kr270", "--json", str(verdict)]) == 0
    doc = json.loads((model_json / "model.json").read_text())
    change(doc)
    bad = tmp_path / "model.json"
    bad.write_text(json.dumps(doc))
    argv = ["report", "--table", model_json / "t.csv", "--model", bad, "--verdict", verdict, "--out", tmp_path / "r"]
    err = one_line_error(capfd, argv)
    assert str(bad) in err and re.search(message, err), err


def test_non_utf8_plan_and_hardware_files(model_json, cell_dir, tmp_path, capfd):
    plan = tmp_path / "plan.json"
    plan.write_bytes('{"poses_deg": [], "note": "K\xf6ln"}'.encode("latin-1"))
    err = one_line_error(capfd, ["run", "--cell", "kr270", "--plan", plan, "--sim", "--session", tmp_path / "s"])
    assert f"{plan}: line 1: not UTF-8 text" in err
    hw = tmp_path / "hw.yaml"
    hw.write_bytes((CONFIGS / "hardware" / "example-cell.yaml").read_bytes() + b"# \xff\n")
    good_plan = tmp_path / "good.json"
    good_plan.write_text(json.dumps({"poses_deg": [[10, -60, 80, 10, 40, 0]], "repeat": 1}))
    err = one_line_error(
        capfd, ["run", "--cell", "kr270", "--plan", good_plan, "--hardware", hw, "--session", tmp_path / "s2"]
    )
    assert f"{hw}: line " in err and "not UTF-8 text (byte 0xff)" in err


GOOD_POSE = [10, -60, 80, 10, 40, 0]  # a kr270 pose inside its limits (the one test_non_utf8_plan_... runs)


@pytest.mark.parametrize(
    "plan, message",
    [  # issue 27, finding 8: 2.7 ran as 2 passes, true as 1, "2" as 2, string angles were taken
        ({"poses_deg": [GOOD_POSE], "repeat": 2.7}, r"plan: repeat: expected an integer, got 2\.7"),
        ({"poses_deg": [GOOD_POSE], "repeat": True}, r"plan: repeat: expected an integer, got True"),
        ({"poses_deg": [GOOD_POSE], "repeat": "2"}, r"plan: repeat: expected an integer, got '2'"),
        ({"poses_deg": [GOOD_POSE], "repeat": 0}, r"plan: repeat: expected an integer >= 1, got 0"),
        ({"poses_deg": [[str(v) for v in GOOD_POSE]]}, r"plan: poses_deg\[0\]\[0\]: expected a number, got the str"),
        ({"poses_deg": [GOOD_POSE, GOOD_POSE[:5]]}, r"plan: poses_deg\[1\]: expected 6 numbers as in row 0, got 5"),
        ({"poses_deg": [GOOD_POSE, 3]}, r"plan: poses_deg\[1\]: expected a list, got 3"),
    ],
)
def test_a_plan_of_the_wrong_types(tmp_path, capfd, plan, message):
    (tmp_path / "plan.json").write_text(json.dumps(plan))
    err = one_line_error(
        capfd, ["run", "--cell", "kr270", "--plan", tmp_path / "plan.json", "--sim", "--session", tmp_path / "s"]
    )
    assert re.search(message, err), err
    assert not (tmp_path / "s").exists()


def test_an_unknown_plan_param_is_refused_when_the_cell_loads(cell_dir, tmp_path, capfd):
    """Issue 27, finding 8: a cell's unknown plan_params name passed `simulate` silently."""
    spoil(cell_dir / "cell.yaml", lambda d: d.update(plan_params=["dq2", "gremlin"]))
    plan = tmp_path / "plan.json"
    plan.write_text(json.dumps({"poses_deg": [GOOD_POSE], "repeat": 1}))
    for argv in (
        ["simulate", "--cell", cell_dir / "cell.yaml", "--poses", 2, "--out", tmp_path / "t.csv"],
        ["plan", "--cell", cell_dir / "cell.yaml", "--json", tmp_path / "p.json"],
        ["run", "--cell", cell_dir / "cell.yaml", "--plan", plan, "--sim", "--session", tmp_path / "s"],
    ):
        err = one_line_error(capfd, argv)
        assert re.search(r"cell\.yaml: plan_params\[1\]: 'gremlin' is no parameter of robot", err), err


def nested(depth: int) -> str:
    """Arrays and objects nested `depth` deep (100k: issue 27, finding 8), valid JSON."""
    return '{"a": ' * (depth // 2) + "[" * (depth // 2) + "]" * (depth // 2) + "}" * (depth // 2)


def test_deeply_nested_json_is_one_line(model_json, tmp_path, capfd):
    deep = tmp_path / "deep.json"
    deep.write_text('{"poses_deg": ' + nested(100_000) + "}")
    message = f"{deep}: not a document of trackcal (arrays or objects nested too deeply)"
    report = ["report", "--table", model_json / "t.csv", "--cell", "kr270", "--out", tmp_path / "r"]
    for argv in (
        ["run", "--cell", "kr270", "--plan", deep, "--sim", "--session", tmp_path / "s"],
        ["predict", model_json / "t.csv", "--model", deep, "--out", tmp_path / "out.csv"],
        [*report, "--model", deep],
        [*report, "--model", model_json / "model.json", "--plan", deep],
        [*report, "--model", model_json / "model.json", "--verdict", deep],
    ):
        err = one_line_error(capfd, argv)
        assert message in err, err


@pytest.mark.parametrize(
    "poses, repeat, message",
    [
        ([["10"] * 6], 1, r"poses_deg\[0\]\[0\]: expected a number, got the string '10'"),
        ([GOOD_POSE], 2.5, r"repeat: expected an integer, got 2\.5"),
    ],
)
def test_the_plan_of_a_report_is_typed_json(model_json, tmp_path, capfd, poses, repeat, message):
    """Issue 27, finding 8: the report took string joint angles and a fractional repeat (the one it prints in
    the `trackcal plan` command it suggests)."""
    plan = tmp_path / "plan.json"
    plan.write_text(json.dumps({"poses_deg": poses, "repeat": repeat}))
    err = one_line_error(
        capfd,
        [
            "report",
            "--table",
            model_json / "t.csv",
            "--cell",
            "kr270",
            "--model",
            model_json / "model.json",
            "--plan",
            plan,
            "--out",
            tmp_path / "r",
        ],
    )
    assert str(plan) in err and re.search(message, err), err


@pytest.mark.parametrize(
    "extension, message",
    [  # issue 27, finding 8: these leaked "invalid literal for int() with base 10" and KeyError's "'unit'"
        (
            {"cause": "cyclic_error", "arcs": {"joint_x": {"from_deg": 0, "to_deg": 90}}},
            r"extension\.arcs: 'joint_x' is not joint_N",
        ),
        (
            {"cause": "cyclic_error", "parameters": {"s1_2": {"value": 1.0}}},
            r"extension\.parameters\.s1_2\.unit: expected one of deg",
        ),
        (
            {"cause": "cyclic_error", "parameters": {"s1_2": {"value": "1", "unit": "deg"}}},
            r"extension\.parameters\.s1_2\.value: expected a number, got the string '1'",
        ),
    ],
)
def test_a_bad_model_extension_in_words_of_the_file(model_json, tmp_path, capfd, extension, message):
    doc = json.loads((model_json / "model.json").read_text())
    bad = tmp_path / "model.json"
    bad.write_text(json.dumps({**doc, "extension": extension}))
    err = one_line_error(capfd, ["predict", model_json / "t.csv", "--model", bad, "--out", tmp_path / "out.csv"])
    assert str(bad) in err and re.search(message, err) and "invalid literal" not in err, err


@pytest.mark.parametrize(
    "command, text, message",
    [
        # a table saved by Excel in a locale with decimal commas: ';' between fields, ',' in numbers (issue 25)
        (
            ["identify", "T", "--cell", "kr270", "--out", "m.json"],
            "seq;t_s;pose;station;point;q1_deg;q2_deg;q3_deg;q4_deg;q5_deg;q6_deg;x_mm;y_mm;z_mm\n"
            "1;0,0;P1;S1;Q1;1,5;-80;80;0;40;5;1000,1;2;3\n",
            "this table is separated by ';' with decimal commas",
        ),
        (
            ["plan", "--cell", "kr270", "--evaluate", "T", "--json", "e.json"],
            "q1_deg;q2_deg;q3_deg;q4_deg;q5_deg;q6_deg\n1.5;-80;80;0;40;5\n",
            "this table is separated by ';', not by ','",
        ),
        (
            ["compensate", "T", "--model", "M", "--out", "c.csv"],
            "name\tq1_deg\tq2_deg\tq3_deg\tq4_deg\tq5_deg\tq6_deg\nHOME\t0\t-90\t90\t0\t0\t0\n",
            "separated by tabs",
        ),
    ],
)
def test_a_table_with_another_separator_is_named_as_such(model_json, tmp_path, capfd, command, text, message):
    table = tmp_path / "t.csv"
    table.write_text(text)
    err = one_line_error(capfd, [table if a == "T" else model_json / "model.json" if a == "M" else a for a in command])
    assert message in err and "row 1" in err and "joint columns" not in err, err
