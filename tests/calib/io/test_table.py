"""The measurement table: round trip, one clear line for each kind of bad input, streaming in blocks, and
writes that leave the previous file or none."""

import dataclasses
import errno
import os
from unittest import mock

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import trackcal.calib.io.files as files_mod
import trackcal.calib.io.table as table_mod
from tests.helpers import kr270_campaign
from trackcal.calib.io.table import TableError, read_table, write_table

HEADER = "seq,t_s,pose,station,point,q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,x_mm,y_mm,z_mm"
ROW = "1,0.0,Q1,S1,P1,10,-60,80,10,40,0,1000.5,200.25,-300.125"


def write(tmp_path, text, name="t.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_round_trip_keeps_values_and_extra_columns(tmp_path, kr270):
    _, table = kr270_campaign(kr270, seed=2)
    table.extra["temp_c"] = [f"{20 + 0.01 * i:.2f}" for i in range(len(table))]
    path = tmp_path / "t.csv"
    write_table(table, path)
    back = read_table(path)
    assert back.pose == table.pose and back.station == table.station and back.point == table.point
    np.testing.assert_allclose(back.q_deg, table.q_deg, atol=5e-5)  # written to 1e-4 deg
    np.testing.assert_allclose(back.xyz, table.xyz, atol=5e-5)  # written to 1e-4 mm
    assert back.extra["temp_c"].tolist() == list(table.extra["temp_c"])
    assert back.subset(np.array([2, 0])).extra["temp_c"].tolist() == [table.extra["temp_c"][2], "20.00"]


@settings(deadline=None, max_examples=30)
@given(picks=st.lists(st.integers(0, 11), min_size=0, max_size=15), ordered=st.booleans())
def test_subset_takes_the_rows_in_order_however_they_are_picked(picks, ordered):
    # increasing rows take the text columns by a mask (issue 41), others by indices: the same rows either way
    n = 12
    table = table_mod.MeasurementTable(
        np.arange(n),
        np.arange(n) * 1.5,
        [f"P{i}" for i in range(n)],
        ["S"] * n,
        ["A", "B", "C"] * 4,
        np.arange(6.0 * n).reshape(n, 6),
        np.arange(3.0 * n).reshape(n, 3),
        {"temp_c": [f"{20 + i}.5" for i in range(n)]},
    )
    rows = np.array(sorted(set(picks)) if ordered else picks, dtype=int)
    sub = table.subset(rows)
    assert sub.pose == [f"P{i}" for i in rows] and sub.point == [table.point[i] for i in rows]
    assert sub.extra["temp_c"].tolist() == [f"{20 + i}.5" for i in rows]
    assert np.array_equal(sub.q_deg, table.q_deg[rows]) and np.array_equal(sub.seq, rows)


@pytest.mark.parametrize(
    "text, message",
    [
        (HEADER.replace(",z_mm", "") + "\n" + ROW.rsplit(",", 1)[0], r"row 1: missing column\(s\) z_mm"),
        (HEADER + "\n" + ROW.replace("1000.5", "nan"), r"row 2: column x_mm: not a finite number: 'nan'"),
        (HEADER + "\n" + ROW.replace("1000.5", "1e400"), r"row 2: column x_mm: not a finite number: '1e400'"),
        # 1e300 mm and 2 km: no tracker measures there (calib/io/table.py MAX_COORDINATE_MM, 1 km; the AT901-LR
        # reaches 80 m); 1e300 made the fit's numerics overflow and ended in "points are collinear"
        (HEADER + "\n" + ROW.replace("1000.5", "1e300"), r"row 2: column x_mm: 1e300 mm is beyond 1 km from the"),
        (HEADER + "\n" + ROW.replace("-300.125", "-2000000"), r"row 2: column z_mm: -2000000 mm is beyond 1 km"),
        (HEADER + "\n" + ROW.replace("-60", "abc"), r"row 2: column q2_deg: not a number: 'abc'"),
        (HEADER + "\n" + ROW.replace("-60", ""), r"row 2: column q2_deg: not a number: ''"),
        (HEADER + "\n" + ROW + ",7", r"row 2: 15 fields, the header has 14"),
        (HEADER + "\n" + ROW.rsplit(",", 1)[0], r"row 2: 13 fields, the header has 14"),
        (HEADER + "\n" + ROW.replace("S1", ""), r"row 2: column station: empty id"),
        (HEADER + "\n" + ROW + "\n" + ROW.replace("1,", "2.5,", 1), r"row 3: column seq: not an integer: '2.5'"),
        (
            HEADER + "\n" + ROW + "\n" + ROW.replace("1,", "2,", 1) + "\n" + ROW,
            r"row 4: column seq: 1 already used in row 2",
        ),
        (HEADER + "\n" + ROW + "\n\n" + ROW.replace("1,", "2,", 1), r"row 3: empty row"),
        (HEADER + "\n" + ROW + "\n \n" + ROW.replace("1,", "2,", 1), r"row 3: empty row"),
        (HEADER + "\n", r"no data rows"),
        (HEADER + "\n\n\n", r"no data rows"),
        ("", r"empty file"),
        ("seq,seq\n1,2\n", r"row 1: duplicate column names"),
    ],
)
def test_bad_tables_name_file_row_and_column(tmp_path, text, message):
    path = write(tmp_path, text)
    with pytest.raises(TableError, match=message) as exc:
        read_table(path)
    assert str(path) in str(exc.value) and "\n" not in str(exc.value)


def test_missing_file_is_a_clear_error(tmp_path):
    with pytest.raises(TableError, match="cannot read"):
        read_table(tmp_path / "nope.csv")


def test_excel_bom_crlf_and_trailing_blank_rows_are_accepted(tmp_path):
    path = tmp_path / "t.csv"
    path.write_bytes(b"\xef\xbb\xbf" + f"{HEADER}\r\n{ROW}\r\n\r\n  \r\n".encode())
    t = read_table(path)
    assert len(t) == 1 and t.seq.tolist() == [1] and t.xyz[0].tolist() == [1000.5, 200.25, -300.125]


def test_non_utf8_names_the_row(tmp_path):
    path = tmp_path / "t.csv"
    latin1 = ROW.replace("Q1", "Qé")  # an editor that saved as Latin-1
    path.write_bytes(f"{HEADER}\n{ROW}\n{latin1}\n".encode("latin-1"))
    with pytest.raises(TableError, match=r"row 3: not UTF-8 text \(byte 0xe9\)"):
        read_table(path)


def test_joint_limits_name_row_and_column(tmp_path, kr270):
    # configs/robots/kr270.yaml: paper Table 4, A6 in [-180, 180] deg
    seven_joints = dataclasses.replace(kr270.chain, joints=(*kr270.chain.joints, kr270.chain.joints[0]))
    ok = ROW.replace(",0,1000.5", ",180.9,1000.5")  # within the 1 deg margin of A6's 180 deg
    bad = ROW.replace("1,", "2,", 1).replace(",0,1000.5", ",1e300,1000.5")  # issue 12
    assert len(read_table(write(tmp_path, f"{HEADER}\n{ok}\n"), chain=kr270.chain)) == 1
    with pytest.raises(TableError, match=r"row 3: column q6_deg: 1e\+300 deg is outside the joint's limits"):
        read_table(write(tmp_path, f"{HEADER}\n{ok}\n{bad}\n"), chain=kr270.chain)
    with pytest.raises(TableError, match=r"row 1: expected joint columns q1_deg..q7_deg, found 6"):
        read_table(write(tmp_path, f"{HEADER}\n{ok}\n"), chain=seven_joints)


def test_too_large_a_table_is_refused_with_the_limit(tmp_path):
    rows = [ROW.replace("1,", f"{i},", 1) for i in range(1, 12)]
    path = write(tmp_path, HEADER + "\n" + "\n".join(rows) + "\n")
    with (
        mock.patch.object(table_mod, "MAX_CELLS", 140),
        pytest.raises(TableError, match=r"more than 10 rows, the limit"),
    ):
        read_table(path)
    rows[1] += "," + "9" * 200
    path = write(tmp_path, HEADER + "\n" + "\n".join(rows) + "\n")
    with (
        mock.patch.object(table_mod, "BLOCK_BYTES", 16),
        mock.patch.object(table_mod, "MAX_LINE_BYTES", 100),
        pytest.raises(TableError, match=r"row 3: longer than 100 bytes"),
    ):
        read_table(path)


def test_predict_input_without_xyz(tmp_path):
    path = write(tmp_path, HEADER.rsplit(",x_mm", 1)[0] + "\n" + ROW.rsplit(",1000.5", 1)[0] + "\n")
    t = read_table(path, require_xyz=False)
    assert t.xyz is None and t.q_deg.shape == (1, 6)


def test_quoted_fields_and_extra_columns(tmp_path):
    path = write(tmp_path, f'{HEADER},note\n{ROW.replace("Q1", chr(34) + "Q,1" + chr(34))}," a, b "\n')
    t = read_table(path)
    assert t.pose == ["Q,1"] and t.extra["note"].tolist() == [" a, b "]


# One defect in an otherwise good table, anywhere, with blocks as small as a row: the error names its row and
# column; no defect: the values are the ones written.
DEFECTS = {
    "none": None,
    "junk": ("q3_deg", "1.2.3", "not a number: '1.2.3'"),
    "inf": ("y_mm", "-inf", "not a finite number: '-inf'"),
    "empty id": ("point", " ", "empty id"),
    "fraction seq": ("seq", "7.5", "not an integer: '7.5'"),
    "limit": ("q2_deg", "146.5", "outside the joint's limits"),  # A2 allows [-145, 0], plus 1 deg
}


@settings(max_examples=60, deadline=None)
@given(
    n=st.integers(1, 40),
    block=st.integers(60, 3000),
    kind=st.sampled_from([*DEFECTS, "extra field", "duplicate seq", "latin-1", "blank row"]),
    where=st.floats(0, 1, exclude_max=True),
    values=st.lists(st.floats(-100, 0, allow_subnormal=False), min_size=1, max_size=40),
)
def test_one_defect_is_named_wherever_the_blocks_fall(tmp_path_factory, kr270, n, block, kind, where, values):
    path = tmp_path_factory.mktemp("defect") / "t.csv"
    cols = HEADER.split(",")
    q = np.resize([float(f"{v:.4f}") for v in values], (n, 6))  # inside every KR-270 limit
    rows = [
        [str(i + 1), f"{0.5 * i:.3f}", f"Q{i // 3}", "S1", f"P{i % 3}", *(f"{v:.4f}" for v in q[i]), "1.5", "-2", "3e2"]
        for i in range(n)
    ]
    bad = int(where * n)  # data row index; file row bad + 2
    message = None
    if kind in DEFECTS and DEFECTS[kind]:
        col, value, what = DEFECTS[kind]
        rows[bad][cols.index(col)] = value
        message = f"row {bad + 2}: column {col}: .*{what}"
    lines = [",".join(r) for r in rows]
    if kind == "extra field":
        lines[bad] += ",9"
        message = f"row {bad + 2}: 15 fields, the header has 14"
    if kind == "duplicate seq" and n > 1:
        bad = max(bad, 1)
        lines[bad] = lines[bad].replace(f"{bad + 1},", "1,", 1)
        message = f"row {bad + 2}: column seq: 1 already used in row 2"
    if kind == "blank row" and bad < n - 1:
        lines[bad] = ""
        message = f"row {bad + 2}: empty row"
    data = (HEADER + "\n" + "\n".join(lines) + "\n").encode()
    if kind == "latin-1":
        data = data.replace(f"\n{lines[bad]}".encode(), f"\n{lines[bad]}".encode().replace(b"S1", b"S\xb9"), 1)
        message = f"row {bad + 2}: not UTF-8 text"
    path.write_bytes(data)
    with mock.patch.object(table_mod, "BLOCK_BYTES", block):
        if message is None:
            t = read_table(path, chain=kr270.chain)
            assert t.seq.tolist() == list(range(1, n + 1))
            np.testing.assert_array_equal(t.q_deg, q)  # exact: the same decimal text, correctly rounded both ways
            assert t.pose == [r[2] for r in rows]
        else:
            with pytest.raises(TableError, match=message) as exc:
                read_table(path, chain=kr270.chain)
            assert str(exc.value).startswith(f"{path}: ") and "\n" not in str(exc.value)


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=400))
def test_arbitrary_bytes_give_a_table_error_or_a_table(tmp_path_factory, data):
    path = tmp_path_factory.mktemp("fuzz") / "t.csv"
    path.write_bytes(data)
    try:
        table = read_table(path)
    except TableError as exc:
        assert str(path) in str(exc) and "\n" not in str(exc)
    else:
        assert len(table) > 0 and np.all(np.isfinite(table.q_deg))


@settings(max_examples=100, deadline=None)
@given(st.lists(st.sampled_from(["1", "-2.5", "x", "", '"', '"a,b"', "nan", " ", "\t", "S1", "1e5"]), max_size=60))
def test_arbitrary_cells_give_a_table_error_or_a_table(tmp_path_factory, cells):
    path = tmp_path_factory.mktemp("cells") / "t.csv"
    body = "\n".join(",".join(cells[i : i + 14]) for i in range(0, len(cells), 14))
    path.write_text(HEADER + "\n" + body + "\n")
    try:
        table = read_table(path)
    except TableError as exc:
        assert str(path) in str(exc) and "\n" not in str(exc)
    else:
        assert len(table) > 0 and np.all(np.isfinite(table.xyz)) and all(table.pose)


class FullDisk:
    """A file that takes `room` bytes, then fails as a full disk does."""

    def __init__(self, fh, room: int):
        self.fh, self.room = fh, room

    def write(self, data):
        if len(data) > self.room:
            self.fh.write(data[: self.room])
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        self.room -= len(data)
        return self.fh.write(data)

    def __getattr__(self, name):
        return getattr(self.fh, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return self.fh.__exit__(*exc)


@pytest.mark.parametrize("room", [0, 100, 5000])
def test_a_full_disk_mid_write_leaves_the_previous_file(tmp_path, kr270, room):
    _, table = kr270_campaign(kr270, seed=2)
    path = tmp_path / "t.csv"
    path.write_text("previous\n")
    real = os.fdopen
    with (
        mock.patch.object(files_mod.os, "fdopen", lambda *a, **k: FullDisk(real(*a, **k), room)),
        pytest.raises(OSError, match="No space left"),
    ):
        write_table(table, path)
    assert path.read_text() == "previous\n" and os.listdir(tmp_path) == ["t.csv"]
    write_table(table, tmp_path / "new.csv")
    with mock.patch.object(files_mod.os, "fsync", side_effect=OSError(errno.EIO, "I/O error")), pytest.raises(OSError):
        write_table(table, path)  # the data may not be on the disk: the rename must not happen
    assert path.read_text() == "previous\n" and sorted(os.listdir(tmp_path)) == ["new.csv", "t.csv"]


@pytest.mark.parametrize("quote", ["", '"'])  # a quoted cell sends the block to the general parser
def test_long_ids_and_text_are_kept(tmp_path, quote):
    pose, note = "pose_0001_station_A", "x" * 40  # past the 15 bytes numpy stores inline in a string
    rows = [ROW.replace("Q1", pose).replace("1,", f"{i},", 1) + f",{quote}{note}{quote}" for i in range(1, 4)]
    t = read_table(write(tmp_path, f"{HEADER},note\n" + "\n".join(rows) + "\n"))
    assert t.pose == [pose] * 3 and t.extra["note"].tolist() == [note] * 3
