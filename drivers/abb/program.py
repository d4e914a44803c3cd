"""RAPID for the ABB family: the module trackcal's ABB client drives the arm through (TrackcalRws.mod, loaded in task
T_ROB1 and started from its `main`: the same pattern as the KR C2's EKI program, a request, a move, an answer), and the
program of compensated joint targets (`trackcal compensate --program NAME`: NAME.mod, PROGRAM below).

- `trackcal_target` (PERS jointtarget): the move's target, written by trackcal over RWS;
- `trackcal_speed` (PERS num): the speed override, percent of the programmed speed (VelSet);
- `trackcal_move` (PERS num): the request, the move's number, written last;
- `trackcal_done` (PERS num): the answer, set to the move's number once MoveAbsJ ... fine has ended (zone `fine`:
  the arm stands in the target, the controller's own in-position check).

RAPID semantics relied on (ABB, "Technical reference manual - RAPID Instructions, Functions and Data types",
3HAC050917-001): a PERS variable keeps its value in the module and is readable and writable over RWS
(`/rw/rapid/symbol/data/RAPID/T_ROB1/<module>/<name>`, Robot Web Services manual, "Update rapid variable current
value"); `jointtarget` is [[rax_1..rax_6],[eax_a..eax_f]] in degrees, 9E9 for an absent external axis; MoveAbsJ moves
joint-interpolated to a jointtarget; `fine` ends the move with the arm standing; VelSet Override, Max scales the
programmed speed by Override percent; `WaitUntil cond \\PollRate` polls a condition. `v5000` is a predefined
speeddata (5000 mm/s TCP, every axis at most its maximum), so the override sets the share of the axes' maxima.

A stop is RWS's `rw/rapid/execution?action=stop` (stopmode=stop: the move ramps down on its path, drives stay on);
before RAPID starts again trackcal resets the program pointer to `main` and sets trackcal_done to trackcal_move, so
the stopped move is not resumed (drivers.abb.client).
"""

from __future__ import annotations

import re

from trackcal.drivers.errors import ProgramError
from trackcal.drivers.families import ProgramWriter, program_names, program_notes, program_targets

MODULE = "TrackcalRws"
TASK = "T_ROB1"
TARGET, SPEED, MOVE, DONE = "trackcal_target", "trackcal_speed", "trackcal_move", "trackcal_done"
NO_AXIS = "9E+09"  # an absent external axis of a jointtarget (RAPID's 9E9)
EOL = "\r\n"  # RobotStudio and the FlexPendant save modules with CR LF


def joint_value(q_deg) -> str:
    """A jointtarget's RAPID value: six robot axes at 4 decimals (the interface's 0.0001 deg), no external axes."""
    axes = ",".join("0.0000" if f"{v:.4f}" == "-0.0000" else f"{v:.4f}" for v in q_deg)
    return f"[[{axes}],[{','.join([NO_AXIS] * 6)}]]"


def module_text(home_deg=(0.0, 0.0, 0.0, 0.0, 30.0, 0.0)) -> str:
    """TrackcalRws.mod: the motion server trackcal talks to over RWS."""
    lines = [
        f"MODULE {MODULE}",
        "  ! trackcal: joint moves requested over Robot Web Services (drivers/abb/program.py)",
        f"  PERS jointtarget {TARGET} := {joint_value(home_deg)};",
        f"  PERS num {SPEED} := 10;",
        f"  PERS num {MOVE} := 0;",
        f"  PERS num {DONE} := 0;",
        "  PROC main()",
        "    WHILE TRUE DO",
        f"      WaitUntil {MOVE} <> {DONE} \\PollRate:=0.01;",
        f"      VelSet {SPEED}, 5000;",
        f"      MoveAbsJ {TARGET}, v5000, fine, tool0;",
        f"      {DONE} := {MOVE};",
        "    ENDWHILE",
        "  ENDPROC",
        "ENDMODULE",
    ]
    return EOL.join(lines) + EOL


def symbol_path(name: str) -> str:
    """The RWS resource of one of the module's variables."""
    return f"rw/rapid/symbol/data/RAPID/{TASK}/{MODULE}/{name}"


# RAPID identifiers: a letter, then letters, digits or underscores, at most 32 characters, case-insensitive (RAPID
# manual, "Basic RAPID programming", identifiers)
NAME_RE = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,31}")


class RapidError(ProgramError):
    """A RAPID program that cannot be written; the message says why."""


def check_name(name: str) -> str:
    if not isinstance(name, str) or not NAME_RE.fullmatch(name):
        raise RapidError(
            f"RAPID module name {name!r} is not valid: at most 32 characters, a letter first, then letters, digits or _"
        )
    return name


def target_names(names: list[str] | None, n: int) -> list[str]:
    """RAPID names of the targets' jointtargets: J and the target's name made an identifier (unique without regard to
    case, at most 32 characters), or J1..Jn for targets without a name."""
    return program_names(names, n, "J", "J", 32)


def texts(
    name: str, q_deg, speed_pct: int = 10, labels: list[str] | None = None, notes: list[str | None] | None = None
) -> dict[str, bytes]:
    """{NAME.mod: its bytes}: a module whose `main` moves MoveAbsJ ... fine through the rows of q_deg (N, 6) at
    speed_pct % of v5000 (VelSet), each target a CONST jointtarget; `notes[i]` a comment above row i's move."""
    check_name(name)
    q, pct = program_targets(q_deg, speed_pct, "ABB", 6, "axis angles rax_1..rax_6", "VelSet", RapidError)
    labels = labels or target_names(None, len(q))
    if (
        len(labels) != len(q)
        or not all(NAME_RE.fullmatch(t) for t in labels)
        or len({t.upper() for t in labels}) != len(labels)
    ):
        raise RapidError(f"one valid RAPID name per target expected (unique without regard to case), got {labels!r}")
    notes = program_notes(notes, len(q), RapidError)
    nominal = sum(t is not None for t in notes)
    what = (
        f"{len(q)} compensated joint targets"
        if not nominal
        else f"{len(q)} joint targets, {len(q) - nominal} compensated, {nominal} NOT compensated (nominal)"
    )
    lines = [f"MODULE {name}", f"  ! trackcal: {what}, MoveAbsJ at {pct} % speed"]
    lines += [f"  CONST jointtarget {t} := {joint_value(row)};" for t, row in zip(labels, q, strict=True)]
    lines += ["  PROC main()", f"    VelSet {pct}, 5000;"]
    for t, note in zip(labels, notes, strict=True):
        lines += [f"    ! {t}: {note}"] if note is not None else []
        lines.append(f"    MoveAbsJ {t}, v5000, fine, tool0;")
    lines += ["  ENDPROC", "ENDMODULE"]
    return {f"{name}.mod": (EOL.join(lines) + EOL).encode("ascii")}


PROGRAM = ProgramWriter(language="RAPID", check_name=check_name, labels=target_names, texts=texts)
