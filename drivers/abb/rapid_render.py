"""A corrected target written back as RAPID text, and the robot configuration (confdata) a set of joints is in.

Rendering replaces only the numbers of a target's literal: a robtarget's trans (mm) and rot (quaternion), a
jointtarget's robax (degrees). Everything else of the literal (robconf, extax, spaces, line breaks, comments inside
it) stays byte for byte. RAPID's `num` is a 32-bit float (RAPID kernel manual, 3HAC050946-001, "num data type": 6 to
7 significant digits), so more decimals than these would not reach the controller: 4 decimals for mm (rounding
<= 0.05 um, under the float's own 0.06 um at 1 m), 8 for a quaternion's components (rotation <= 2e-8 rad), 5 for
degrees (<= 5e-6 deg, 9e-8 rad). Trailing zeros are dropped (`600`, `225.3`), as RobotStudio writes them.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from trackcal.drivers.abb.rapid_values import Node, matrix_quaternion, value_of
from trackcal.drivers.program_text import ProgramReadError

MM_DECIMALS = 4
QUATERNION_DECIMALS = 8
DEGREE_DECIMALS = 5


def number_text(value: float, decimals: int) -> str:
    """`value` rounded to `decimals`, trailing zeros and a bare point dropped, never "-0"."""
    text = f"{round(float(value), decimals) + 0.0:.{decimals}f}"
    text = text.rstrip("0").rstrip(".") if "." in text else text
    return "0" if text in ("", "-0") else text


def _replace(text: str, offset: int, leaves: list[Node], new: list[str]) -> str:
    """`text` (the file's text from `offset`) with each leaf's span replaced by its new text."""
    for leaf, value in sorted(zip(leaves, new, strict=True), key=lambda p: p[0].start, reverse=True):
        text = text[: leaf.start - offset] + value + text[leaf.end - offset :]
    return text


def robtarget_renderer(text: str, offset: int, trans: list[Node], rot: list[Node]) -> Callable[[np.ndarray], str]:
    """render(pose 4 x 4, mm) -> the robtarget literal `text` (which starts at `offset` of its file) with trans and
    rot replaced. The quaternion keeps the source's hemisphere (q and -q are the same rotation: the sign whose dot
    product with the source's is not negative), so a target read and rendered unchanged reads the same."""
    source = np.array([value_of(n) for n in rot], dtype=float)

    def render(value: np.ndarray) -> str:
        pose = np.asarray(value, dtype=float)
        if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
            raise ProgramReadError(f"a robtarget's corrected value must be a finite 4 x 4 pose, got shape {pose.shape}")
        q = matrix_quaternion(pose[:3, :3])
        q = -q if float(q @ source) < 0 else q
        new = [number_text(v, MM_DECIMALS) for v in pose[:3, 3]] + [number_text(v, QUATERNION_DECIMALS) for v in q]
        return _replace(text, offset, trans + rot, new)

    return render


def joint_renderer(text: str, offset: int, robax: list[Node]) -> Callable[[np.ndarray], str]:
    """render(joints (6,), degrees) -> the jointtarget literal `text` with its robax replaced (extax kept)."""

    def render(value: np.ndarray) -> str:
        q = np.asarray(value, dtype=float).ravel()
        if q.shape != (len(robax),) or not np.all(np.isfinite(q)):
            raise ProgramReadError(f"a jointtarget's corrected value must be {len(robax)} finite angles, got {q.shape}")
        return _replace(text, offset, robax, [number_text(v, DEGREE_DECIMALS) for v in q])

    return render


BOUNDARY_DEG = 1e-6  # rounding of an angle at a quadrant's end (far below the 1e-5 deg the jointtargets carry)


def quadrant(angle_deg: float) -> int:
    """The quadrant of an axis angle as confdata numbers it: 0 for [0, 90) deg, 1 for [90, 180), -1 for [-90, 0) ..."""
    return math.floor(angle_deg / 90.0)


def in_quadrant(angle_deg: float, cf: int) -> bool:
    """Whether an angle is in quadrant `cf`, an angle within BOUNDARY_DEG of the quadrant's ends counting as in it: a
    target written at a boundary (axis 4 at 0 deg, common) comes back from an inverse kinematics as -1e-13 deg."""
    return cf * 90.0 - BOUNDARY_DEG <= angle_deg < (cf + 1) * 90.0 + BOUNDARY_DEG


def config_accepts(config: tuple[int, int, int, int]) -> Callable[[np.ndarray], bool]:
    """accepts(joints deg) -> whether the joints are in the robconf `config` = (cf1, cf4, cf6, cfx).

    The rule (ABB, "RAPID Instructions, Functions and Data types", 3HAC050917-001, data type confdata, serial
    six-axis robots; its table of cfx is reproduced in CEAD-group/py-opw-kinematics AXIS_CONFIGURATION.md):
    - cf1, cf4, cf6 are the quadrants of axes 1, 4 and 6: quadrant 0 is the first quarter turn 0..90 deg in the positive
      direction, 1 the next (90..180), -1 the quarter 0..-90 deg, and so on (`quadrant`);
    - cfx (0..7) names one of eight arm configurations: 4 if the wrist centre is behind axis 1, + 2 if it is behind
      the lower arm, + 1 if axis 5's angle is negative.
    Checked here: cf1, cf4, cf6, and cfx's axis 5 bit (an angle of exactly 0, the wrist singularity, passes either
    way). The two wrist-centre bits depend on the arm's geometry (where the wrist centre is relative to axis 1 and
    the lower arm), not on joint values alone, so they are not checked: the filter picks the nearest of the solutions
    this accepts, which keeps the arm configuration unless a correction crosses a shoulder or elbow singularity."""
    cf1, cf4, cf6, cfx = config

    def accepts(q_deg: np.ndarray) -> bool:
        q = np.asarray(q_deg, dtype=float).ravel()
        if q.shape[0] < 6 or not np.all(np.isfinite(q[:6])):
            return False
        wrist_flip = bool(q[4] < 0) if abs(q[4]) > BOUNDARY_DEG else bool(cfx & 1)
        return all(in_quadrant(q[j], cf) for j, cf in ((0, cf1), (3, cf4), (5, cf6))) and wrist_flip == bool(cfx & 1)

    return accepts
