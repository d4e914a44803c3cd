"""The grid parser of plain blocks against the general parser it stands in for: on any table, read with the grid
parser and read by the general parser alone give the same arrays, dtypes, strings and errors; plain tables are
read by the grid parser alone; its numbers are float()'s, bit for bit."""

from unittest import mock

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import trackcal.calib.io.table as table_mod
from trackcal.calib.io import csv_grid
from trackcal.calib.io.table import TableError, read_table

HEADER = ["seq", "t_s", "pose", "station", "point", "q1_deg", "q2_deg", "q3_deg", "x_mm", "y_mm", "z_mm"]
NUMERIC = [c for c in HEADER if c not in ("seq", "pose", "station", "point")]
XYZ = ("x_mm", "y_mm", "z_mm")


def plain_number(sign, whole, frac):
    return f"{sign}{whole}" + (f".{frac}" if frac else "")


# Plain decimals the grid parser always takes (up to 15 bytes after the sign); leading zeros, "-0", "+5" included.
PLAIN = st.builds(
    plain_number,
    st.sampled_from(["", "-", "+"]),
    st.text("0123456789", min_size=1, max_size=8),
    st.text("0123456789", max_size=6),
)
# Numbers float() reads that are not plain: the general parser's (exponents, spaces, a bare dot side, 17 digits).
OTHER = st.sampled_from(
    ["1e5", "-2.5E-3", " 7.25", "8 ", "5.", ".5", "-.5", "12345678901234567", "1.234567890123456789"]
)
NUMBER = st.one_of(PLAIN, PLAIN, PLAIN, OTHER)
# Plain coordinates a tracker measures: within 1 km (calib/io/table.py MAX_COORDINATE_MM; 6 whole digits)
PLAIN_XYZ = st.builds(
    plain_number,
    st.sampled_from(["", "-", "+"]),
    st.text("0123456789", min_size=1, max_size=6),
    st.text("0123456789", max_size=6),
)
PRINTABLE = "".join(chr(c) for c in range(0x21, 0x7F) if chr(c) not in '",')  # ASCII, no space, quote or comma
PLAIN_ID = st.text(PRINTABLE, min_size=1, max_size=20)
ANY = st.text(st.characters(blacklist_characters=',"\r\n\x00', blacklist_categories=("Cs",)), max_size=12)
ID = st.one_of(PLAIN_ID, PLAIN_ID, ANY, st.sampled_from([" Q1", "S 2 ", "Qé", "P\u00a0", "x" * 70, '"Q,1"']))
TEXT = st.one_of(ANY, st.sampled_from(['"a,b"', "x" * 70, ""]))


def same_table(a, b):
    for name in ("seq", "t_s", "q_deg", "xyz"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes(), name  # -0.0 too
    assert (a.pose, a.station, a.point, a.source) == (b.pose, b.station, b.point, b.source)
    assert list(a.extra) == list(b.extra)
    for name in a.extra:
        assert a.extra[name].dtype == b.extra[name].dtype and a.extra[name].tolist() == b.extra[name].tolist()


def general_only():
    return mock.patch.object(csv_grid, "split", return_value=None)


def outcome(path):
    try:
        return read_table(path)
    except TableError as exc:
        return str(exc)


@st.composite
def tables(draw, number=NUMBER, ident=ID, text=TEXT, xyz=None):
    n = draw(st.integers(1, 12))
    extras = draw(st.lists(st.sampled_from(["note", "temp_c"]), max_size=2, unique=True))
    seqs = draw(st.permutations(range(1, n + 1)))
    seq_text = st.sampled_from(["{}", "{}", "+{}", "00{}", "{}.0"]) if number is NUMBER else st.just("{}")
    rows = []
    for i in range(n):
        row = {c: draw(xyz if xyz is not None and c in XYZ else number) for c in NUMERIC}
        row["seq"] = draw(seq_text).format(seqs[i])
        row.update({c: draw(ident) for c in ("pose", "station", "point")})
        row.update({c: draw(text) for c in extras})
        rows.append(row)
    return [*HEADER, *extras], rows


def table_bytes(header, rows, crlf=False, last_newline=True):
    end = "\r\n" if crlf else "\n"
    text = end.join([",".join(header), *(",".join(r[c] for c in header) for r in rows)])
    return (text + (end if last_newline else "")).encode()


@settings(max_examples=100, deadline=None)
@given(table=tables(), block=st.integers(40, 1000), crlf=st.booleans(), last_newline=st.booleans())
def test_any_table_reads_the_same_with_and_without_the_grid(tmp_path_factory, table, block, crlf, last_newline):
    path = tmp_path_factory.mktemp("grid") / "t.csv"
    path.write_bytes(table_bytes(*table, crlf, last_newline))
    with mock.patch.object(table_mod, "BLOCK_BYTES", block):
        fast = outcome(path)
        with general_only():
            general = outcome(path)
    if isinstance(general, str):
        assert fast == general
    else:
        same_table(fast, general)


@settings(max_examples=60, deadline=None)
@given(table=tables(number=PLAIN, ident=PLAIN_ID, text=st.text(PRINTABLE + " ", max_size=12), xyz=PLAIN_XYZ))
def test_plain_tables_are_read_by_the_grid_alone(tmp_path_factory, table):
    path = tmp_path_factory.mktemp("plain") / "t.csv"
    path.write_bytes(table_bytes(*table))
    with mock.patch.object(table_mod._Columns, "add", side_effect=AssertionError("general parser used")):
        fast = read_table(path)
    with general_only():
        same_table(fast, read_table(path))


# Every kind of bad cell, put anywhere in a plain table: the same one-line error as the general parser gives.
BAD = {
    "q2_deg": ["abc", "1.2.3", "nan", "-inf", "inf", "1e400", "", " ", "--1", "+", "-", ".", "1,5", "0x10", "1_0"],
    "seq": ["7.5", "x", "", "1e300", "99999999999999999"],
    "station": ["", " ", "\t"],
    "x_mm": ["1000000.5", "-2000000", "1e300"],  # beyond 1 km from the tracker (MAX_COORDINATE_MM)
}


@settings(max_examples=100, deadline=None)
@given(
    table=tables(number=PLAIN, ident=PLAIN_ID, text=st.just("t"), xyz=PLAIN_XYZ),
    column=st.sampled_from(sorted(BAD)),
    data=st.data(),
    where=st.floats(0, 1, exclude_max=True),
    block=st.integers(40, 1000),
)
def test_a_bad_cell_gives_the_general_parsers_error(tmp_path_factory, table, column, data, where, block):
    header, rows = table
    bad = int(where * len(rows))
    rows[bad][column] = data.draw(st.sampled_from(BAD[column]))
    path = tmp_path_factory.mktemp("bad") / "t.csv"
    path.write_bytes(table_bytes(header, rows))
    with mock.patch.object(table_mod, "BLOCK_BYTES", block):
        fast = outcome(path)
        with general_only():
            general = outcome(path)
    assert isinstance(general, str) and fast == general and str(path) in fast and "\n" not in fast


def numbers(texts):
    grid = csv_grid.split(("\n".join(texts) + "\n").encode(), 1)
    return None if grid is None else grid.numbers(0)


@settings(max_examples=200, deadline=None)
@given(st.lists(PLAIN, min_size=1, max_size=20))
def test_plain_numbers_are_floats_bit_for_bit(texts):
    got = numbers(texts)
    assert got is not None
    assert got.tobytes() == np.array([float(t) for t in texts]).tobytes()


@pytest.mark.parametrize(
    "text, value",
    [
        ("9007199254740991", 2.0**53 - 1),  # the largest integer below 2**53: exact
        ("9007199254740.99", 9007199254740.99),  # 16 bytes with the dot, digits below 2**53: correctly rounded
        ("0.1", 0.1),
        ("-0", -0.0),
        ("0000000000000007", 7.0),
    ],
)
def test_plain_number_limits(text, value):
    got = numbers([text])
    assert got is not None and got.tobytes() == np.array([value]).tobytes()


@pytest.mark.parametrize("text", ["9007199254740993", "12345678901234567", "1e5", "5.", ".5", "-", "", " 1", "1.2.3"])
def test_numbers_past_the_plain_form_are_left_to_the_general_parser(text):
    assert numbers([text]) is None
