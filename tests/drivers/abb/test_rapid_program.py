"""The RAPID program of compensated joint targets (drivers/abb/program.py, `compensate --program` for an ABB cell):
RAPID's identifier rule, one CONST jointtarget and one MoveAbsJ ... fine per row, the notes of uncompensated rows."""

from __future__ import annotations

import pytest

from trackcal.drivers.abb.program import RapidError, check_name, target_names, texts


def test_a_module_of_absolute_joint_moves():
    notes = [None, "NOT COMPENSATED, its nominal target: out of range"]
    files = texts("calib_moves", [[1, 2, 3, 4, 5, 6], [0, -1, 2, 3, 4, 5]], 20, ["JP1", "JP2"], notes)
    text = files["calib_moves.mod"].decode("ascii")
    lines = text.split("\r\n")
    assert lines[0] == "MODULE calib_moves" and lines[-2] == "ENDMODULE" and lines[-1] == ""
    assert (
        "  CONST jointtarget JP1 := [[1.0000,2.0000,3.0000,4.0000,5.0000,6.0000],[9E+09,9E+09,9E+09,9E+09,9E+09,"
        "9E+09]];" in lines
    )
    assert lines.index("    VelSet 20, 5000;") < lines.index("    MoveAbsJ JP1, v5000, fine, tool0;")
    note = lines.index("    ! JP2: NOT COMPENSATED, its nominal target: out of range")
    assert lines[note + 1] == "    MoveAbsJ JP2, v5000, fine, tool0;"
    assert "1 NOT compensated" in lines[1]


def test_target_names_are_rapid_identifiers_unique_without_regard_to_case():
    names = target_names(["P 1", "p_1", "", "x" * 40], 4)
    assert names[0] == "JP_1" and names[1] == "Jp_1_2" and names[2] == "J3" and len(names[3]) == 32
    assert len({n.upper() for n in names}) == 4


@pytest.mark.parametrize("name", ["9moves", "a b", "x" * 33, ""])
def test_a_name_rapid_refuses_is_refused(name):
    # RAPID identifiers: a letter first, then letters, digits, underscores; at most 32 characters
    with pytest.raises(RapidError):
        check_name(name)


@pytest.mark.parametrize(
    ("q", "speed", "labels"), [([[0] * 5], 10, None), ([[0] * 6], 0, None), ([[0] * 6] * 2, 10, ["A", "a"])]
)
def test_bad_rows_speeds_and_duplicate_names_are_refused(q, speed, labels):
    with pytest.raises(RapidError):
        texts("p", q, speed, labels)
