"""The KRL program reader (drivers/kuka/krl_reader.py): poses from the Euler definition, frames from the cell's
$config.dat and the program, status and turn, the renderer, byte-identical round trips, one-line errors.

Numbers come from the sample programs written for the project (configs/programs/krc2, krc4) or from programs written
here; expected poses are built in the test from KUKA's A, B, C definition (Rz(A) Ry(B) Rx(C), RoboDK-API
Matlab/Pose_2_KUKA.m) with scipy's intrinsic "ZYX" rotations, not with the reader's own helpers."""

import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from tests.helpers import ROOT
from trackcal.drivers.families import program_readers
from trackcal.drivers.kuka.krl_reader import read_krl
from trackcal.drivers.kuka.krl_values import status_turn
from trackcal.drivers.program_text import ProgramReadError

SAMPLES = ROOT / "configs" / "programs"
ERROR_LINE = re.compile(r"^[^\n:]+:\d+: [^\n]+$")  # file:line: what was expected, on one line


def _sample(folder: str, config: bool = True) -> dict[str, str]:
    paths = sorted(Path(SAMPLES, folder).iterdir())
    return {p.name: p.read_bytes().decode("latin-1") for p in paths if config or p.name != "$config.dat"}


def _kuka(x, y, z, a, b, c) -> np.ndarray:
    """4 x 4 of a KUKA frame: intrinsic Z-Y'-X'' rotations by A, B, C (degrees), then the translation (mm)."""
    out = np.eye(4)
    out[:3, :3] = Rotation.from_euler("ZYX", [a, b, c], degrees=True).as_matrix()
    out[:3, 3] = [x, y, z]
    return out


def _program(src_body: str, dat_body: str = "", eol: str = "\r\n") -> dict[str, str]:
    src = ["DEF T( )", *src_body.strip("\n").split("\n"), "END"]
    dat = ["DEFDAT T PUBLIC", *[ln for ln in dat_body.strip("\n").split("\n") if ln], "ENDDAT"]
    return {"T.src": eol.join(src) + eol, "T.dat": eol.join(dat) + eol}


def _by_name(program, name: str):
    return next(t for t in program.targets if t.name == name)


def test_the_krc2_family_reads_src_files():
    assert program_readers()[".src"] is read_krl


def test_e6pos_pose_is_kukas_zyx_euler():
    files = _program(
        "PTP XP1\nPTP XP2",
        "DECL E6POS XP1={X 100.0,Y -20.0,Z 300.0,A 90.0,B 0.0,C 180.0,S 2,T 3}\n"
        "DECL E6POS XP2={X 1.5,Y 2.5,Z -3.5,A 30.0,B 20.0,C 10.0,S 2,T 3}",
    )
    program = read_krl(files)
    # Rz(90) Rx(180) by hand: x' = y, y' = x, z' = -z
    hand = np.array([[0, 1, 0, 100.0], [1, 0, 0, -20.0], [0, 0, -1, 300.0], [0, 0, 0, 1]])
    np.testing.assert_allclose(_by_name(program, "XP1").value, hand, atol=1e-12)
    np.testing.assert_allclose(_by_name(program, "XP2").value, _kuka(1.5, 2.5, -3.5, 30, 20, 10), atol=1e-12)
    assert _by_name(program, "XP1").config == (2, 3)
    assert _by_name(program, "XP1").motion == "PTP" and not _by_name(program, "XP1").joint


def test_krc2_sample_frames_from_config_and_program():
    program = read_krl(_sample("krc2"))
    p1 = _by_name(program, "XP1")  # FDAT FP1: TOOL_NO 1, BASE_NO 1 of the sample's $config.dat
    np.testing.assert_allclose(p1.base, _kuka(1500.0, -500.0, 400.0, 90.0, 0.0, 0.0), atol=1e-12)
    np.testing.assert_allclose(p1.tool, _kuka(0.0, 0.0, 200.0, 0.0, 0.0, 0.0), atol=1e-12)
    np.testing.assert_allclose(p1.value, _kuka(120.5, -35.25, 310.0, 30.0, 0.0, 180.0), atol=1e-12)
    # S/T: the KR-270 configuration that reaches it within its limits (tests/integration/test_filter_samples.py)
    assert p1.config == (2, 3) and p1.file == "PALLET.dat"
    for name in ("XP3", "XP4"):  # CIRC's auxiliary and end point, S and T written as bit patterns
        assert _by_name(program, name).motion == "CIRC" and _by_name(program, name).config == (0b010, 0b000011)
    place = [t for t in program.targets if t.file == "PALLET.src" and t.motion == "LIN"]
    assert len(place) == 2  # the inline LINs after $TOOL=TOOL_DATA[2] and $BASE={...} set directly
    for t in place:
        np.testing.assert_allclose(t.base, _kuka(2100.0, 650.0, 180.0, 90.0, 0.0, 0.0), atol=1e-12)
        np.testing.assert_allclose(t.tool, _kuka(0.0, 45.0, 185.5, 0.0, -15.0, 0.0), atol=1e-12)
        assert t.config == (0b010, 0b101010)
    joints = {t.name: t for t in program.targets if t.joint}
    np.testing.assert_allclose(joints["XPREPLACE"].value, [62.5, -75.0, 98.25, 0.0, 66.75, -12.5])
    assert joints["XHOME"].file == "$config.dat" and joints["XHOME"].motion == "PTP"
    assert "HOME" not in joints  # $config.dat's AXIS HOME: no move of the program uses it


def test_krc4_sample_fdat_bas_and_loop_elements():
    program = read_krl(_sample("krc4"))
    spindle, brush = _kuka(85.0, 0.0, 310.25, 0.0, 30.0, 0.0), _kuka(-40.0, 12.5, 275.0, 90.0, 0.0, 0.0)
    casting = _kuka(1650.0, -220.0, 735.5, 180.0, 0.0, 0.0)
    for name in ("XP1", "XP2", "XP3", "XP4"):  # FDAT_ACT: TOOL_NO 3, BASE_NO 2
        np.testing.assert_allclose(_by_name(program, name).tool, spindle, atol=1e-12)
        np.testing.assert_allclose(_by_name(program, name).base, casting, atol=1e-12)
    for name in ("XEDGE[1]", "XEDGE[2]", "XEDGE[3]", "XEDGE_END"):  # BAS(#TOOL,4), BAS(#BASE,2); LIN XEDGE[I]
        t = _by_name(program, name)
        np.testing.assert_allclose(t.tool, brush, atol=1e-12)
        np.testing.assert_allclose(t.base, casting, atol=1e-12)
        assert t.motion == "LIN"
    rel = [t for t in program.targets if t.motion == "LIN_REL"]
    assert len(rel) == 1 and not rel[0].accepts(np.zeros(6))  # relative: listed, never filterable


def test_spline_with_clause_and_bas_frames():
    dat = (
        "DECL FRAME TOOL_DATA[16]\nTOOL_DATA[2]={X 0.0,Y 0.0,Z 150.0,A 0.0,B 0.0,C 0.0}\n"
        "DECL FRAME BASE_DATA[32]\nBASE_DATA[5]={X 10.0,Y 20.0,Z 30.0,A 0.0,B 0.0,C 90.0}\n"
        "DECL FDAT FP1={TOOL_NO 2,BASE_NO 5,IPO_FRAME #BASE}\n"
        "DECL E6POS XP1={X 1.0,Y 2.0,Z 3.0,A 0.0,B 0.0,C 0.0,S 2,T 0}"
    )
    program = read_krl(_program("SPTP XP1 WITH $TOOL = STOOL2(FP1), $BASE = SBASE(FP1.BASE_NO)", dat))
    np.testing.assert_allclose(program.targets[0].base, _kuka(10.0, 20.0, 30.0, 0.0, 0.0, 90.0), atol=1e-12)
    np.testing.assert_allclose(program.targets[0].tool, _kuka(0.0, 0.0, 150.0, 0.0, 0.0, 0.0), atol=1e-12)


def test_no_frame_set_means_nullframe_and_flange():
    program = read_krl(_program("LIN XP1", "DECL POS XP1={X 1.0,Y 2.0,Z 3.0,A 0.0,B 0.0,C 0.0}"))
    np.testing.assert_array_equal(program.targets[0].base, np.eye(4))
    np.testing.assert_array_equal(program.targets[0].tool, np.eye(4))
    assert program.targets[0].config == (-1, -1) and program.targets[0].accepts(np.array([-5.0, 3, 4, -6, 7, 8]))


@pytest.mark.parametrize(
    ("src", "config", "expected"),
    [
        ("BAS(#BASE,3)\nLIN XP1", False, r"T\.src:3: XP1's LIN: its base is BASE_DATA\[3\], which the given files"),
        ("FDAT_ACT=FP9\nPTP XP1", False, r"T\.src:3: .*FDAT_ACT = FP9 \(line 2\), not in the given files"),
        ("$BASE=BASE_DATA[1]\nLIN XP1\n$BASE=BASE_DATA[2]\nLIN XP1", True, r"T\.src:5: .*and at line 3 .*for both"),
        ("$IPO_MODE=#TCP\nLIN XP1", True, r"T\.src:3: .*external tool"),
        ("$BASE=MAKE_BASE(2)\nLIN XP1", True, r"T\.src:3: .*MAKE_BASE .*cannot evaluate"),
    ],
)
def test_a_target_in_an_unknown_or_ambiguous_frame_is_refused(src, config, expected):
    dat = "DECL E6POS XP1={X 1.0,Y 2.0,Z 3.0,A 0.0,B 0.0,C 0.0,S 2,T 0}"
    files = _program(src, dat)
    if config:
        files["$config.dat"] = (
            "DEFDAT $CONFIG\r\nDECL FRAME BASE_DATA[32]\r\n"
            "BASE_DATA[1]={X 1.0,Y 0.0,Z 0.0,A 0.0,B 0.0,C 0.0}\r\n"
            "BASE_DATA[2]={X 2.0,Y 0.0,Z 0.0,A 0.0,B 0.0,C 0.0}\r\nENDDAT\r\n"
        )
    with pytest.raises(ProgramReadError, match=expected) as err:
        read_krl(files)
    assert ERROR_LINE.match(str(err.value))


def test_joint_targets_need_no_frame():
    program = read_krl(_program("BAS(#BASE,3)\nPTP XA", "DECL E6AXIS XA={A1 1.0,A2 -2.0,A3 3.0,A4 4.0,A5 5.0,A6 6.0}"))
    assert program.targets[0].joint and program.targets[0].accepts(np.zeros(6))


# --- status and turn (krl_values docstring: robot-forum.com thread 13092, ISG "Status & Turn") ---------------------
HOME = [0.0, -90.0, 90.0, 0.0, 45.0, 0.0]  # upper arm up, forearm forward, wrist bent: basic area, A3 > phi, A5 > 0


@pytest.mark.parametrize(
    ("s", "t", "q", "ok", "why"),
    [
        (None, 0b000101, [-10, 5, -30, 0, 20, 0], True, "T bits 0 and 2: A1 and A3 negative, the others not"),
        (None, 0b000101, [10, 5, -30, 0, 20, 0], False, "T bit 0 set but A1 positive"),
        (None, 0b000000, [0, 0, 0, 0, 0, 0], True, "an axis at exactly 0 deg counts as positive (bit clear)"),
        (None, 0b100000, [0, 0, 0, 0, 0, -0.001], True, "T bit 5: A6 just below 0"),
        (2, None, HOME, True, "S 'B010': basic area, A3 >= phi, A5 in [0, 180)"),
        (6, None, HOME, False, "S bit 2 set needs A5 in [-180, 0) or >= 180; A5 = 45"),
        (6, None, [0, -90, 90, 0, -45, 0], True, "S bit 2 set, A5 = -45"),
        (6, None, [0, -90, 90, 0, 190, 0], True, "S bit 2 set, A5 = 190 >= 180"),
        (2, None, [0, -90, 90, 0, -190, 0], True, "A5 = -190 < -180: bit 2 clear"),
        (2, None, [0, -30, -60, 0, 45, 0], False, "S bit 1 set needs A3 >= phi; A3 = -60 is beyond any offset's phi"),
        (0, None, [0, -150, -60, 0, 45, 0], True, "A3 = -60: bit 1 clear"),
        (0, None, [0, -90, 5, 0, 45, 0], True, "A3 = 5 deg: within phi's band, bit 1 not decided from joints"),
        (2, None, [0, -90, 5, 0, 45, 0], True, "the same, the other bit 1"),
        (3, None, HOME, False, "S bit 0 (overhead) but both arm links point forward: the wrist is in front of A1"),
        (1, None, [0, -150, -60, 0, 45, 0], True, "upper arm back and up, forearm back: overhead possible"),
    ],
)
def test_status_turn_acceptance(s, t, q, ok, why):
    assert status_turn(s, t)(np.array(q, dtype=float)) is ok, why


@given(st.lists(st.floats(-350, 350).filter(lambda v: abs(v) > 1e-9), min_size=6, max_size=6), st.integers(0, 5))
def test_turn_is_the_signs_of_the_axes(q, flip):
    # T's definition: bit i set exactly when A(i+1) < 0 (robot-forum.com thread 13092; ISG "Status & Turn")
    t = sum(1 << i for i, v in enumerate(q) if v < 0)
    assert status_turn(None, t)(np.array(q))
    assert not status_turn(None, t ^ (1 << flip))(np.array(q))


def test_status_turn_read_from_the_program():
    program = read_krl(_program("PTP XP1", "DECL E6POS XP1={X 1.0,Y 2.0,Z 3.0,A 0.0,B 0.0,C 0.0,S 'B110',T 'B010010'}"))
    accepts = program.targets[0].accepts
    # A2, A5 < 0 (T bits 1, 4), A5 < 0 (S bit 2), A3 >= phi (S bit 1)
    assert accepts(np.array([0.0, -90, 90, 0, -45, 0]))
    assert not accepts(np.array([0.0, -90, 90, 0, 45, 0]))


# --- render -----------------------------------------------------------------------------------------------------
def test_render_keeps_every_byte_but_the_position_members():
    program = read_krl(_sample("krc2"))
    p1 = _by_name(program, "XP1")
    assert p1.render(p1.value) == (
        "{X 120.5000,Y -35.2500,Z 310.0000,A 30.00000,B 0.00000,C 180.00000,S 2,T 3,"
        "E1 0.0,E2 0.0,E3 0.0,E4 0.0,E5 0.0,E6 0.0}"
    )
    xa = _by_name(program, "XPREPLACE")
    assert xa.render(xa.value + 0.5) == (
        "{A1 63.00000,A2 -74.50000,A3 98.75000,A4 0.50000,A5 67.25000,A6 -12.00000,"
        "E1 0.0,E2 0.0,E3 0.0,E4 0.0,E5 0.0,E6 0.0}"
    )


def test_render_keeps_more_decimals_and_the_spacing():
    files = _program("LIN {X  1.123456, Y 2,Z 3.0,A 10.0,B 0.0,C -0.0}", "")
    t = read_krl(files).targets[0]
    assert t.render(t.value) == "{X  1.123456, Y 2.0000,Z 3.0000,A 10.00000,B 0.00000,C 0.00000}"


@given(st.floats(-5, 5), st.floats(-5, 5), st.floats(-5, 5), st.floats(-0.2, 0.2), st.floats(-0.2, 0.2))
@settings(max_examples=20, deadline=None)
def test_a_corrected_value_reads_back(dx, dy, dz, da, db):
    files = _sample("krc4")
    program = read_krl(files)
    index = [i for i, t in enumerate(program.targets) if t.name == "XP3"][0]
    moved = program.targets[index].value @ _kuka(dx, dy, dz, da, db, 0.0)
    again = read_krl(program.write({index: moved}, {}))
    t = _by_name(again, "XP3")
    np.testing.assert_allclose(t.value[:3, 3], moved[:3, 3], atol=1e-4)  # 4 decimals of mm
    np.testing.assert_allclose(t.value[:3, :3], moved[:3, :3], atol=1e-6)  # 5 decimals of deg: < 1e-7 rad
    text = again.files["DEBURR.dat"]
    assert text[t.start : t.end].endswith(",S 2,T 3,E1 0.0,E2 0.0,E3 0.0,E4 0.0,E5 0.0,E6 0.0}")


def test_render_at_b_90_keeps_a():
    t = read_krl(_program("LIN {X 0.0,Y 0.0,Z 0.0,A 25.0,B 90.0,C 40.0}")).targets[0]
    # at B = 90 deg only C - A is defined (gimbal lock): A stays as written, C follows
    assert t.render(t.value) == "{X 0.0000,Y 0.0000,Z 0.0000,A 25.00000,B 90.00000,C 40.00000}"


# --- round trip and errors --------------------------------------------------------------------------------------
@pytest.mark.parametrize("folder", ["krc2", "krc4"])
def test_samples_round_trip_byte_identical(folder):
    files = _sample(folder)
    assert "\r\n" in files[next(iter(files))]  # CR LF, as the KUKA editor writes
    assert read_krl(files).write({}, {}) == files


NUMBER = st.decimals(-3000, 3000, places=3, allow_nan=False, allow_infinity=False).map(str)


@st.composite
def programs(draw):
    """A generated program: E6POS / E6AXIS data, moves to them and inline, comments, spacing and line ends."""
    eol = draw(st.sampled_from(["\r\n", "\n"]))
    sp = draw(st.sampled_from(["", " ", "  "]))
    n = draw(st.integers(1, 6))
    dat, src, expect = [], [], {}
    for k in range(n):
        joint = draw(st.booleans())
        keys = ("A1", "A2", "A3", "A4", "A5", "A6") if joint else ("X", "Y", "Z", "A", "B", "C")
        nums = [draw(NUMBER) for _ in keys]
        extra = ",E1 0.0" if joint else f",S {draw(st.integers(0, 7))},T {draw(st.integers(0, 63))}"
        agg = "{" + f",{sp}".join(f"{key} {v}" for key, v in zip(keys, nums, strict=True)) + extra + "}"
        expect[f"XP{k}"] = [float(v) for v in nums]
        dat.append(f"DECL {'E6AXIS' if joint else 'E6POS'} XP{k}={agg}")
        src.append(
            f"{sp}{draw(st.sampled_from(['PTP', 'LIN']))} XP{k}{draw(st.sampled_from(['', ' C_DIS']))}"
            f"{draw(st.sampled_from(['', ' ; moved here']))}"
        )
        if draw(st.booleans()):
            src.append(f";FOLD a fold;%{{PE}}%R 5.5{eol.strip()}")
    files = {
        "G.src": eol.join(["&ACCESS RVP", "DEF G( )", *src, "END"]) + eol,
        "G.dat": eol.join(["DEFDAT G PUBLIC", *dat, "ENDDAT"]) + eol,
    }
    return files, expect


@given(programs())
@settings(max_examples=60, deadline=None)
def test_generated_programs_round_trip_and_read_their_values(case):
    files, expect = case
    program = read_krl(files)
    assert program.write({}, {}) == files
    assert {t.name for t in program.targets} == set(expect)
    for t in program.targets:
        got = t.value if t.joint else [*t.value[:3, 3], *Rotation.from_matrix(t.value[:3, :3]).as_euler("ZYX", True)]
        if t.joint:
            np.testing.assert_allclose(got, expect[t.name])
        else:  # the pose of the written X..C: compare poses, the Euler angles having several spellings
            np.testing.assert_allclose(t.value, _kuka(*expect[t.name]), atol=1e-9)


@pytest.mark.parametrize(
    ("src", "dat", "expected"),
    [
        ('MSG = "unclosed', "", r"T\.src:2: a string"),
        ("PTP", "", r"T\.src:2: expected a point after PTP"),
        ("CIRC XP1", "", r"T\.src:2: expected , and the end point"),
        ("LIN {X 1.0,Y 2.0", "", r"T\.src:2: expected '\}' to close '\{'"),
        ("LIN {X 1.0,Y 2.0 Z 3.0}", "", r"T\.src:2: expected , or \} after member Y, got 'Z'"),
        ("LIN {X 1.0,Y}", "", r"T\.src:2: expected a value"),
        ("LIN {X 1.0,X 2.0}", "", r"T\.src:2: member X given twice"),
        ("PTP XP1 ?", "", r"T\.src:2: unexpected character '\?'"),
        ("PTP XP1", "DECL E6POS XP1={X 1,Y 2,Z 3,A 0,B 0,C 0,S 2.5,T 0}", r"T\.dat:2: S of XP1 must be a whole"),
        ("IF (A > 1 THEN", "", r"T\.src:2: expected '\)' to close"),
        ("LIN {X 1E999,Y 0,Z 0,A 0,B 0,C 0}", "", r"T\.src:2: the number 1E999 is out of range"),
        ("S = 'B012'", "", r"T\.src:2: expected a bit pattern"),
    ],
)
def test_broken_programs_one_line_errors(src, dat, expected):
    with pytest.raises(ProgramReadError, match=expected) as err:
        read_krl(_program(src, dat))
    assert ERROR_LINE.match(str(err.value))


def test_structure_errors():
    with pytest.raises(ProgramReadError, match=r"^T\.src:3: expected END \(for line 1\) before the file's end$"):
        read_krl({"T.src": "DEF T( )\r\nPTP XP1\r\n;FOLD\r\n"})
    with pytest.raises(ProgramReadError, match=r"^T\.src:1: expected DEF, DEFFCT or DEFDAT before 'PTP'$"):
        read_krl({"T.src": "PTP XP1\r\n"})
    with pytest.raises(ProgramReadError, match=r"^T\.dat:2: expected ENDDAT \(for line 1\), got END$"):
        read_krl({"T.dat": "DEFDAT T\nEND\n"})


@given(
    st.sampled_from(["krc2", "krc4"]),
    st.integers(0, 2),
    st.lists(
        st.tuples(
            st.floats(0, 1),
            st.integers(0, 6),
            st.text(alphabet=st.characters(min_codepoint=0, max_codepoint=300), max_size=4),
        ),
        min_size=1,
        max_size=4,
    ),
)
@settings(max_examples=150, deadline=None)
def test_fuzzed_programs_read_or_fail_in_one_line(folder, which, edits):
    files = _sample(folder)
    name = sorted(files)[which]
    text = files[name]
    for where, cut, junk in edits:
        i = int(where * len(text))
        text = text[:i] + junk + text[i + cut :]
    files[name] = text
    try:
        program = read_krl(files)
    except ProgramReadError as err:
        assert ERROR_LINE.match(str(err)), str(err)
    else:
        assert program.write({}, {}) == files


@given(
    st.text(alphabet=st.sampled_from(list("{}()[],:=;&\"' \r\nXYZABCST0123456789.-+#$_EDFLINPTCRUW'B")), max_size=120)
)
@settings(max_examples=300, deadline=None)
def test_fuzzed_krl_alphabet_reads_or_fails_in_one_line(text):
    for files in ({"F.src": text}, {"F.src": f"DEF F( )\n{text}\nEND\n"}, {"F.dat": f"DEFDAT F\n{text}\nENDDAT\n"}):
        try:
            program = read_krl(files)
        except ProgramReadError as err:
            assert ERROR_LINE.match(str(err)), str(err)
        else:
            assert program.write({}, {}) == files
