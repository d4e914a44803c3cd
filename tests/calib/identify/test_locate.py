"""`trackcal locate`: a tracker station that moved, placed with the robot model held, from 3 points or k poses; then
`predict` works for it. A twin table whose station moved by a known transform recovers that transform within its
interval, and the held-out poses are predicted at the twin's truth within the noise."""

import json
import os
from pathlib import Path

import numpy as np
import pytest

from tests.helpers import ROOT, kr270_campaign
from trackcal.calib.doe.poses import random_poses
from trackcal.calib.identify.solver import Station
from trackcal.calib.io.table import MeasurementTable, read_table, write_table
from trackcal.calib.model.rigid import exp_so3
from trackcal.campaign.cli import main

# The known move of the tracker: 4 deg about a tilted axis and 0.3 m across, a tracker carried to another spot of
# the same cell (any rigid transform would do; this one keeps every point in front of the tracker).
MOVE_R = exp_so3(np.radians(4.0) * np.array([0.3, -0.2, 0.93]) / np.linalg.norm([0.3, -0.2, 0.93]))
MOVE_T = np.array([180.0, -240.0, 60.0])
POINTS = ("P1", "P2", "P3")


def two_sessions(d, kr270, seed: int = 5, effects: dict | None = None, extend: str = "none"):
    """(twin, folder, session 2's table, its noise-free positions): session 1 calibrates (identify, model m.json),
    session 2 is the same robot seen from station S1 moved by (MOVE_R, MOVE_T), renamed G, 3 points at each of 12
    new poses."""
    twin, table = kr270_campaign(kr270, seed=seed, n_poses=30, effects=effects or {})
    write_table(table, d / "s1.csv")
    assert main(["identify", str(d / "s1.csv"), "--cell", "kr270", "--extend", extend, "--out", str(d / "m.json")]) == 0
    s1 = twin.true_stations["S1"]
    twin.true_stations["G"] = Station(MOVE_R @ s1.rotation, MOVE_R @ s1.translation + MOVE_T)
    poses = np.round(np.degrees(random_poses(kr270, 12, np.random.default_rng(6))), 4)  # poses session 1 never saw
    rows = [(k, pt, np.array(q)) for k, q in enumerate(poses) for pt in POINTS]
    xyz = np.array([twin.measure(q, pt, "G", f"s2/{k}/{pt}") for k, pt, q in rows])
    s2 = MeasurementTable(
        seq=np.arange(1, len(rows) + 1),
        t_s=np.arange(len(rows), dtype=float),
        pose=[f"R{k + 1}" for k, _, _ in rows],
        station=["G"] * len(rows),
        point=[pt for _, pt, _ in rows],
        q_deg=np.array([q for _, _, q in rows]),
        xyz=xyz,
    )
    write_table(s2, d / "s2.csv")
    exact = np.array([twin.exact(q, pt, "G") for _, pt, q in rows])
    return twin, d, s2, exact


@pytest.fixture(scope="module")
def session(tmp_path_factory, kr270):
    return two_sessions(tmp_path_factory.mktemp("locate"), kr270)


def _recovered(doc: dict, name: str) -> None:
    """The located station equals the model's S1 moved by the known transform, within the 95 % intervals of both
    (the model's stations absorb what the robot's base and the first joint share, the same for S1 and the moved
    one, so the move between them is what a locate can be checked on)."""
    s1, g = doc["stations"]["S1"], doc["stations"][name]
    r_exp = MOVE_R @ np.array(s1["rotation"])
    t_exp = MOVE_R @ np.array(s1["translation_mm"]) + MOVE_T
    dr = np.array(g["rotation"]) @ r_exp.T  # Exp(w): the located station's rotation error, station frame
    w = np.degrees(0.5 * np.array([dr[2, 1] - dr[1, 2], dr[0, 2] - dr[2, 0], dr[1, 0] - dr[0, 1]]))
    v = np.array(g["translation_mm"]) - dr @ t_exp
    ci_v = np.hypot(g["ci95_translation_mm"], s1["ci95_translation_mm"])
    ci_w = np.hypot(g["ci95_rotation_deg"], s1["ci95_rotation_deg"])
    # each of the 6 components within its 95 % interval widened to ~3 sigma (1.5x): one component in 200 outside
    assert np.all(np.abs(v) <= 1.5 * ci_v), (v, ci_v)
    assert np.all(np.abs(w) <= 1.5 * ci_w), (w, ci_w)


def test_three_points_of_one_pose_locate_the_moved_station(session, capsys):
    _, d, s2, _ = session
    out = d / "m3.json"
    assert (
        main(["locate", "--model", str(d / "m.json"), "--table", str(d / "s2.csv"), "--poses", "1", "--out", str(out)])
        == 0
    )
    text = " ".join(capsys.readouterr().out.split())  # the console folds long lines
    assert "Station G located on 3 points of 1 pose(s)" in text and "noise floor" in text
    doc = json.loads(out.read_text())
    m = json.loads((d / "m.json").read_text())
    assert {k: v for k, v in doc.items() if k not in ("stations", "located", "digest")} == {
        k: v for k, v in m.items() if k not in ("stations", "digest")
    }  # the input model, every robot figure unchanged
    assert set(doc["stations"]) == {"S1", "S2", "G"} and doc["located"]["G"]["n_points"] == 3
    assert doc["located"]["G"]["poses"] == ["R1"]
    _recovered(doc, "G")


def test_k_poses_locate_and_predict_the_rest_at_the_twins_truth(session, capsys):
    twin, d, s2, exact = session
    out, rest = d / "m5.json", d / "rest.csv"
    assert (
        main(
            [
                "locate",
                "--model",
                str(d / "m.json"),
                "--table",
                str(d / "s2.csv"),
                "--poses",
                "5",
                "--out",
                str(out),
                "--predict-out",
                str(rest),
            ]
        )
        == 0
    )
    assert "held out" in capsys.readouterr().out
    doc = json.loads(out.read_text())
    assert doc["located"]["G"]["held_out"]["rows"] == 21 and doc["located"]["G"]["held_out"]["poses"] == 7
    _recovered(doc, "G")
    pred = read_table(rest)
    assert pred.pose == s2.pose[15:]
    floor = doc["located"]["G"]["noise_floor_mm"]
    # the held-out predictions against the twin's noise-free positions: what is left is the model's and the
    # located station's estimation error, each of the order of the tracker noise (AT901 model, ~0.013 mm per
    # coordinate here), so within 3 noise floors per coordinate
    err = pred.xyz - exact[15:]
    assert np.sqrt(np.mean(err**2)) < 3 * floor, np.sqrt(np.mean(err**2))
    # and predict itself now knows the station
    again = d / "again.csv"
    assert main(["predict", "--model", str(out), str(rest), "--out", str(again)]) == 0
    assert np.allclose(read_table(again).xyz, pred.xyz, atol=1e-4)


def test_predict_without_the_station_points_at_locate(session, capsys):
    _, d, _, _ = session
    assert main(["predict", "--model", str(d / "m.json"), str(d / "s2.csv"), "--out", str(d / "p.csv")]) == 2
    err = capsys.readouterr().err
    assert "unknown station 'G'" in err and "trackcal locate" in err and err.count("\n") == 1


def _rows(s2: MeasurementTable, idx: list[int], path) -> str:
    write_table(s2.subset(np.array(idx)), path)
    return str(path)


@pytest.mark.parametrize(
    "case, message",
    [
        ("two", "2 point(s) to locate it on; at least 3 non-collinear points"),
        ("collinear", "collinear"),
        ("columns", "expected joint columns q1_deg..q6_deg, found 5"),
        ("point", "unknown point id 'P9'"),
        ("predict_all", "nothing is left to predict"),
        ("predict_no_poses", "--predict-out needs --poses"),
        ("stations", "has stations G, H; say which one to locate"),
        ("no_station", "--station K: no such station"),
    ],
)
def test_mistakes_are_one_line(session, tmp_path, capsys, case, message):
    _, d, s2, _ = session
    model, out = str(d / "m.json"), str(tmp_path / "o.json")
    extra: list[str] = []
    if case == "two":
        table = _rows(s2, [0, 1], tmp_path / "t.csv")
    elif case == "collinear":  # two measurements of one point and one of another: three points on a line
        dup = s2.subset(np.array([0, 0, 1]))
        dup.seq = np.array([1, 2, 3])
        write_table(dup, tmp_path / "t.csv")
        table = str(tmp_path / "t.csv")
    elif case == "columns":
        text = (d / "s2.csv").read_text().replace("q6_deg", "a6")
        (tmp_path / "t.csv").write_text(text)
        table = str(tmp_path / "t.csv")
    elif case == "point":
        bad = s2.subset(np.arange(6))
        bad.point[4] = "P9"
        write_table(bad, tmp_path / "t.csv")
        table = str(tmp_path / "t.csv")
    elif case in ("stations", "no_station"):
        two = s2.subset(np.arange(9))
        two.station = ["G"] * 6 + ["H"] * 3
        write_table(two, tmp_path / "t.csv")
        table = str(tmp_path / "t.csv")
        extra = ["--station", "K"] if case == "no_station" else []
    else:
        table = str(d / "s2.csv")
        extra = ["--predict-out", str(tmp_path / "r.csv")] + (["--poses", "12"] if case == "predict_all" else [])
    assert main(["locate", "--model", model, "--table", table, "--out", out, *extra]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1, err
    assert not (tmp_path / "o.json").exists()


def test_a_model_with_an_extension_is_located_with_it(tmp_path, kr270, capsys):
    """A robot with gravity compliance (hidden at 0.05 mm, 4x the tracker noise, of what a geometric model cannot
    absorb): the model extended by joint_compliance is located and predicts with its extension, at the twin's truth
    within 3 noise floors; the geometric model of the same session, located the same way, does not."""
    errors = {}
    for extend in ("joint_compliance", "none"):
        d = tmp_path / extend
        d.mkdir()
        _, d, s2, exact = two_sessions(d, kr270, seed=7, effects={"joint_compliance": 0.05}, extend=extend)
        assert (
            main(
                [
                    "locate",
                    "--model",
                    str(d / "m.json"),
                    "--table",
                    str(d / "s2.csv"),
                    "--poses",
                    "5",
                    "--out",
                    str(d / "m5.json"),
                    "--predict-out",
                    str(d / "rest.csv"),
                ]
            )
            == 0
        )
        floor = json.loads((d / "m5.json").read_text())["located"]["G"]["noise_floor_mm"]
        errors[extend] = np.sqrt(np.mean((read_table(d / "rest.csv").xyz - exact[15:]) ** 2)) / floor
    capsys.readouterr()
    assert errors["joint_compliance"] < 3 < errors["none"], errors


def test_a_station_of_the_same_name_is_replaced_and_another_name_added(session, capsys):
    _, d, _, _ = session
    for name in ("S1", "G2"):
        out = d / f"as-{name}.json"
        assert (
            main(
                ["locate", "--model", str(d / "m.json"), "--table", str(d / "s2.csv"), "--as", name, "--out", str(out)]
            )
            == 0
        )
        doc, m = json.loads(out.read_text()), json.loads((d / "m.json").read_text())
        assert set(doc["stations"]) == set(m["stations"]) | {name}
        assert doc["stations"][name] != m["stations"].get(name)  # S1 replaced by the moved station
        assert doc["located"][name]["station_in_table"] == "G" and doc["located"][name]["n_points"] == 36
        # the TCP figure at the test pose is in S1's frame: it goes with the replaced S1, stays beside a new station
        assert m["test_pose"]["station"] == "S1"
        assert doc.get("test_pose") == (None if name == "S1" else m["test_pose"])
    assert "station replaced" in capsys.readouterr().out.split("G2")[0]


IPA = Path(os.environ.get("TRACKCAL_IPA_DATA") or ROOT.parent / "shared" / "data" / "ipa-robot-accuracy")


@pytest.mark.slow
@pytest.mark.skipif(not IPA.is_dir(), reason="IPA data set not present (TRACKCAL_IPA_DATA)")
def test_the_real_ur10_calibrated_on_b_predicts_d_from_a_station_located_on_10_poses(tmp_path, capsys):
    """Christianlandgraf/ipa-robot-accuracy (MIT; Landgraf et al., IEEE CASE 2021): calibrate on Series B, locate D's
    tracker on D's first 10 poses, predict D's other 622. The calibrated model must beat the nominal robot located
    the same way (the README's table: D held out, 1.118 mm nominal against 0.596 mm calibrated, with D's station
    located on all of D)."""
    b, dd = tmp_path / "b.csv", tmp_path / "d.csv"
    assert (
        main(["import", "ipa-ur10", str(IPA / "Series_B" / "measurements_joint_configurations.csv"), "--out", str(b)])
        == 0
    )
    assert (
        main(
            [
                "import",
                "ipa-ur10",
                str(IPA / "Series_D" / "measurements_iso_cubes.csv"),
                "--station",
                "D",
                "--out",
                str(dd),
            ]
        )
        == 0
    )
    held = {}
    params = {
        "calibrated": "px1,py1,phix1,dq2,px2,phix2,phiy2,dq3,px3,phix3,phiy3,dq4,px4,py4,phix4,dq5",
        "nominal": ",",
    }  # the README's $P; "," is no parameter: the nominal robot, station and point fitted
    for name, p in params.items():
        m = tmp_path / f"{name}.json"
        assert (
            main(["identify", str(b), "--cell", "ur10-ipa", "--weighting", "iid", "--params", p, "--out", str(m)]) == 0
        )
        out = tmp_path / f"{name}-on-d.json"
        assert main(["locate", "--model", str(m), "--table", str(dd), "--poses", "10", "--out", str(out)]) == 0
        held[name] = json.loads(out.read_text())["located"]["D"]["held_out"]
    capsys.readouterr()
    assert held["calibrated"]["rows"] == 622
    assert held["calibrated"]["dist_rms_mm"] < 0.8 * held["nominal"]["dist_rms_mm"], held
