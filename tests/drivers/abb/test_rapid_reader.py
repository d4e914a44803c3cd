"""The RAPID reader for program filtering: poses and frames checked by hand, the robot configuration rule, the round
trip byte for byte, and one-line errors for what it cannot read (fuzzed: never another exception)."""

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from tests.helpers import ROOT
from trackcal.calib.model.cell import load_robot
from trackcal.calib.model.kinematics import Kinematics
from trackcal.drivers.abb.rapid_reader import read_rapid
from trackcal.drivers.program_text import ProgramReadError

SAMPLE = ROOT / "configs" / "programs" / "abb" / "CellDemo.mod"
EXTAX = "[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]"


def transform(trans, quat_scalar_first) -> np.ndarray:
    """A 4 x 4 from a position and a quaternion (q1 scalar), computed with scipy (scalar last), not the reader."""
    w, x, y, z = quat_scalar_first
    m = np.eye(4)
    m[:3, :3] = Rotation.from_quat([x, y, z, w]).as_matrix()
    m[:3, 3] = trans
    return m


def rot_y(deg: float) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = Rotation.from_euler("y", deg, degrees=True).as_matrix()
    return m


def module(body: str, data: str = "") -> dict[str, str]:
    return {"T.mod": f"MODULE T\n{data}\nPROC main()\n{body}\nENDPROC\nENDMODULE\n"}


def by_name(program, name):
    return next(t for t in program.targets if t.name == name)


# ---- poses and frames checked by hand ---------------------------------------------------------------------------


def test_calibration_position_of_the_irb120_in_tool0_and_wobj0():
    # IRB 120 at all joints 0 (ABB's calibration position): the flange centre at x 302 + 72 = 374 mm, z 290 + 270 +
    # 70 = 630 mm (product specification 3HAC035960-001), and ABB's tool0 there has z forward (base +x) and x down:
    # 90 deg about y, the quaternion [cos 45, 0, sin 45, 0]
    q = [0.70710678, 0, 0.70710678, 0]
    files = module(
        "MoveL pCal, v100, fine, tool0;", f"CONST robtarget pCal:=[[374,0,630],[{q[0]},0,{q[2]},0],[0,0,0,0],{EXTAX}];"
    )
    t = read_rapid(files).targets[0]
    assert (t.name, t.joint, t.line, t.config, t.motion) == ("pCal", False, 2, (0, 0, 0, 0), "MoveL")
    np.testing.assert_allclose(t.value, transform([374, 0, 630], q), atol=1e-9)
    np.testing.assert_allclose(t.base, np.eye(4))
    # the robot configs' flange frame (irb120.yaml's last joint: x along axis 6, z up at zero) is the base's
    # orientation at the calibration position, so the TCP's pose there is the flange (374, 0, 630) times the tool
    flange = np.eye(4)
    flange[:3, 3] = [374, 0, 630]
    np.testing.assert_allclose(t.base @ t.value, flange @ t.tool, atol=1e-6)


def test_tool_and_work_object_frames_from_another_module():
    # a user module declares the tool and the work object; uframe 45 deg about z at (100, 200, 300), oframe 10 mm
    # along its x: the object frame's origin is (100 + 10 cos 45, 200 + 10 sin 45, 300); the tool 30 deg about y
    c, s = np.cos(np.pi / 8), np.sin(np.pi / 8)  # the half angles of 45 deg
    c30, s30 = np.cos(np.pi / 12), np.sin(np.pi / 12)
    user = (
        "MODULE User(SYSMODULE)\n"
        f"PERS tooldata tPen:=[TRUE,[[12.5,0,95],[{c30},0,{s30},0]],[0.3,[5,0,45],[1,0,0,0],0,0,0]];\n"
        f'TASK PERS wobjdata wTable:=[FALSE,TRUE,"",[[100,200,300],[{c},0,0,{s}]],[[10,0,0],[1,0,0,0]]];\n'
        "ENDMODULE\n"
    )
    files = {
        "User.sys": user,
        **module(
            "MoveJ p1, v100, z10, tPen \\WObj:=wTable;", f"CONST robtarget p1:=[[1,2,3],[1,0,0,0],[0,0,0,0],{EXTAX}];"
        ),
    }
    t = read_rapid(files).targets[0]
    np.testing.assert_allclose(t.base[:3, 3], [100 + 10 * np.sqrt(0.5), 200 + 10 * np.sqrt(0.5), 300], atol=1e-6)
    np.testing.assert_allclose(t.base, transform([100, 200, 300], [c, 0, 0, s]) @ transform([10, 0, 0], [1, 0, 0, 0]))
    # the TCP in the flange frame: ABB's wrist frame (90 deg about y in the configs' flange frame) times tframe
    np.testing.assert_allclose(t.tool, rot_y(90) @ transform([12.5, 0, 95], [c30, 0, s30, 0]), atol=1e-12)
    np.testing.assert_allclose(t.value, transform([1, 2, 3], [1, 0, 0, 0]))


# the joints the sample program's targets were taught from (configs/programs/abb/CellDemo.mod was written from them)
SAMPLE_JOINTS = {
    "pApproach": [-20, 20, 10, 15, 50, -30],
    "pPick": [-20, 28, 12, 15, 42, -30],
    "pCirc": [-5, 25, 15, 10, 45, 20],
    "pEnd": [10, 20, 20, 0, 50, 40],
    "pPlace": [35, 22, 8, -20, 55, 100],
    "line 52": [25, 15, 25, 120, -40, 95],
}


@pytest.mark.parametrize("robot", ["irb120", "irb120-dh"])
def test_sample_targets_are_the_irb120_poses_they_were_taught_at(robot):
    # the tool's pose by the project's own kinematics (the URDF chain and the DH table of the IRB 120) at the taught
    # joints equals base * target read from the program (to the sample's 0.01 mm and 1e-6 quaternion digits), and
    # the joints are in the target's robconf
    program = read_rapid({"CellDemo.mod": SAMPLE.read_text()})
    kin = Kinematics(load_robot(robot)[0], [])
    for name, q in SAMPLE_JOINTS.items():
        t = by_name(program, name)
        r, o = kin.end_frames(np.radians([q]))
        flange = np.eye(4)
        flange[:3, :3], flange[:3, 3] = r[0], o[0]
        np.testing.assert_allclose(t.base @ t.value, flange @ t.tool, atol=0.02, err_msg=name)
        assert t.accepts(np.array(q, dtype=float)), name


def test_sample_program_moves_and_motions():
    program = read_rapid({"CellDemo.mod": SAMPLE.read_text()})
    got = [(t.name, t.joint, t.motion) for t in program.targets]
    assert got == [
        ("jHome", True, "MoveAbsJ"),
        ("pApproach", False, "MoveJ"),
        ("pPick", False, "MoveL, MoveL Offs"),
        ("pCirc", False, "MoveC"),
        ("pEnd", False, "MoveC"),
        ("pPlace", False, "MoveJ RelTool, MoveL, MoveJ"),
        ("line 52", False, "MoveL"),
    ]
    np.testing.assert_allclose(program.targets[0].value, [0, 0, 0, 0, 30, 0])
    assert program.language == "RAPID" and program.comment == "!"


# ---- the robot configuration ------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "q, ok, why",
    [
        (
            [-30, 10, 10, 45, -20, 100],
            True,
            "axis 1 in [-90, 0): -1; axis 4 in [0, 90): 0; axis 6 in [90, 180): 1; 5 < 0",
        ),
        ([30, 10, 10, 45, -20, 100], False, "axis 1 in [0, 90) is quadrant 0, not -1"),
        ([-90, 10, 10, 45, -20, 100], True, "-90 deg opens quadrant -1 ([-90, 0))"),
        ([-90.001, 10, 10, 45, -20, 100], False, "just below -90 deg is quadrant -2"),
        ([-30, 10, 10, 90.001, -20, 100], False, "axis 4 past 90 deg is quadrant 1"),
        (
            [-30, 10, 10, 90, -20, 100],
            True,
            "axis 4 at 90 deg: a boundary, within rounding of quadrant 0's end (an IK "
            "returns a target written at 0 or 90 deg as +-1e-13 deg off)",
        ),
        ([-30, 10, 10, 45, -20, 89.9], False, "axis 6 below 90 deg is quadrant 0"),
        ([-30, 10, 10, 45, -20, 460], False, "axis 6 one turn further (460 deg) is quadrant 5, not 1"),
        ([-30, 10, 10, 45, 20, 100], False, "cfx odd: axis 5 must be negative"),
        ([-30, 10, 10, 45, 0, 100], True, "axis 5 at 0 (the wrist singularity) is either sign"),
    ],
)
def test_robconf_quadrants_and_axis5_sign(q, ok, why):
    # confdata (RAPID Instructions, Functions and Data types): quadrant n of an axis is [90 n, 90 (n + 1)) deg
    files = module("MoveL p, v100, fine, tool0;", f"CONST robtarget p:=[[400,0,500],[0,0,1,0],[-1,0,1,1],{EXTAX}];")
    t = read_rapid(files).targets[0]
    assert t.config == (-1, 0, 1, 1)
    assert t.accepts(np.array(q, dtype=float)) is ok, why


def test_robconf_wrist_centre_bits_are_not_checked_from_joints():
    # cfx 5 = behind axis 1 (4) + axis 5 negative (1): the wrist centre's place needs the arm's geometry, so only the
    # axis 5 bit is checked
    files = module("MoveL p, v100, fine, tool0;", f"CONST robtarget p:=[[400,0,500],[0,0,1,0],[0,0,0,5],{EXTAX}];")
    t = read_rapid(files).targets[0]
    assert t.accepts(np.array([10, 0, 0, 10, -30, 10.0]))
    assert not t.accepts(np.array([10, 0, 0, 10, 30, 10.0]))


# ---- rendering --------------------------------------------------------------------------------------------------


def test_render_replaces_trans_and_rot_only_and_keeps_the_source_hemisphere():
    # the source writes q1 < 0 (the same rotation as its negative): the corrected quaternion keeps that sign
    text = (
        "CONST robtarget p:=[ [374, 0,630] , [-0.70710678,0,-0.70710678,0],[0,-1,2,1],\n"
        "   [11, 12.3, 9E9, 9E9, 9E9, 9E9] ]; ! taught\n"
    )
    files = module("MoveL p, v100, fine, tool0;", text)
    t = read_rapid(files).targets[0]
    moved = t.value.copy()
    moved[:3, 3] += [0.0123, -0.5, 1e-5]
    out = t.render(moved)
    assert out == (
        "[ [374.0123, -0.5,630] , [-0.70710678,0,-0.70710678,0],[0,-1,2,1],\n   [11, 12.3, 9E9, 9E9, 9E9, 9E9] ]"
    )
    tilted = moved @ rot_y(1e-4 * 180 / np.pi)  # 1e-4 rad about the tool's y: q1, q3 turn by half of it
    again = read_rapid({"T.mod": files["T.mod"].replace(t.render(t.value), t.render(tilted))}).targets[0]
    np.testing.assert_allclose(again.value, tilted, atol=1e-7)
    assert ", [-0.707" in t.render(tilted) and "[0,-1,2,1]" in t.render(tilted)


def test_jointtarget_render_replaces_robax_only():
    files = module("MoveAbsJ [[0,0,0,0,30,0],[9E9,9E9,9E9,9E9,9E9,9E9]]\\NoEOffs, v1000, z50, tool0;")
    t = read_rapid(files).targets[0]
    assert (t.name, t.joint, t.config, t.motion) == ("line 4", True, (), "MoveAbsJ")
    assert t.render(np.array([1.5, -2.25, 3.000004, 0, 29.99999, -0.000001])) == (
        "[[1.5,-2.25,3.00000,0,29.99999,0],[9E9,9E9,9E9,9E9,9E9,9E9]]".replace("3.00000", "3")
    )


# ---- what is read -----------------------------------------------------------------------------------------------


def test_offs_reltool_arrays_and_movec_targets():
    data = (
        f"CONST robtarget a:=[[1,0,0],[1,0,0,0],[0,0,0,0],{EXTAX}];\n"
        f"CONST robtarget b:=[[2,0,0],[1,0,0,0],[0,0,0,0],{EXTAX}];\n"
        f"CONST robtarget path{{2}}:=[[[3,0,0],[1,0,0,0],[0,0,0,0],{EXTAX}],\n"
        f"                            [[4,0,0],[1,0,0,0],[0,0,0,0],{EXTAX}]];\n"
        f"VAR robtarget loose:=[[5,0,0],[1,0,0,0],[0,0,0,0],{EXTAX}];\n"
        "VAR robtarget now;\n"
    )
    body = (
        "moveL Offs(a, 0, 0, 50), v100, z10, tool0;\n"
        "MoveC \\Conc, a, b \\ID:=1, v100, z10 \\Inpos:=inpos20, tool0;\n"
        "FOR i FROM 1 TO 2 DO MoveL path{i}, v100, fine, tool0; ENDFOR\n"
        "now := CRobT();  MoveL now, v100, fine, tool0;\n"
        "MoveJ RelTool(CRobT(), 0, 0, 10), v100, fine, tool0;"
    )
    program = read_rapid(module(body, data))
    got = [(t.name, t.motion) for t in program.targets]
    assert got == [
        ("a", "MoveL Offs, MoveC"),
        ("b", "MoveC"),
        ("path{1}", "MoveL"),
        ("path{2}", "MoveL"),
        ("loose", ""),
    ]
    np.testing.assert_allclose([t.value[0, 3] for t in program.targets], [1, 2, 3, 4, 5])


def test_prg_header_local_scope_and_case_insensitive_names():
    prg = (
        "%%%\n  VERSION:1\n  LANGUAGE:ENGLISH\n%%%\n\nMODULE Old\n"
        f"  LOCAL PERS tooldata T1:=[TRUE,[[0,0,50],[1,0,0,0]],[1,[0,0,1],[1,0,0,0],0,0,0]];\n"
        f"  CONST ROBTARGET P1:=[[1,2,3],[1,0,0,0],[0,0,0,0],{EXTAX}];\n"
        "  PROC main()\n    movel p1, v100, fine, t1;\n  ENDPROC\nENDMODULE\n"
    )
    t = read_rapid({"OLD.PRG": prg}).targets[0]
    assert (t.name, t.line, t.motion) == ("P1", 8, "MoveL")
    np.testing.assert_allclose(t.tool[:3, 3], [50, 0, 0], atol=1e-12)  # tool z 50 mm = the configs' flange x


# ---- round trip -------------------------------------------------------------------------------------------------


def test_sample_round_trip_is_byte_identical_and_renders_its_own_values():
    files = {"CellDemo.mod": SAMPLE.read_text()}
    program = read_rapid(files)
    assert program.write({}, {}) == files
    rewritten = program.write({i: t.value for i, t in enumerate(program.targets)}, {})
    again = read_rapid(rewritten)
    for a, b in zip(program.targets, again.targets, strict=True):
        np.testing.assert_allclose(a.value, b.value, atol=1e-4)
        assert (a.name, a.config, a.motion) == (b.name, b.config, b.motion)


_num = st.one_of(
    st.integers(-2000, 2000).map(str),
    st.floats(-2000, 2000, allow_nan=False).map(lambda v: f"{v:.3f}"),
    st.floats(0.001, 99, allow_nan=False).map(lambda v: f"{v:.2E}"),
)
_space = st.sampled_from(["", " ", "  ", "\n   ", ' ! a comment [ ; "\n', "\r\n"])


@st.composite
def _modules(draw):
    """A module of robtargets (numbers in RAPID's forms, spaces and comments between tokens) and moves using them."""
    sp = lambda: draw(_space)  # noqa: E731
    n = draw(st.integers(1, 4))
    lines = [f"MODULE M{sp()}"]
    for k in range(n):
        trans = f",{sp()}".join(draw(_num) for _ in range(3))
        axis = draw(st.sampled_from(["1,0,0,0", "0,0,1,0", "0.5,0.5,0.5,-0.5", "-0.70710678, 0, 0, 0.70710678"]))
        storage = draw(st.sampled_from(["CONST", "PERS", "VAR", "LOCAL CONST", "TASK PERS"]))
        lines.append(
            f"{storage} robtarget{sp()} p{k}{sp()}:={sp()}[[{trans}],{sp()}[{axis}],[0,{sp()}-1,2,0],"
            f"[9E9,9E9,9E9,9E9,9E9,9E9]{sp()}]{sp()};"
        )
    lines.append("PROC main()")
    for k in range(n):
        move = draw(st.sampled_from(["MoveL", "movej", "MOVEL"]))
        lines.append(f"  {move} p{k},{sp()}v100, z10,{sp()}tool0;{sp()}")
    lines.append(f"ENDPROC\n{sp()}ENDMODULE{sp()}")
    return {"M.mod": "\n".join(lines)}, n


@given(_modules())
@settings(max_examples=60, deadline=None)
def test_generated_modules_round_trip(case):
    files, n = case
    program = read_rapid(files)
    assert program.write({}, {}) == files
    assert [t.name for t in program.targets] == [f"p{k}" for k in range(n)]
    again = read_rapid(program.write({i: t.value for i, t in enumerate(program.targets)}, {}))
    for a, b in zip(program.targets, again.targets, strict=True):
        np.testing.assert_allclose(a.value, b.value, atol=1e-4)


# ---- errors -------------------------------------------------------------------------------------------------------

P = f"CONST robtarget p:=[[1,2,3],[1,0,0,0],[0,0,0,0],{EXTAX}];"
FIXED = "[[0,0,0],[1,0,0,0]]"


@pytest.mark.parametrize(
    "files, line, words",
    [
        ({"a.mod": "PROC main()\nENDPROC\n"}, 1, "expected MODULE"),
        ({"a.mod": "MODULE A\nPROC main()\n  MoveL p, v100, fine, tool0;\n"}, 3, "ENDPROC of main"),
        ({"a.mod": "MODULE A\nPROC main()\nENDPROC\n"}, 3, "ENDMODULE"),
        ({"a.mod": 'MODULE A\nVAR string s:="open;\nENDMODULE\n'}, 2, "string not closed"),
        ({"a.mod": "MODULE A\nVAR num x:=1 # 2;\nENDMODULE\n"}, 2, "unexpected character '#'"),
        (module("MoveL p, v100, tool0;", P), 4, "MoveL needs a target, a speed, a zone and a tool"),
        (module("MoveC p, v100, z10, tool0;", P), 4, "MoveC needs two targets"),
        (module("MoveL p, v100, fine, tGun;", P), 4, "tooldata tGun, which the files given do not declare"),
        (module("MoveL p, v100, fine, tool0 \\WObj:=w;", P), 4, "wobjdata w, which the files given do not declare"),
        (module("MoveL p, v100, fine, tool0", P), 4, "expected ';' before ENDPROC"),
        (
            module("MoveL p, v100, fine, tool0;", "CONST robtarget p:=[[1,2,3],[1,0,0,0],[0,0,0,0]];"),
            2,
            "robtarget p as [[x,y,z],[q1,q2,q3,q4],[cf1,cf4,cf6,cfx],[extax]]",
        ),
        (
            module("MoveL p, v100, fine, tool0;", f"CONST robtarget p:=[[1,2,3],[0,0,0,0],[0,0,0,0],{EXTAX}];"),
            2,
            "quaternion [q1, q2, q3, q4] is not normalised",
        ),
        (
            module("MoveL p, v100, fine, tool0;", f"CONST robtarget p:=[[1,2,3],[1,0,0,0],[0,0.5,0,0],{EXTAX}];"),
            2,
            "robconf [cf1, cf4, cf6, cfx] must be integers",
        ),
        (
            module("MoveL p, v100, fine, tool0;", f"CONST robtarget p:=[[1,x0,3],[1,0,0,0],[0,0,0,0],{EXTAX}];"),
            2,
            "expected a number in robtarget p's trans",
        ),
        (
            module(
                "MoveL p, v100, fine, tFix;", P + f"\nPERS tooldata tFix:=[FALSE,{FIXED},[1,[0,0,1],[1,0,0,0],0,0,0]];"
            ),
            3,
            "tooldata tFix: a stationary tool (robhold FALSE) is not supported",
        ),
        (
            module("MoveL p, v100, fine, tool0\\WObj:=w;", P + f'\nPERS wobjdata w:=[TRUE,TRUE,"",{FIXED},{FIXED}];'),
            3,
            "robhold TRUE, a stationary tool) is not supported",
        ),
        (
            module(
                "MoveL p, v100, fine, tool0\\WObj:=w;", P + f'\nPERS wobjdata w:=[FALSE,FALSE,"STN_1",{FIXED},{FIXED}];'
            ),
            3,
            "coordinated work object",
        ),
        (
            module(
                "MoveL p, v100, fine, tool0;\nMoveL p, v100, fine, tool0\\WObj:=w;",
                P + '\nPERS wobjdata w:=[FALSE,TRUE,"",[[0,0,9],[1,0,0,0]],[[0,0,0],[1,0,0,0]]];',
            ),
            6,
            "p is used with tool tool0 in work object wobj0 (line 5) and with tool tool0 in w",
        ),
        (module("MoveL p, v100, fine, tool0;", P + "\nMODULE B\nENDMODULE"), 3, "expected a declaration, PROC"),
        (module("x := (1 + 2;", P), 4, "'(' not closed"),
    ],
)
def test_broken_programs_fail_in_one_line_with_file_and_line(files, line, words):
    with pytest.raises(ProgramReadError) as err:
        read_rapid(files)
    message = str(err.value)
    assert "\n" not in message
    name = next(iter(files))
    assert message.startswith(f"{name}:{line}: "), message
    assert words in message, message


def test_a_target_in_two_frames_names_both():
    # the same robtarget used in two work objects cannot get one correction for both: refused, not half-corrected
    files = module(
        "MoveL p, v100, fine, tool0;\nMoveL p, v100, fine, tool0\\WObj:=w;",
        P + '\nPERS wobjdata w:=[FALSE,TRUE,"",[[0,0,9],[1,0,0,0]],[[0,0,0],[1,0,0,0]]];',
    )
    with pytest.raises(ProgramReadError, match="one corrected value cannot serve both"):
        read_rapid(files)


_SAMPLE_TEXT = SAMPLE.read_text()


@given(
    st.lists(
        st.tuples(
            st.integers(0, len(_SAMPLE_TEXT)),
            st.integers(0, 6),
            st.text(alphabet='[](){},;:=!"\\%-+.0123456789EeMoveLJCTRUE \n\tpx{}', max_size=6),
        ),
        min_size=1,
        max_size=4,
    )
)
@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
def test_mutated_sample_reads_or_fails_in_one_line(edits):
    text = _SAMPLE_TEXT
    for pos, cut, insert in edits:
        pos = min(pos, len(text))
        text = text[:pos] + insert + text[pos + cut :]
    try:
        program = read_rapid({"CellDemo.mod": text})
    except ProgramReadError as err:
        assert "\n" not in str(err) and str(err).startswith("CellDemo.mod:")
        return
    assert program.write({}, {}) == {"CellDemo.mod": text}


@given(st.text(max_size=300))
@settings(max_examples=200, deadline=None)
def test_any_text_reads_or_fails_in_one_line(text):
    try:
        read_rapid({"X.mod": text})
    except ProgramReadError as err:
        assert "\n" not in str(err)


def test_sample_is_a_file_of_the_project():
    assert Path(SAMPLE).is_file() and "MoveC" in _SAMPLE_TEXT and "MoveAbsJ" in _SAMPLE_TEXT


def test_hexadecimal_binary_octal_literals_read():
    # RobotWare 6.x+ writes integers also as 0x.., 0b.., 0o.. (RAPID kernel, numeric literals): 0x10 = 16, 0b11 = 3
    files = module("MoveL p, v100, fine, tool0;", f"CONST robtarget p:=[[0x10,0b11,0o10],[1,0,0,0],[0,0,0,0],{EXTAX}];")
    np.testing.assert_allclose(read_rapid(files).targets[0].value[:3, 3], [16, 3, 8])


def test_routine_parameters_are_the_callers_data():
    # in PROC GoTo(robtarget p), `p` is the caller's argument, not the module's p: the module's p is used by no move
    data = P + "\nPERS tooldata t1:=[TRUE,[[0,0,50],[1,0,0,0]],[1,[0,0,1],[1,0,0,0],0,0,0]];"
    files = {
        "T.mod": f"MODULE T\n{data}\nPROC GoTo(robtarget p, \\switch Fast)\n  MoveL p, v100, fine, t1;\n"
        "ENDPROC\nENDMODULE\n"
    }
    assert [(t.name, t.motion) for t in read_rapid(files).targets] == [("p", "")]
    # a tool given as a parameter has no frame in the text: a target moved with it is refused, not guessed
    files = {
        "T.mod": f"MODULE T\n{data}\nPROC Draw(PERS tooldata tUse)\n  MoveL p, v100, fine, tUse;\nENDPROC\nENDMODULE\n"
    }
    with pytest.raises(ProgramReadError, match="T.mod:5: MoveL's tooldata tUse is a parameter of its routine"):
        read_rapid(files)


def test_an_empty_argument_is_an_error():
    with pytest.raises(ProgramReadError, match="T.mod:4: an empty argument of MoveL"):
        read_rapid(module("MoveL p,, v100, fine, tool0;", P))


def test_a_persistent_declared_alike_in_two_modules_is_one():
    # PERS data may be declared in several modules of a task with the same value (RAPID kernel, persistents)
    tool = "PERS tooldata tG:=[TRUE,[[0,0,80],[1,0,0,0]],[1,[0,0,1],[1,0,0,0],0,0,0]];"
    files = {
        "A.mod": f"MODULE A\n{tool}\nENDMODULE\n",
        "B.mod": f"MODULE B\n  {tool}\nENDMODULE\n",
        **module("MoveL p, v100, fine, tG;", P),
    }
    np.testing.assert_allclose(read_rapid(files).targets[0].tool[:3, 3], [80, 0, 0], atol=1e-12)
    files["B.mod"] = files["B.mod"].replace("80", "81")
    with pytest.raises(ProgramReadError, match="tG is declared globally twice"):
        read_rapid(files)


@pytest.mark.parametrize("bom", ["\ufeff", "\xef\xbb\xbf"])  # decoded as UTF-8, and byte for byte as Latin-1
def test_byte_order_mark_and_crlf_lines(bom):
    # a module saved with a UTF-8 byte order mark and Windows line ends reads, and round-trips byte for byte
    text = bom + SAMPLE.read_text().replace("\n", "\r\n")
    program = read_rapid({"CellDemo.mod": text})
    assert program.write({}, {}) == {"CellDemo.mod": text}
    assert by_name(program, "line 52").line == 52
    rewritten = program.write({0: program.targets[0].value}, {0: "kept"})["CellDemo.mod"]
    assert "[[0,0,0,0,30,0],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]]; ! kept\r\n" in rewritten


def test_targets_tool_and_work_object_passed_to_a_procedure():
    # a common cell pattern: a PROC that moves to the robtarget, with the tool and work object it is given; the
    # call's arguments are what the move uses (uframe (0, 0, 100): the base 100 mm up; tool 80 mm along tool0's z)
    data = (
        P + "\nPERS tooldata tG:=[TRUE,[[0,0,80],[1,0,0,0]],[1,[0,0,1],[1,0,0,0],0,0,0]];"
        '\nPERS wobjdata wT:=[FALSE,TRUE,"",[[0,0,100],[1,0,0,0]],[[0,0,0],[1,0,0,0]]];'
    )
    files = {
        "T.mod": f"MODULE T\n{data}\nPROC main()\n  MoveTo p, tG, wT;\nENDPROC\n"
        "PROC MoveTo(robtarget pTo, PERS tooldata t, PERS wobjdata w)\n"
        "  MoveL Offs(pTo, 0, 0, 10), v100, z10, t\\WObj:=w;\n  MoveL pTo, v100, fine, t\\WObj:=w;\n"
        "ENDPROC\nENDMODULE\n"
    }
    t = read_rapid(files).targets[0]
    assert (t.name, t.motion) == ("p", "MoveL Offs via MoveTo, MoveL via MoveTo")
    np.testing.assert_allclose(t.base[:3, 3], [0, 0, 100])
    np.testing.assert_allclose(t.tool[:3, 3], [80, 0, 0], atol=1e-12)  # tool0's z is the configs' flange x


@pytest.mark.parametrize("robot", ["irb120", "irb120-dh"])
def test_the_wrist_flip_of_a_sample_pose_is_another_configuration(robot):
    # (q4 + 180, -q5, q6 + 180) reaches the same flange pose (axes 4 and 6 along the same line through the wrist
    # centre when axis 5 is turned back), checked with the project's kinematics; robconf tells the two apart: cf4 and
    # cf6 quadrants 2 and 1 instead of 0 and -1, and axis 5 negative against cfx 0
    program = read_rapid({"CellDemo.mod": SAMPLE.read_text(), "X.mod": "MODULE X\nENDMODULE\n"})
    t = by_name(program, "pApproach")
    q = np.array(SAMPLE_JOINTS["pApproach"], dtype=float)
    flipped = q + [0, 0, 0, 180, 0, 180]
    flipped[4] = -q[4]
    kin = Kinematics(load_robot(robot)[0], [])
    (r1, r2), (o1, o2) = kin.end_frames(np.radians([q, flipped]))
    np.testing.assert_allclose(r1, r2, atol=1e-9)
    np.testing.assert_allclose(o1, o2, atol=1e-6)
    assert t.accepts(q) and not t.accepts(flipped)


def test_alias_declarations_are_skipped():
    files = module("MoveL p, v100, fine, tool0;", "ALIAS num level;\n" + P)
    assert [t.name for t in read_rapid(files).targets] == ["p"]
