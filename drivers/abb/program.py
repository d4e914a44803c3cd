"""The RAPID module trackcal's ABB client drives the arm through (TrackcalRws.mod, loaded in task T_ROB1 and started
from its `main`): the same pattern as the KR C2's EKI program, a request, a move, an answer.

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
