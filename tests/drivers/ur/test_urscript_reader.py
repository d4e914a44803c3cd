"""The URScript reader (drivers/ur/urscript_reader.py): the targets of a script with their frames, the text kept byte
for byte, a corrected value written in the source's style, one line for what it cannot read.

Expected values come from the sample's own text (configs/programs/ur/cell_demo.script) and the URScript manual's
conventions: metres and rotation vectors in p[...], radians in joint lists, pose_trans(feature, pose) the pose in the
feature's frame."""

import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from trackcal.drivers.families import program_readers
from trackcal.drivers.program_text import ProgramReadError
from trackcal.drivers.ur.urscript_reader import read_urscript

SAMPLE = Path(__file__).resolve().parents[3] / "configs" / "programs" / "ur" / "cell_demo.script"


def pose(x, y, z, rx, ry, rz) -> np.ndarray:
    """4 x 4 (mm) of a URScript pose, by scipy's rotation vector (independent of the reader's)."""
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = Rotation.from_rotvec([rx, ry, rz]).as_matrix(), np.array([x, y, z]) * 1000.0
    return out


def test_the_ur_family_reads_script_files():
    assert program_readers()[".script"] is read_urscript
    assert program_readers()[".urscript"] is read_urscript


def test_the_sample_program_s_targets_and_frames():
    text = SAMPLE.read_text()
    read = read_urscript({"cell_demo.script": text})
    assert read.language == "URScript" and read.comment == "#"
    names = [(t.name, t.line, t.joint, t.motion) for t in read.targets]
    assert names == [
        ("home", 8, True, "movej"),
        ("approach", 9, False, "movej"),
        ("pick", 10, False, "movel"),
        ("place", 11, False, "movel"),
        ("line 19", 19, False, "movec"),
        ("line 19", 19, False, "movec"),
        ("line 22", 22, False, "movep"),
        ("line 24", 24, True, "movej"),
    ]
    fixture = pose(-0.9, -0.1, 0.05, 0.0, 0.0, 0.3)  # line 7 of the sample
    tcp = pose(0.0, 0.05, 0.15, 0.0, 0.0, 0.0)  # its set_tcp
    home, approach, pick = read.targets[:3]
    np.testing.assert_allclose(home.value, np.degrees([0.0, -1.5708, 1.5708, -1.5708, -1.5708, 0.0]))
    np.testing.assert_allclose(approach.value, pose(0.030702, 0.207735, 0.216985, 2.591996, 1.775151, 0.0), atol=1e-9)
    np.testing.assert_allclose(pick.value, pose(0.011206, 0.220488, 0.048684, -2.591996, -1.775151, 0.0), atol=1e-9)
    for t in read.targets[1:6]:
        np.testing.assert_allclose(t.base, fixture, atol=1e-12)
    np.testing.assert_allclose(read.targets[6].base, np.eye(4))  # movep of a pose in the robot's base frame
    for t in read.targets:
        np.testing.assert_allclose(t.tool, tcp, atol=1e-12)
        assert text[t.start : t.end].count(",") == 5


def test_a_corrected_value_is_written_in_the_source_s_style_and_reads_back():
    text = SAMPLE.read_text()
    read = read_urscript({"cell_demo.script": text})
    moved = {i: t.value.copy() for i, t in enumerate(read.targets)}
    for i, t in enumerate(read.targets):
        if t.joint:
            moved[i] = t.value + 0.01  # deg
        else:
            moved[i][:3, 3] += [0.5, -0.25, 0.125]  # mm
    out = read.write(moved, {})["cell_demo.script"]
    again = read_urscript({"cell_demo.script": out})
    for i, t in enumerate(again.targets):
        np.testing.assert_allclose(t.value, moved[i], atol=1e-3)  # 1e-6 m, 1e-6 rad written
        number = re.compile(r"-?\d+\.(\d+)")
        assert all(len(d) >= 6 for d in number.findall(out[t.start : t.end]))
    # the half-turn rotation vector of `pick` keeps its sign convention (-2.59, -1.78, 0)
    assert out[again.targets[2].start :].startswith("0.011706, 0.220238, 0.048809, -2.591996, -1.775151")
    # everything but the targets is the same text
    strip = [(t.start, t.end) for t in read.targets]
    kept = "".join(
        text[a:b] for a, b in zip([0] + [e for _, e in strip], [s for s, _ in strip] + [len(text)], strict=True)
    )
    strip2 = [(t.start, t.end) for t in again.targets]
    kept2 = "".join(
        out[a:b] for a, b in zip([0] + [e for _, e in strip2], [s for s, _ in strip2] + [len(out)], strict=True)
    )
    assert kept == kept2


def test_a_note_is_an_end_of_line_comment():
    text = SAMPLE.read_text().replace("\n", "\r\n")
    read = read_urscript({"a.script": text})
    out = read.write({}, {2: "kept: unreachable"})["a.script"]
    line = out.split("\r\n")[9]
    assert line == "  pick = p[0.011206, 0.220488, 0.048684, -2.591996, -1.775151, 0.000000] # kept: unreachable"


# ------------------------------------------------------------------------------------------- round trip, fuzz
numbers = st.builds(lambda v, d: f"{v:.{d}f}", st.floats(-2.0, 2.0, allow_nan=False), st.integers(0, 8))
pose_text = st.lists(numbers, min_size=6, max_size=6).map(lambda v: "p[" + ", ".join(v) + "]")
joint_text = st.lists(numbers, min_size=6, max_size=6).map(lambda v: "[" + ",".join(v) + "]")
statement = st.one_of(
    pose_text.map(lambda p: f"movel({p}, a=1.2, v=0.25)"),
    joint_text.map(lambda q: f"movej({q})"),
    st.tuples(pose_text, pose_text).map(lambda p: f"movec({p[0]}, {p[1]}, r=0.0)"),
    pose_text.map(lambda p: f"set_tcp({p})"),
    pose_text.map(lambda p: f"frame = {p}"),
    pose_text.map(lambda p: f"movep(pose_trans(frame, {p}))"),
    st.text(st.characters(min_codepoint=32, max_codepoint=126), max_size=30).map(lambda c: f"# {c}"),
    st.just('textmsg("at [1, 2]", 3)'),
    st.just("if x > 2:\n    sleep(0.1)\n  end"),
)


@settings(max_examples=150)
@given(st.lists(statement, max_size=12), st.sampled_from(["\n", "\r\n"]))
def test_read_and_written_without_change_is_byte_identical(lines, eol):
    text = "def prog():" + eol + "".join(f"  {s}{eol}" for s in lines) + "end" + eol
    read = read_urscript({"p.script": text})
    assert read.write({}, {}) == {"p.script": text}
    for t in read.targets:  # a target's value written back holds the same numbers (to the decimals written)
        back = read_urscript({"p.script": read.write({0: t.value}, {})["p.script"]}) if t is read.targets[0] else None
        if back is not None:
            np.testing.assert_allclose(back.targets[0].value, t.value, atol=2e-3)


@settings(max_examples=300)
@given(st.text(max_size=200))
def test_anything_is_read_or_refused_in_one_line(text):
    try:
        read_urscript({"f.script": text})
    except ProgramReadError as exc:
        msg = str(exc)
        assert msg.startswith("f.script: line ") and "\n" not in msg


@pytest.mark.parametrize(
    ("text", "line", "what"),
    [
        ('def a():\n  textmsg("open\nend\n', 2, "closing quote"),
        ("def a():\n  movel(p[0.1, 0.2, 0.3, 0, 0, 0]\nend\n", 2, "never closed"),
        ("def a():\n  x = 1)\nend\n", 2, "closes nothing"),
        ("def a():\n\n  movel(p[0.1, 0.2, 0.3, 0, 0])\nend\n", 3, "needs 6 numbers, got 5"),
        ("def a():\n  movel(p[0.1, 0.2, 0.3, 0, 0, 0]) $\nend\n", 2, "unexpected character '$'"),
    ],
)
def test_broken_scripts_are_one_line_naming_the_line(text, line, what):
    with pytest.raises(ProgramReadError) as err:
        read_urscript({"b.script": text})
    assert str(err.value).startswith(f"b.script: line {line}: ") and what in str(err.value)


def test_poses_computed_at_run_time_are_not_targets():
    text = (
        "def a():\n  here = get_actual_tcp_pose()\n  movel(pose_add(here, p[0, 0, 0.1, 0, 0, 0]))\n  movel(here)\nend\n"
    )
    assert read_urscript({"a.script": text}).targets == []
