"""The ABB RAPID program reader for program filtering: `read_rapid(files)` -> ProgramRead (drivers/program_text.py).

What is read (RobotWare 6 and 7 modules, `.mod`, `.modx`, and S4C `.prg`; layouts in rapid_values.py, syntax in
rapid_structure.py, tokens in rapid_tokens.py):
- every `robtarget` and `jointtarget` declared with a literal value (CONST, PERS or VAR; in a module or a routine; an
  array's elements one by one, named `path{2}`), and every inline literal of a move (named "line N");
- the moves MoveJ, MoveL, MoveC (its circle point and end point), MoveAbsJ and their DO/AO/GO/Sync forms: a
  Cartesian target takes the move's tool (tooldata: the TCP in ABB's wrist frame tool0, which WRIST_IN_FLANGE puts in
  the robot configs' flange frame) and work object (`\\WObj:=`, default wobj0): its base is uframe * oframe in the
  world frame, taken as the robot's base frame (the robot installed without a base frame offset in its system
  parameters); tool0 is the wrist frame itself, wobj0 the identity;
- the tooldata and wobjdata may be declared in another module of the same files (a user or system module); names
  are found as RAPID scopes them: the routine's own data, then its module's, then the global data of the others;
- `Offs(p, dx, dy, dz)` and `RelTool(p, dx, dy, dz ...)`: the robtarget p is the target, read and corrected once, and
  the move is reported (motion "MoveL Offs"). The offset points the controller computes from the corrected p get
  p's correction, not their own: Offs adds (dx, dy, dz) in the work object's frame, so an offset point moves by p's
  translation correction exactly, and its error is how much the robot's error changes over the offset distance;
  RelTool's offset is in p's tool frame, so it also turns with p's rotation correction (1e-4 rad over 100 mm: 10 um);
- a robtarget that no move of these files uses (passed to a routine, used in an expression) is a target with motion
  "": its tool and work object are not known, so it is read in wobj0 with tool0.
Not targets (left as written): a robtarget given by an expression (`:= Offs(p1, ...)`, CRobT()) and a move's target
written as one; program displacements (PDispOn/PDispSet, EOffsSet) are the controller's at run time, not read.
Refused with a one-line ProgramReadError: a stationary tool (tooldata robhold FALSE, wobjdata robhold TRUE), a
coordinated work object (ufprog FALSE, ufmec set), one robtarget used with two different tool/work object pairs (one
corrected value cannot serve both), a tool or work object a move names that the files do not declare.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from trackcal.drivers.abb.rapid_render import config_accepts, joint_renderer, robtarget_renderer
from trackcal.drivers.abb.rapid_structure import Declaration, Move, TargetArgument, Walker
from trackcal.drivers.abb.rapid_tokens import fail, tokenize
from trackcal.drivers.abb.rapid_values import Node, jointtarget, robtarget, tool_frame, value_of, work_object_frame
from trackcal.drivers.program_text import ProgramRead, ProgramTarget

IDENTITY = np.eye(4)
# ABB's wrist coordinate system (tool0, the frame a tooldata's tframe is given in) in the flange frame of the robot
# configs (configs/robots/irb120.yaml's last joint frame, ROS-Industrial's link_6: x along axis 6, z up at the
# calibration position). tool0 has z along axis 6 and x pointing down there: +90 deg about y (ROS-Industrial's ABB
# URDFs, joint_6-tool0 rpy (0, pi/2, 0); Susta79/RF210001 README: "ABB: tool0: Z forward, X downward = rotation of 90
# deg around Y of the base frame"). A ProgramTarget's `tool` is WRIST_IN_FLANGE @ tframe.
WRIST_IN_FLANGE = np.array([[0.0, 0, 1, 0], [0, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 0, 1]])
PREDEFINED = {"TOOL0": "TOOLDATA", "WOBJ0": "WOBJDATA"}  # the system's data: the flange, the world frame


@dataclass(frozen=True)
class _Use:
    """One move's use of a target: its motion label, the tool and work object (declarations, names), the frames."""

    label: str
    frames: tuple  # (tool declaration, work object declaration): two uses agree when these do
    names: tuple[str, str]  # (tool, work object) as the move writes them
    tool: np.ndarray
    base: np.ndarray
    line: int


@dataclass
class _Target:
    """A target being read: its literal, its name, and the moves using it."""

    file: str
    node: Node
    name: str
    joint: bool
    uses: list[_Use] = field(default_factory=list)


def read_rapid(files: dict[str, str]) -> ProgramRead:
    """Reads RAPID modules {file name: text}; the targets in file order, then text order."""
    declarations: list[Declaration] = []
    moves: list[Move] = []
    module = 0
    for name, text in files.items():
        walker = Walker(name, tokenize(name, text), module)
        module = walker.walk()
        declarations += walker.declarations
        moves += walker.moves
    scope = _Scope(declarations)
    targets = _declared_targets(declarations)
    for move in moves:
        _add_uses(scope, targets, move)
    order = {name: k for k, name in enumerate(files)}
    ordered = sorted(targets.values(), key=lambda t: (order[t.file], t.node.start))
    return ProgramRead("RAPID", dict(files), [_program_target(files, t) for t in ordered], "!")


class _Scope:
    """RAPID's name lookup over the declarations read (names are case-insensitive)."""

    def __init__(self, declarations: list[Declaration]) -> None:
        self.by_name: dict[str, list[Declaration]] = {}
        for d in declarations:
            self.by_name.setdefault(d.name.upper(), []).append(d)

    def find(self, name: str, file: str, module: int, routine: str | None, line: int) -> Declaration | None:
        """The declaration `name` means in (module, routine): the routine's own, the module's, else the one global
        declaration of another module (None when the files declare none)."""
        candidates = self.by_name.get(name.upper(), [])
        for d in candidates:
            if d.module == module and d.routine is not None and d.routine == routine:
                return d
        for d in candidates:
            if d.module == module and d.routine is None:
                return d
        others = [d for d in candidates if d.routine is None and not d.local]
        if len(others) > 1 and all(d.storage == "PERS" and _same(d.value, others[0].value) for d in others):
            return others[0]  # one persistent declared alike in several modules (RAPID allows it): one value
        if len(others) > 1:
            where = " and ".join(f"{d.file}:{d.line}" for d in others)
            raise fail(file, line, f"{name} is declared globally twice ({where})")
        return others[0] if others else None


def _same(a: Node | None, b: Node | None) -> bool:
    """Whether two literals hold the same values (their spelling aside)."""
    if a is None or b is None:
        return a is b
    if a.kind != b.kind or a.value != b.value or len(a.items) != len(b.items):
        return False
    return a.kind != "expr" and all(_same(x, y) for x, y in zip(a.items, b.items, strict=True))


def _declared_targets(declarations: list[Declaration]) -> dict[tuple, _Target]:
    """The targets of the robtarget and jointtarget declarations with a literal value, keyed by (declaration, index)."""
    out: dict[tuple, _Target] = {}
    for d in declarations:
        if d.type not in ("ROBTARGET", "JOINTTARGET") or d.value is None:
            continue
        for index, node in _elements(d, d.value, d.dims):
            name = d.name + ("{" + ",".join(map(str, index)) + "}" if index else "")
            joint = d.type == "JOINTTARGET"
            _check(d.file, node, name, joint)
            out[(id(d), index)] = _Target(d.file, node, name, joint)
    return out


def _elements(d: Declaration, node: Node, dims: int, index: tuple[int, ...] = ()) -> list[tuple[tuple, Node]]:
    """The elements of an array literal of `dims` dimensions with their 1-based indices (a scalar: one, index ())."""
    if dims == 0:
        return [(index, node)]
    if node.kind != "list":
        raise fail(d.file, node.line, f"expected an array literal [..] of {d.type.lower()} for {d.name}")
    return [e for k, item in enumerate(node.items, 1) for e in _elements(d, item, dims - 1, (*index, k))]


def _check(file: str, node: Node, name: str, joint: bool) -> None:
    """Reads the literal once so a malformed one fails where it is, used or not."""
    if joint:
        jointtarget(file, node, name)
    else:
        robtarget(file, node, name)


def _add_uses(scope: _Scope, targets: dict[tuple, _Target], move: Move) -> None:
    """Records on each target `move` names: the motion label and the frames it is used in."""
    frames = None
    for arg in move.targets:
        for key, target in _resolve(scope, targets, move, arg):
            label = f"{move.instruction} {arg.via}".strip()
            if target.joint != (not move.cartesian):
                continue  # a robtarget given to MoveAbsJ, a jointtarget to MoveL: RAPID refuses it; not a target here
            if frames is None:
                frames = _frames(scope, move) if move.cartesian else ((), ("", ""), IDENTITY, IDENTITY)
            targets.setdefault(key, target).uses.append(_Use(label, *frames, move.line))


def _resolve(scope: _Scope, targets: dict[tuple, _Target], move: Move, arg: TargetArgument) -> list:
    """The (key, target) pairs a move's target argument names: an inline literal's new target, or the declared
    target(s) of a name (every element when the array index is not a literal)."""
    if arg.node is not None:
        name = f"line {arg.line}"
        _check(move.file, arg.node, name, not move.cartesian)
        return [((move.file, arg.node.start), _Target(move.file, arg.node, name, not move.cartesian))]
    if arg.name is None or arg.name.upper in move.parameters:
        return []  # a parameter of the move's routine: the caller's data, not known here
    d = scope.find(arg.name.text, move.file, move.module, move.routine, move.line)
    if d is None or d.value is None:
        return []
    if arg.index is None or arg.index == ():
        return [(k, t) for k, t in targets.items() if k[0] == id(d)]
    return [((id(d), arg.index), targets[(id(d), arg.index)])] if (id(d), arg.index) in targets else []


def _frames(scope: _Scope, move: Move) -> tuple[tuple, tuple[str, str], np.ndarray, np.ndarray]:
    """(the tool's and work object's declarations, their names, tool frame, base frame) of a Cartesian move."""
    tool_d, tool = _frame_data(scope, move, move.tool.text, "TOOLDATA")
    wobj_name = move.wobj.text if move.wobj is not None else "wobj0"
    wobj_d, base = _frame_data(scope, move, wobj_name, "WOBJDATA")
    return (tool_d, wobj_d), (move.tool.text, wobj_name), tool, base


def _frame_data(scope: _Scope, move: Move, name: str, type_: str) -> tuple[int | str, np.ndarray]:
    """(identity of the declaration, frame) of the tool or work object `name` a move uses."""
    what = type_.lower()
    if name.upper() in move.parameters:
        raise fail(move.file, move.line, f"{move.instruction}'s {what} {name} is a parameter of its routine: its frame "
                                         "is not known from the program's text")  # fmt: skip
    d = scope.find(name, move.file, move.module, move.routine, move.line)
    if d is None and PREDEFINED.get(name.upper()) == type_:
        return name.upper(), WRIST_IN_FLANGE if type_ == "TOOLDATA" else IDENTITY
    if d is None:
        raise fail(move.file, move.line, f"{move.instruction} uses {what} {name}, which the files given do not declare "
                                         "(give the module that declares it too)")  # fmt: skip
    if d.type != type_ or d.dims:
        raise fail(move.file, move.line, f"{move.instruction} uses {name} as its {what}, declared as another type")
    if d.value is None:
        raise fail(move.file, move.line, f"{what} {name} has no literal value in the files (its frame is unknown)")
    if type_ == "TOOLDATA":
        return id(d), WRIST_IN_FLANGE @ tool_frame(d.file, d.value, d.name)
    return id(d), work_object_frame(d.file, d.value, d.name)


def _program_target(files: dict[str, str], t: _Target) -> ProgramTarget:
    """The ProgramTarget of a target read, with its one pair of frames (refusing a target used with two)."""
    tool, base = WRIST_IN_FLANGE, IDENTITY
    if t.uses:
        first = t.uses[0]
        other = next((u for u in t.uses if u.frames != first.frames), None)
        if other is not None:
            raise fail(t.file, other.line, f"{t.name} is used with tool {first.names[0]} in work object "
                                           f"{first.names[1]} (line {first.line}) and with tool {other.names[0]} in "
                                           f"{other.names[1]}: one corrected value cannot serve both")  # fmt: skip
        tool, base = first.tool, first.base
    motion = ", ".join(dict.fromkeys(u.label for u in t.uses))
    text = files[t.file][t.node.start : t.node.end]
    if t.joint:
        robax = jointtarget(t.file, t.node, t.name)
        value = np.array([value_of(n) for n in robax], dtype=float)
        render = joint_renderer(text, t.node.start, robax)
        return ProgramTarget(t.file, t.node.start, t.node.end, t.node.line, t.name, True, value, IDENTITY.copy(),
                             IDENTITY.copy(), (), _any_joints, render, motion)  # fmt: skip
    rt = robtarget(t.file, t.node, t.name)
    render = robtarget_renderer(text, t.node.start, rt.trans, rt.rot)
    return ProgramTarget(t.file, t.node.start, t.node.end, t.node.line, t.name, False, rt.pose, base.copy(),
                         tool.copy(), rt.config, config_accepts(rt.config), render, motion)  # fmt: skip


def _any_joints(q_deg: np.ndarray) -> bool:
    """A joint target carries no configuration: any joint values are its own."""
    return True
