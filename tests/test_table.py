"""The measurement table: round trip and one clear line for each kind of bad input."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from calib.table import TableError, read_table, write_table
from tests.conftest import kr270_campaign

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
    assert back.extra["temp_c"] == table.extra["temp_c"]


@pytest.mark.parametrize(
    "text, message",
    [
        (HEADER.replace(",z_mm", "") + "\n" + ROW.rsplit(",", 1)[0], r"row 1: missing column\(s\) z_mm"),
        (HEADER + "\n" + ROW.replace("1000.5", "nan"), r"row 2: column x_mm: not a finite number"),
        (HEADER + "\n" + ROW.replace("-60", "abc"), r"row 2: column q2_deg: not a number: 'abc'"),
        (HEADER + "\n" + ROW + ",7", r"row 2: 15 fields, the header has 14"),
        (HEADER + "\n" + ROW.replace("S1", ""), r"row 2: column station: empty id"),
        (HEADER + "\n" + ROW + "\n" + ROW.replace("1,", "2.5,", 1), r"row 3: column seq: not an integer"),
        (HEADER + "\n", r"no data rows"),
        ("", r"empty file"),
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


def test_predict_input_without_xyz(tmp_path):
    path = write(tmp_path, HEADER.rsplit(",x_mm", 1)[0] + "\n" + ROW.rsplit(",1000.5", 1)[0] + "\n")
    t = read_table(path, require_xyz=False)
    assert t.xyz is None and t.q_deg.shape == (1, 6)


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
