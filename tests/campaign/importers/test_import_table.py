"""`trackcal import table FILE --map MAP`: another tool's export read through a map. A table written in a random
layout, units, separator and decimal mark reads back through the map equal to the original within float rounding;
every bad cell is named by row and column; a file with another separator says which one."""

import csv
import io
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.helpers import ROOT
from trackcal.calib.io.table import read_table
from trackcal.campaign.cli import main
from trackcal.campaign.importers.table_map import ImportMapError, import_table, load_map

EXAMPLES = ROOT / "docs" / "examples"
# the file's units per degree and per mm: rad = deg * pi / 180; the inch is 25.4 mm exactly (NIST SP 811, B.6)
PER_DEG = {"deg": 1.0, "rad": np.pi / 180.0}
PER_MM = {"mm": 1.0, "m": 1e-3, "in": 1.0 / 25.4}


@st.composite
def exports(draw):
    """(the table as lists, the map as a dict, the export's text)."""
    n_joints = draw(st.integers(2, 7))
    n_poses = draw(st.integers(1, 5))
    points = [f"P{k + 1}" for k in range(draw(st.integers(1, 3)))]
    layout = draw(st.sampled_from(["point_rows", "pose_rows"]))
    ju, lu = draw(st.sampled_from(list(PER_DEG))), draw(st.sampled_from(list(PER_MM)))
    sep = draw(st.sampled_from([",", ";", "\t", "|"]))
    dec = draw(st.sampled_from(["."] if sep == "," else [".", ","]))
    header = draw(st.booleans())
    by_name = header and draw(st.booleans())
    base = draw(st.sampled_from([0, 1]))
    with_pose, with_time, with_station = draw(st.booleans()), draw(st.booleans()), draw(st.booleans())
    angle = st.floats(-180, 180, allow_nan=False).map(lambda v: round(v, 4))
    length = st.floats(-5000, 5000, allow_nan=False).map(lambda v: round(v, 4))
    poses = []
    for k in range(n_poses):
        q = draw(st.lists(angle, min_size=n_joints, max_size=n_joints))
        q[0] = -170.0 + 10.0 * k  # consecutive poses differ (the map's rule for files without pose ids)
        poses.append(
            (
                f"Q{k + 1}",
                float(k * 30),
                draw(st.sampled_from(["S1", "T2"])) if with_station else "T1",
                q,
                {p: draw(st.lists(length, min_size=3, max_size=3)) for p in points},
            )
        )
    # the file's columns: names and their order
    names = (
        ([("pose", "Pose ID")] if with_pose else [])
        + ([("time", "Time")] if with_time else [])
        + ([("station", "Stn")] if with_station else [])
        + [(f"q{j}", f"J{j + 1}") for j in range(n_joints)]
    )
    if layout == "point_rows":
        names += [("point", "Target"), ("x", "X"), ("y", "Y"), ("z", "Z")]
    else:
        names += [(f"{p}{a}", f"{p} {a.upper()}") for p in points for a in "xyz"]
    order = draw(st.permutations(names))
    pos = {key: i for i, (key, _) in enumerate(order)}

    def ref(key):
        return dict(order)[key] if by_name else pos[key] + base

    def num(v, factor):
        text = repr(float(v) * factor)
        return text.replace(".", ",") if dec == "," else text

    lines = [[label for _, label in order]] if header else []
    for pid, t, sid, q, xyz in poses:
        cells = {"pose": pid, "time": num(t, 1.0), "station": sid}
        cells.update({f"q{j}": num(v, PER_DEG[ju]) for j, v in enumerate(q)})
        if layout == "point_rows":
            for p in points:
                row = {**cells, "point": p, **{a: num(v, PER_MM[lu]) for a, v in zip("xyz", xyz[p], strict=True)}}
                lines.append([row[k] for k, _ in order])
        else:
            cells.update({f"{p}{a}": num(v, PER_MM[lu]) for p in points for a, v in zip("xyz", xyz[p], strict=True)})
            lines.append([cells[k] for k, _ in order])
    out = io.StringIO()
    csv.writer(out, delimiter=sep, lineterminator="\n").writerows(lines)
    columns = {"joints": [ref(f"q{j}") for j in range(n_joints)]}
    columns.update({k: ref(k) for k in ("pose", "time", "station") if k in pos})
    doc = {
        "separator": sep,
        "decimal": dec,
        "header": header,
        "layout": layout,
        "units": {"joints": ju, "length": lu},
        "columns": columns,
    }
    if not by_name:
        doc["positions"] = f"{base}-based"
    if layout == "point_rows":
        columns.update({"point": ref("point"), "xyz": [ref("x"), ref("y"), ref("z")]})
    else:
        doc["points"] = {p: [ref(f"{p}{a}") for a in "xyz"] for p in points}
    expected = [(pid, t, sid, p, q, xyz[p]) for pid, t, sid, q, xyz in poses for p in points]
    return expected, doc, out.getvalue(), with_pose, with_time


@settings(max_examples=60, deadline=None)
@given(exports())
def test_a_table_in_any_layout_reads_back_through_its_map(tmp_path_factory, export):
    expected, doc, text, with_pose, with_time = export
    d = tmp_path_factory.mktemp("rt")
    (d / "map.yaml").write_text(yaml.safe_dump(doc))
    (d / "export.txt").write_text(text)
    table = import_table(d / "export.txt", load_map(d / "map.yaml")).table
    assert len(table) == len(expected)
    assert table.station == [e[2] for e in expected] and table.point == [e[3] for e in expected]
    np.testing.assert_allclose(table.q_deg, [e[4] for e in expected], rtol=1e-12, atol=1e-9)  # unit round trip
    np.testing.assert_allclose(table.xyz, [e[5] for e in expected], rtol=1e-12, atol=1e-9)
    if with_pose:
        assert table.pose == [e[0] for e in expected]
    else:  # sequential ids, one per pose
        assert len(set(table.pose)) == len({e[0] for e in expected})
    if with_time:
        np.testing.assert_allclose(table.t_s, [e[1] for e in expected], atol=1e-12)


def _write(tmp_path: Path, text: str, doc: dict) -> tuple[str, str]:
    (tmp_path / "e.csv").write_text(text)
    (tmp_path / "m.yaml").write_text(yaml.safe_dump(doc))
    return str(tmp_path / "e.csv"), str(tmp_path / "m.yaml")


MAP = {"columns": {"joints": ["A1", "A2"], "xyz": ["X", "Y", "Z"]}}


@pytest.mark.parametrize(
    "text, doc, message",
    [
        ("A1,A2,X,Y,Z\n1,2,3,4,5\n1,2,3,x4,5\n", MAP, "row 3: column 'Y' (1-based position 4): not a number: 'x4'"),
        ("A1,A2,X,Y,Z\n1,nan,3,4,5\n", MAP, "row 2: column 'A2' (1-based position 2): not a finite number: 'nan'"),
        ("A1,A2,X,Y,Z\n1,2,3,4,inf\n", MAP, "row 2: column 'Z' (1-based position 5): not a finite number: 'inf'"),
        ("A1,A2,X,Y,Z\n1,2,3,4,nan\n", MAP, "point P1: 1 of 1 rows have no reading (NaN or empty), more than 50%"),
        ("A1;A2;X;Y;Z\n1,5;2;3;4;5\n", MAP, "row 1 has 1 column; the file looks ';'-separated: set separator: ';'"),
        (
            "A1;A2;X;Y;Z\n1,5;2;3;4;5\n",
            {**MAP, "separator": ";"},
            "row 2: column 'A1' (1-based position 1): not a number: '1,5' (a decimal comma? set decimal: ',')",
        ),
        (
            "1\t2\t3\t4\t5\n",
            {"header": False, "positions": "1-based", "columns": {"joints": [1, 2], "xyz": [3, 4, 5]}},
            "row 1 has 1 column; the file looks tab-separated: set separator: '\\t'",
        ),
        (
            "1,2,3,4\n",
            {"header": False, "positions": "0-based", "columns": {"joints": [0, 1], "xyz": [2, 3, 4]}},
            "row 1 has 4 columns, the map needs 5",
        ),
        (
            "A1,A2,X,Y,Z\n1,2,3,4,5\n",
            {"columns": {"joints": [1, 2], "xyz": [3, 4, 5]}},
            "positions: missing; a column is given by position",
        ),
        ("A1,A2,X,Y,Q\n1,2,3,4,5\n", MAP, "no column 'Z'"),
        ("A1,A2,X,Y,Z\n1,2,3,4,5\n", {**MAP, "units": {"length": "ft"}}, "units.length: expected mm, m, in, got 'ft'"),
        ("A1,A2,X,Y,Z\n1,2,3,4,5\n", {**MAP, "colums": {}}, "colums: unknown key"),
    ],
)
def test_every_mistake_names_its_row_and_column(tmp_path, capsys, text, doc, message):
    export, mapping = _write(tmp_path, text, doc)
    assert main(["import", "table", export, "--map", mapping, "--out", str(tmp_path / "t.csv")]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1, err
    assert not (tmp_path / "t.csv").exists()


def test_a_semicolon_file_with_the_default_map_says_so(tmp_path):
    export, mapping = _write(tmp_path, "A1;A2;X;Y;Z\n1,5;2;3;4;5\n", MAP)
    with pytest.raises(ImportMapError, match=r"looks ';'-separated: set separator: ';'"):
        import_table(export, load_map(mapping))


@pytest.mark.parametrize(
    "name, poses, rows, points", [("three-smr", 4, 12, ["P1", "P2", "P3"]), ("one-reflector", 5, 11, ["P1"])]
)
def test_the_documented_examples_import(tmp_path, capsys, name, poses, rows, points):
    out = tmp_path / "t.csv"
    assert (
        main(
            [
                "import",
                "table",
                str(EXAMPLES / f"{name}-export.csv"),
                "--map",
                str(EXAMPLES / f"{name}.map.yaml"),
                "--out",
                str(out),
            ]
        )
        == 0
    )
    # an export names no instrument: the import says which model identify will assume (issue 23)
    assert "the Leica AT901 when the cell names none" in " ".join(capsys.readouterr().out.split())
    t = read_table(out)
    assert (len(set(t.pose)), len(t), sorted(set(t.point))) == (poses, rows, points)
    # both files hold the same twin campaign's first pose seen from S1, P1 at the same place: metres and radians
    # (one-reflector) and millimetres and degrees with decimal commas (three-smr) agree to their printed digits
    assert t.station[0] == "S1" and np.allclose(t.xyz[0], [4687.2158, 336.6955, 1113.6881], atol=1e-4)
    assert np.allclose(t.q_deg[0], [-149.1663, -110.6625, 102.3377, 29.5783, -101.4678, -24.0743], atol=1e-4)


def test_one_file_per_point_shares_poses_by_their_joints(tmp_path):
    """Three files, one per reflector, the same robot program (the same joints) in each, without pose ids: the
    rows with the same joints are one pose across the files, and each file's name is its point."""
    q = [[10, 20], [30, 40], [50, 60]]
    files = []
    for k, name in enumerate(("P1", "P2", "P3")):
        order = q if k != 1 else q[::-1]  # one file measured the poses in the reverse order
        text = "J1;J2;X;Y;Z\n" + "".join(f"{a};{b};{k},5;{a}.0;{b}\n".replace(".0", ",0") for a, b in order)
        (tmp_path / f"{name}.csv").write_text(text)
        files.append(str(tmp_path / f"{name}.csv"))
    m = {
        "separator": ";",
        "decimal": ",",
        "point": "{file}",
        "columns": {"joints": ["J1", "J2"], "xyz": ["X", "Y", "Z"]},
    }
    (tmp_path / "m.yaml").write_text(yaml.safe_dump(m))
    out = tmp_path / "t.csv"
    assert main(["import", "table", *files, "--map", str(tmp_path / "m.yaml"), "--out", str(out)]) == 0
    t = read_table(out)
    assert t.point == ["P1"] * 3 + ["P2"] * 3 + ["P3"] * 3
    assert t.pose == ["P0001", "P0002", "P0003", "P0003", "P0002", "P0001", "P0001", "P0002", "P0003"]
    assert np.allclose(t.xyz[:, 0], [0.5] * 3 + [1.5] * 3 + [2.5] * 3)
    assert np.allclose(t.xyz[3], [1.5, 50, 60])
