"""issue 36: the data as published. `trackcal import table` reads MATLAB .mat files, joins a joints file with one
positions file per reflector by row, skips rows where the tracker had no reading (NaN) and says how many, and writes
a seeded pose-level train/test split. What it cannot read is one line, never a traceback."""

from pathlib import Path

import numpy as np
import pytest
import scipy.io
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from trackcal.calib.io.table import read_table
from trackcal.campaign.cli import main

N = 6
Q = np.round(np.linspace(-60, 60, N)[:, None] + np.arange(6)[None, :] * 7.5, 4)  # distinct joints per row (deg)
XYZ = {
    p: np.round(np.array([3000.0 + 10 * k, 200.0 * k, 900.0])[None, :] + np.arange(N)[:, None] * [1.5, 2.5, 3.5], 4)
    for k, p in enumerate(("P1", "P2", "P3"))
}
JOINTS = [f"q(:,{j + 1})" for j in range(6)]


def run(tmp_path: Path, capsys, files: list[str], doc: dict, *extra: str) -> tuple[int, str, str]:
    (tmp_path / "map.yaml").write_text(yaml.safe_dump(doc))
    code = main(
        ["import", "table", *files, "--map", str(tmp_path / "map.yaml"), "--out", str(tmp_path / "t.csv"), *extra]
    )
    out, err = capsys.readouterr()
    return code, out, err


def test_a_mat_file_with_one_row_per_pose(tmp_path, capsys):
    """Joints N x 6 and one N x 3 matrix per reflector in one .mat: each matrix column is a map column."""
    scipy.io.savemat(tmp_path / "e.mat", {"q": Q, **XYZ})
    doc = {
        "layout": "pose_rows",
        "columns": {"joints": JOINTS},
        "points": {p: [f"{p}(:,{a})" for a in (1, 2, 3)] for p in XYZ},
    }
    code, out, err = run(tmp_path, capsys, [str(tmp_path / "e.mat")], doc)
    assert code == 0, err
    t = read_table(tmp_path / "t.csv")
    assert len(t) == 3 * N and len(set(t.pose)) == N
    np.testing.assert_allclose(t.q_deg[::3], Q)
    np.testing.assert_allclose(t.xyz[1::3], XYZ["P2"])


def test_a_joints_file_and_one_file_per_reflector_joined_by_row(tmp_path, capsys):
    """joints.mat holds q (N x 6); P1.mat holds X, Y, Z vectors, P2.csv the same columns as text: row k of each is
    measured at row k of the joints file, and each file's name is its point."""
    scipy.io.savemat(tmp_path / "joints.mat", {"q": Q})
    scipy.io.savemat(tmp_path / "P1.mat", {"X": XYZ["P1"][:, 0], "Y": XYZ["P1"][:, 1], "Z": XYZ["P1"][:, 2]})
    (tmp_path / "P2.csv").write_text("X,Y,Z\n" + "".join(",".join(map(repr, r)) + "\n" for r in XYZ["P2"].tolist()))
    doc = {"point": "{file}", "columns": {"joints": JOINTS, "xyz": ["X", "Y", "Z"]}}
    code, out, err = run(
        tmp_path,
        capsys,
        [str(tmp_path / "P1.mat"), str(tmp_path / "P2.csv")],
        doc,
        "--joints",
        str(tmp_path / "joints.mat"),
    )
    assert code == 0, err
    t = read_table(tmp_path / "t.csv")
    assert t.point == ["P1"] * N + ["P2"] * N
    assert t.pose[:N] == t.pose[N:] and len(set(t.pose)) == N  # the same joints: the same pose
    np.testing.assert_allclose(t.q_deg, np.vstack([Q, Q]))
    np.testing.assert_allclose(t.xyz, np.vstack([XYZ["P1"], XYZ["P2"]]))


def test_rows_without_a_reading_are_skipped_and_counted(tmp_path, capsys):
    p1 = XYZ["P1"].copy()
    p1[[1, 4]] = np.nan  # the tracker lost the beam at two poses
    scipy.io.savemat(tmp_path / "joints.mat", {"q": Q})
    scipy.io.savemat(tmp_path / "P1.mat", {"xyz": p1})
    doc = {"point": "{file}", "positions": "1-based", "columns": {"joints": JOINTS, "xyz": [1, 2, 3]}}
    code, out, err = run(tmp_path, capsys, [str(tmp_path / "P1.mat")], doc, "--joints", str(tmp_path / "joints.mat"))
    assert code == 0, err
    assert "skipped 2 rows without a reading (NaN or empty x, y, z): P1 2 of 6" in out
    t = read_table(tmp_path / "t.csv")
    np.testing.assert_allclose(t.xyz, XYZ["P1"][[0, 2, 3, 5]])
    np.testing.assert_allclose(t.q_deg, Q[[0, 2, 3, 5]])


def _v73(path: Path) -> None:
    """A file with the header of a MATLAB v7.3 (HDF5) file: version 0x0200 at byte 124 (MAT-file format, The
    MathWorks: the header's version field; v7.3 files are HDF5 with this 128-byte header)."""
    scipy.io.savemat(path, {"q": Q})
    data = bytearray(path.read_bytes())
    data[124:126] = b"\x00\x02" if data[126:128] == b"IM" else b"\x02\x00"
    path.write_bytes(bytes(data))


@pytest.mark.parametrize(
    "make, files, doc, joints, message",
    [
        (
            lambda d: scipy.io.savemat(d / "e.mat", {"a": np.ones((3, 2))}),
            ["e.mat"],
            {"columns": {"joints": JOINTS, "xyz": ["X", "Y", "Z"]}},
            None,
            "e.mat: no variable 'q(:,1)' (the map",
        ),
        (
            lambda d: scipy.io.savemat(d / "e.mat", {"a": np.ones((3, 2))}),
            ["e.mat"],
            {"columns": {"joints": JOINTS, "xyz": ["X", "Y", "Z"]}},
            None,
            "the file holds a (3x2 double)",
        ),
        (
            lambda d: scipy.io.savemat(d / "e.mat", {"q": Q, "X": np.ones(N)}),
            ["e.mat"],
            {"columns": {"joints": ["q"], "xyz": ["X", "X", "X"]}},
            None,
            "'q' is a matrix: name its columns 'q(:,1)' ... 'q(:,6)'",
        ),
        (
            lambda d: scipy.io.savemat(
                d / "e.mat", {"q": Q, "X": np.ones(N - 1), "Y": np.ones(N - 1), "Z": np.ones(N - 1)}
            ),
            ["e.mat"],
            {"columns": {"joints": JOINTS, "xyz": ["X", "Y", "Z"]}},
            None,
            "the map's columns have different row counts",
        ),
        (
            lambda d: (
                scipy.io.savemat(d / "j.mat", {"q": Q}),
                scipy.io.savemat(d / "P1.mat", {"X": np.ones(N - 1), "Y": np.ones(N - 1), "Z": np.ones(N - 1)}),
            ),
            ["P1.mat"],
            {"columns": {"joints": JOINTS, "xyz": ["X", "Y", "Z"]}},
            "j.mat",
            "P1.mat: 5 rows, the joints file",
        ),
        (
            lambda d: (d / "e.mat").write_bytes(b"not a mat file at all\n" * 20),
            ["e.mat"],
            {"columns": {"joints": JOINTS, "xyz": ["X", "Y", "Z"]}},
            None,
            "e.mat: not a MATLAB .mat file that can be read",
        ),
        (
            lambda d: _v73(d / "e.mat"),
            ["e.mat"],
            {"columns": {"joints": JOINTS, "xyz": ["X", "Y", "Z"]}},
            None,
            "a MATLAB v7.3 (HDF5) file",
        ),
        (
            lambda d: scipy.io.savemat(
                d / "e.mat", {"q": Q, "X": np.r_[np.nan * np.ones(4), np.ones(2)], "Y": np.ones(N), "Z": np.ones(N)}
            ),
            ["e.mat"],
            {"columns": {"joints": JOINTS, "xyz": ["X", "Y", "Z"]}},
            None,
            "point P1: 4 of 6 rows have no reading (NaN or empty), more than 50%",
        ),
    ],
)
def test_what_cannot_be_read_is_one_line(tmp_path, capsys, make, files, doc, joints, message):
    make(tmp_path)
    extra = ["--joints", str(tmp_path / joints)] if joints else []
    code, _, err = run(tmp_path, capsys, [str(tmp_path / f) for f in files], doc, *extra)
    assert code == 2 and message in err and err.count("\n") == 1, err
    assert not (tmp_path / "t.csv").exists()


def test_holdout_splits_by_pose_seeded(tmp_path, capsys):
    """Every row of a pose goes to one side; the share is round(fraction x poses); the same seed draws the same
    split, the union is the whole table."""
    scipy.io.savemat(tmp_path / "e.mat", {"q": Q, **XYZ})
    doc = {
        "layout": "pose_rows",
        "columns": {"joints": JOINTS},
        "points": {p: [f"{p}(:,{a})" for a in (1, 2, 3)] for p in XYZ},
    }
    splits = []
    for seed in ("4", "4", "5"):
        test = tmp_path / f"test{len(splits)}.csv"
        code, out, err = run(
            tmp_path,
            capsys,
            [str(tmp_path / "e.mat")],
            doc,
            "--holdout",
            "0.34",
            "--seed",
            seed,
            "--test-out",
            str(test),
        )
        assert code == 0, err
        train, held = read_table(tmp_path / "t.csv"), read_table(test)
        assert not set(train.pose) & set(held.pose)
        assert len(set(held.pose)) == 2 and len(set(train.pose)) == N - 2  # round(0.34 x 6) = 2
        assert len(train) + len(held) == 3 * N
        splits.append(sorted(set(held.pose)))
    assert splits[0] == splits[1]
    code, _, err = run(
        tmp_path, capsys, [str(tmp_path / "e.mat")], doc, "--holdout", "1.5", "--test-out", str(tmp_path / "x.csv")
    )
    assert code == 2 and "strictly between 0 and 1" in err and err.count("\n") == 1
    code, _, err = run(tmp_path, capsys, [str(tmp_path / "e.mat")], doc, "--holdout", "0.2")
    assert code == 2 and "--test-out" in err and err.count("\n") == 1


names = st.sampled_from(["q", "X", "Y", "Z", "xyz", "P1", "t"])
matrices = hnp.arrays(
    np.float64,
    hnp.array_shapes(min_dims=1, max_dims=3, max_side=7),
    elements=st.one_of(st.floats(allow_nan=True, allow_infinity=True, width=64), st.just(np.nan)),
)
contents = st.dictionaries(
    names, st.one_of(matrices, st.text(max_size=5), st.lists(st.text(max_size=3), max_size=4)), max_size=4
)
maps = st.sampled_from(
    [
        {"columns": {"joints": ["q(:,1)", "q(:,2)"], "xyz": ["X", "Y", "Z"]}},
        {"positions": "1-based", "columns": {"joints": [1, 2], "xyz": [3, 4, 5]}},
        {"layout": "pose_rows", "columns": {"joints": ["q"]}, "points": {"P1": ["P1(:,1)", "P1(:,2)", "P1(:,3)"]}},
        {"columns": {"joints": ["t"], "xyz": ["xyz(:,1)", "xyz(:,2)", "xyz(:,3)"]}},
    ]
)


finite = st.floats(-1e4, 1e4, allow_nan=False)


@st.composite
def readable(draw):
    """A .mat the first map reads: q (n x 2) and X, Y, Z (n) finite, at most n // 2 rows of X NaN."""
    n = draw(st.integers(1, 6))
    cols = {k: draw(hnp.arrays(np.float64, n, elements=finite)) for k in ("X", "Y", "Z")}
    cols["X"][: draw(st.integers(0, n // 2))] = np.nan
    return {"q": draw(hnp.arrays(np.float64, (n, 2), elements=finite)), **cols}, MAPS[0], False


MAPS = maps.elements


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.one_of(readable(), st.tuples(contents, maps, st.booleans())))
def test_any_mat_file_gives_a_table_or_one_line(tmp_path, capsys, case):
    """Whatever a .mat holds (vectors, matrices, 3-D arrays, NaN, inf, strings, nothing) and however the map names
    it: exit 0 and a table, or exit 2 and one line; a file holding what the map names is read."""
    variables, doc, joined = case
    path = tmp_path / "e.mat"
    scipy.io.savemat(path, variables)
    (tmp_path / "t.csv").unlink(missing_ok=True)
    extra = ["--joints", str(path)] if joined else []
    code, _, err = run(tmp_path, capsys, [str(path)], doc, *extra)
    assert (code, err) == (0, "") or (code == 2 and err.count("\n") == 1 and err.startswith("error: ")), err
    assert (tmp_path / "t.csv").exists() == (code == 0)
    if doc is MAPS[0] and set(variables) == {"q", "X", "Y", "Z"} and not joined:
        assert code == 0, err
