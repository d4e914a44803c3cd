"""KUKA KR C2 (KSS 5.x) programs of axis-specific PTP motions: NAME.src and NAME.dat.

What the generated text relies on (checked against public material, not against a controller):
- a KRL program is a pair of files with the same name, the motions in NAME.src (DEF NAME() ... END) and
  the permanent data in NAME.dat (DEFDAT NAME PUBLIC ... ENDDAT) (Wikipedia "KUKA Robot Language");
- axis positions as the E6AXIS structure {A1 .., A6 .., E1 .., E6 ..}, the robot axes A1-A6 and the external
  axes E1-E6 (same article; a KSS 5.x inline-form generator writes `DECL E6AXIS X..={A1 ..,..,A6 ..,E1 0.0,
  E2 0.0,E3 0.0,E4 0.0,E5 0.0,E6 0.0}` in the .dat and `PTP X..` in the .src, and declares
  `EXT BAS (BAS_COMMAND :IN,REAL :IN )` in the .dat as the KUKA template does);
- `BAS(#INITMOV,0)` initialises the motion parameters, after which `$VEL_AXIS[i]` / `$ACC_AXIS[i]` (integer
  percentages of the axis maxima) override the PTP speed and acceleration: the KRL post-processor of
  visose/Robots (Robots/RobotKUKA.cs) writes exactly this sequence for KUKA controllers.
- KRL names: at most 24 characters, a letter first, then letters, digits and underscores (KUKA system
  software naming rule, as given to this project; KRL is not case-sensitive).
Files are written with CR LF line ends, as the Windows-based KR C2 editor saves them. This module makes the texts;
the caller writes them (trackcal compensate, atomically).
"""

from __future__ import annotations

import re

from trackcal.drivers.errors import ProgramError
from trackcal.drivers.families import ProgramWriter, program_names, program_notes, program_targets

NAME_RE = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,23}")
AXES = 6
EOL = "\r\n"


class KrlError(ProgramError):
    """A program that cannot be written; the message says why."""


def check_name(name: str) -> str:
    if not isinstance(name, str) or not NAME_RE.fullmatch(name):
        raise KrlError(
            f"KRL program name {name!r} is not valid: at most 24 characters, a letter first, then letters, digits or _"
        )
    return name


def point_names(names: list[str] | None, n: int) -> list[str]:
    """KRL names of the targets' E6AXIS data: X (the prefix KSS inline forms give point data) and the target's
    name made a KRL name (other characters -> _, at most 24 characters, unique without regard to case), or
    XP1..XPn for targets without a name."""
    return program_names(names, n, "X", "XP", 24)


def _angle(v: float) -> str:
    text = f"{v:.4f}"
    return "0.0000" if text == "-0.0000" else text


def krl_texts(
    name: str, q_deg, speed_pct: int = 10, points: list[str] | None = None, notes: list[str | None] | None = None
) -> tuple[str, str]:
    """(src, dat) texts of a program moving PTP through the rows of q_deg (N, 6) in degrees; `points` are the
    rows' KRL names (`point_names`; default XP1..XPn); `notes[i]`, when not None, a comment line above row i's PTP
    (a target left at its nominal angles says so and why)."""
    check_name(name)
    q, pct = program_targets(q_deg, speed_pct, "KR C2", AXES, "axis angles A1..A6", "axis", KrlError)
    points = points or point_names(None, len(q))
    if len(points) != len(q) or not all(NAME_RE.fullmatch(p) for p in points):
        raise KrlError(f"one valid KRL name per target expected, got {points!r}")
    notes = program_notes(notes, len(q), KrlError)
    nominal = sum(t is not None for t in notes)
    what = (
        f"{len(q)} compensated joint targets"
        if not nominal
        else f"{len(q)} joint targets, {len(q) - nominal} compensated, {nominal} NOT compensated (nominal)"
    )
    src = [f"DEF {name}()", f"; trackcal: {what}, PTP at {pct} % axis speed", "BAS(#INITMOV,0)"]
    src += [f"$VEL_AXIS[{i}]={pct}" for i in range(1, AXES + 1)]
    src += [f"$ACC_AXIS[{i}]={pct}" for i in range(1, AXES + 1)]
    for p, note in zip(points, notes, strict=True):
        src += [f"; {p}: {note}"] if note is not None else []
        src.append(f"PTP {p}")
    src.append("END")
    dat = [f"DEFDAT {name} PUBLIC", "EXT BAS (BAS_COMMAND :IN,REAL :IN )"]
    for p, row in zip(points, q, strict=True):
        axes = ",".join(f"A{i + 1} {_angle(v)}" for i, v in enumerate(row))
        dat.append(f"DECL E6AXIS {p}={{{axes},E1 0.0,E2 0.0,E3 0.0,E4 0.0,E5 0.0,E6 0.0}}")
    dat.append("ENDDAT")
    return EOL.join(src) + EOL, EOL.join(dat) + EOL


def texts(
    name: str, q_deg, speed_pct: int = 10, points: list[str] | None = None, notes: list[str | None] | None = None
) -> dict[str, bytes]:
    """{NAME.src, NAME.dat: their bytes}: ASCII, CR LF."""
    src, dat = krl_texts(name, q_deg, speed_pct, points, notes)
    return {f"{name}.src": src.encode("ascii"), f"{name}.dat": dat.encode("ascii")}


PROGRAM = ProgramWriter(language="KRL", check_name=check_name, labels=point_names, texts=texts)
