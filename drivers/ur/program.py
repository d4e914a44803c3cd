"""Universal Robots URScript programs of joint moves: NAME.script, one `movej` per target (compensated, or nominal with
a comment saying why it is not).

What the generated text relies on (Universal Robots, "The URScript Programming Language", module motion):
- a program is a function `def NAME():` ... `end`, its body indented, `#` starting a comment; a name is a letter
  first, then letters, digits and underscores (the language's identifiers);
- `movej(q, a=1.4, v=1.05, t=0, r=0)`: q the 6 joint positions in radians as a list, a the joint acceleration
  (rad/s2) and v the joint speed (rad/s) of the leading axis, r = 0 a stop at the target; the defaults 1.4 rad/s2
  and 1.05 rad/s are those of the manual, which `speed_pct` scales (as the KRL program's $VEL_AXIS / $ACC_AXIS
  percentages do, drivers/kuka/program.py).
The targets are those of the KRL program, row for row (campaign/jobs/compensate.py: every row, compensated or
nominal, rounded to the 1e-4 deg the controller reports), written in radians with 10 decimals (1e-10 rad: far below
the 1e-4 deg = 1.7e-6 rad step), each under a comment with its name and its degrees. This module makes the text;
the caller writes it (trackcal compensate, atomically).
"""

from __future__ import annotations

import math
import re

from trackcal.drivers.errors import ProgramError
from trackcal.drivers.families import ProgramWriter, comment_text, program_notes, program_targets

NAME_RE = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,62}")
AXES = 6
MOVEJ_A_RAD_S2, MOVEJ_V_RAD_S = 1.4, 1.05  # the URScript manual's movej defaults


class UrScriptError(ProgramError):
    """A program that cannot be written; the message says why."""


def check_name(name: str) -> str:
    if not isinstance(name, str) or not NAME_RE.fullmatch(name):
        raise UrScriptError(
            f"URScript program name {name!r} is not valid: a letter first, then letters, digits or _ "
            "(at most 63 characters)"
        )
    return name


def urscript_text(
    name: str, q_deg, speed_pct: int = 10, points: list[str] | None = None, notes: list[str | None] | None = None
) -> str:
    """The program moving with movej through the rows of q_deg (N, 6) in degrees; `points` name the rows in a
    comment each; `notes[i]`, when not None, one more comment line above row i's move (a target left at its nominal
    angles says so and why)."""
    check_name(name)
    q, pct = program_targets(q_deg, speed_pct, "UR", AXES, "joint angles", "joint", UrScriptError)
    f = pct / 100.0
    a, v = f"{MOVEJ_A_RAD_S2 * f:.4f}", f"{MOVEJ_V_RAD_S * f:.4f}"
    points = points or [f"P{k + 1}" for k in range(len(q))]
    if len(points) != len(q):
        raise UrScriptError(f"one name per target expected, got {len(points)} for {len(q)}")
    notes = program_notes(notes, len(q), UrScriptError)
    nominal = sum(t is not None for t in notes)
    what = (
        f"{len(q)} compensated joint targets"
        if not nominal
        else f"{len(q)} joint targets, {len(q) - nominal} compensated, {nominal} NOT compensated (nominal)"
    )
    lines = [
        f"def {name}():",
        f"  # trackcal: {what}, movej at {int(speed_pct)} % of {MOVEJ_V_RAD_S} rad/s and {MOVEJ_A_RAD_S2} rad/s2",
    ]
    for p, row, note in zip(points, q, notes, strict=True):
        rad = ", ".join(_rad(x) for x in row)
        lines += [f"  # {comment_text(p)}: {note}"] if note is not None else []
        lines.append(f"  # {comment_text(p)}: {', '.join(f'{x:.4f}' for x in row)} deg")
        lines.append(f"  movej([{rad}], a={a}, v={v})")
    lines.append("end")
    return "\n".join(lines) + "\n"


def _rad(deg: float) -> str:
    text = f"{math.radians(deg):.10f}"
    return "0.0000000000" if text == "-0.0000000000" else text


def labels(names: list[str] | None, n: int) -> list[str]:
    """The rows' names in the program's comments: the targets' own (P1..Pn without names; the text keeps printable
    ASCII, others -> _)."""
    return [(names[k] if names else "").strip() or f"P{k + 1}" for k in range(n)]


def texts(
    name: str, q_deg, speed_pct: int = 10, points: list[str] | None = None, notes: list[str | None] | None = None
) -> dict[str, bytes]:
    """{NAME.script: its bytes}: ASCII, LF."""
    return {f"{name}.script": urscript_text(name, q_deg, speed_pct, points, notes).encode("ascii")}


PROGRAM = ProgramWriter(language="URScript", check_name=check_name, labels=labels, texts=texts)
