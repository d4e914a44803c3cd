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
- a procedure call `MoveTo p10, tGripper, wobjTable;` to a PROC of the files: the moves of that PROC whose target,
  tool or work object are its parameters use the call's arguments (motion "MoveL via MoveTo"); one level deep (a
  parameter passed on again is not followed);
- a robtarget that no move of these files uses (used in an expression, passed on through two routines) is a target
  with motion "": its tool and work object are not known, so it is read in wobj0 with tool0.
Not targets (left as written): a robtarget given by an expression (`:= Offs(p1, ...)`, CRobT()) and a move's target
written as one; program displacements (PDispOn/PDispSet, EOffsSet) are the controller's at run time, not read.
Refused with a one-line ProgramReadError: a stationary tool (tooldata robhold FALSE, wobjdata robhold TRUE), a
coordinated work object (ufprog FALSE, ufmec set), one robtarget used with two different tool/work object pairs (one
corrected value cannot serve both), a tool or work object a move names that the files do not declare, a tool or work
object that is a routine's parameter when no call of the files gives it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from trackcal.drivers.abb.rapid_render import config_accepts, joint_renderer, robtarget_renderer
from trackcal.drivers.abb.rapid_structure import Call, Declaration, Move, Procedure, TargetArgument, Walker
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
    procedures: list[Procedure] = []
    calls: list[Call] = []
    module = 0
    for name, text in files.items():
        walker = Walker(name, tokenize(name, text), module)
        module = walker.walk()
        declarations += walker.declarations
        moves += walker.moves
        procedures += walker.procedures
        calls += walker.calls
    scope = _Scope(declarations)
    targets = _declared_targets(declarations)
    for key in targets:
        scope.elements.setdefault(key[0], []).append(key)
    for move in moves:
        if not _frames_are_parameters(move):
            _add_uses(scope, targets, move)
    given = set()  # the moves whose frames a call gave
    by_routine: dict[tuple, list[Move]] = {}
    for move in moves:
        by_routine.setdefault((move.module, move.routine), []).append(move)
    procedures_by_name: dict[str, list[Procedure]] = {}
    for p in procedures:
        procedures_by_name.setdefault(p.name.upper(), []).append(p)
    for call in calls:
        procedure = _procedure(procedures_by_name.get(call.name.upper, []), call)
        for move in by_routine.get((procedure.module, procedure.name.upper()), []) if procedure else []:
            _add_uses(scope, targets, move, call, procedure)
            given.add(id(move))
    for move in moves:
        if _frames_are_parameters(move) and id(move) not in given:
            _add_uses(scope, targets, move)  # its own targets with frames no call gives: refused (_frame_data)
    order = {name: k for k, name in enumerate(files)}
    ordered = sorted(targets.values(), key=lambda t: (order[t.file], t.node.start))
    return ProgramRead("RAPID", dict(files), [_program_target(files, t) for t in ordered], "!")


class _Scope:
    """RAPID's name lookup over the declarations read (names are case-insensitive)."""

    def __init__(self, declarations: list[Declaration]) -> None:
        self.by_name: dict[str, list[Declaration]] = {}
        self.elements: dict[int, list[tuple]] = {}  # a robtarget/jointtarget declaration -> its targets' keys
        self.frames: dict[int, np.ndarray] = {}  # a tooldata/wobjdata declaration -> its frame, read once
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


def _add_uses(
    scope: _Scope,
    targets: dict[tuple, _Target],
    move: Move,
    call: Call | None = None,
    procedure: Procedure | None = None,
) -> None:
    """Records on each target `move` names its motion label and the frames it is used in. With `call`, `move` sits in
    the called `procedure`: its targets, tool and work object that are the procedure's parameters are the call's
    arguments (looked up where the call is); its other targets are read only when its frames depend on the call."""
    frames = None
    for arg in move.targets:
        where, bound, via = _bound_target(move, arg, call, procedure)
        if bound is None:
            continue
        for key, target in _resolve(scope, targets, where, bound, move.cartesian):
            if target.joint != (not move.cartesian):
                continue  # a robtarget given to MoveAbsJ, a jointtarget to MoveL: RAPID refuses it; not a target here
            if frames is None:
                frames = _frames(scope, move, call, procedure) if move.cartesian else ((), ("", ""), IDENTITY, IDENTITY)
            label = " ".join(w for w in (move.instruction, via, f"via {call.instruction}" if call else "") if w)
            targets.setdefault(key, target).uses.append(_Use(label, *frames, where.line))


def _bound_target(
    move: Move, arg: TargetArgument, call: Call | None, procedure: Procedure | None
) -> tuple[Move | Call, TargetArgument | None, str]:
    """(where to look the target up, the target argument there or None to skip it, its offset function)."""
    if call is None or procedure is None:
        return move, arg, arg.via
    if arg.name is not None and arg.name.upper in procedure.positional:
        k = procedure.positional.index(arg.name.upper)
        given = call.targets[k] if k < len(call.targets) else None
        if given is None or (arg.via and given.via):
            return call, None, ""
        return call, given, arg.via or given.via
    return move, (arg if _frames_are_parameters(move) else None), arg.via


def _frames_are_parameters(move: Move) -> bool:
    """Whether a Cartesian move's tool or work object is a parameter of its routine (known only at a call)."""
    names = [move.tool] + ([move.wobj] if move.wobj is not None else [])
    return move.cartesian and any(t.upper in move.parameters for t in names)


def _resolve(
    scope: _Scope, targets: dict[tuple, _Target], where: Move | Call, arg: TargetArgument, cartesian: bool
) -> list:
    """The (key, target) pairs a target argument names where it is written: an inline literal's new target, or the
    declared target(s) of a name (every element when the array index is not a literal)."""
    if arg.node is not None:
        name = f"line {arg.line}"
        _check(where.file, arg.node, name, not cartesian)
        return [((where.file, arg.node.start), _Target(where.file, arg.node, name, not cartesian))]
    if arg.name is None or arg.name.upper in where.parameters:
        return []  # a parameter of the routine: the caller's data (read at the calls of the files)
    d = scope.find(arg.name.text, where.file, where.module, where.routine, where.line)
    if d is None or d.value is None:
        return []
    if arg.index is None or arg.index == ():
        return [(k, targets[k]) for k in scope.elements.get(id(d), [])]
    return [((id(d), arg.index), targets[(id(d), arg.index)])] if (id(d), arg.index) in targets else []


def _frames(
    scope: _Scope, move: Move, call: Call | None, procedure: Procedure | None
) -> tuple[tuple, tuple[str, str], np.ndarray, np.ndarray]:
    """(the tool's and work object's declarations, their names, tool frame, base frame) of a Cartesian move; a tool
    or work object that is a parameter of the called `procedure` is the `call`'s argument."""
    named = []
    for token, default in ((move.tool, ""), (move.wobj, "wobj0")):
        where, name = move, token.text if token is not None else default
        if call is not None and procedure is not None and name.upper() in procedure.positional:
            k = procedure.positional.index(name.upper())
            given = call.names[k] if k < len(call.names) else None
            if given is None:
                raise fail(
                    call.file,
                    call.line,
                    f"{call.instruction}'s argument for {name} is not a tooldata or "
                    "wobjdata name: its frame is not known from the text",
                )
            where, name = call, given.text
        named.append((where, name))
    (tool_where, tool_name), (wobj_where, wobj_name) = named
    tool_d, tool = _frame_data(scope, tool_where, tool_name, "TOOLDATA")
    wobj_d, base = _frame_data(scope, wobj_where, wobj_name, "WOBJDATA")
    return (tool_d, wobj_d), (tool_name, wobj_name), tool, base


def _frame_data(scope: _Scope, where: Move | Call, name: str, type_: str) -> tuple[int | str, np.ndarray]:
    """(identity of the declaration, frame) of the tool or work object `name` a move (or a call) names."""
    what = type_.lower()
    if name.upper() in where.parameters:
        raise fail(
            where.file,
            where.line,
            f"{where.instruction}'s {what} {name} is a parameter of its routine and no "
            "call in the files gives it: its frame is not known",
        )
    d = scope.find(name, where.file, where.module, where.routine, where.line)
    if d is None and PREDEFINED.get(name.upper()) == type_:
        return name.upper(), WRIST_IN_FLANGE if type_ == "TOOLDATA" else IDENTITY
    if d is None:
        raise fail(
            where.file,
            where.line,
            f"{where.instruction} uses {what} {name}, which the files given do not "
            "declare (give the module that declares it too)",
        )
    if d.type != type_ or d.dims:
        raise fail(where.file, where.line, f"{where.instruction} uses {name} as its {what}, declared as another type")
    if d.value is None:
        raise fail(where.file, where.line, f"{what} {name} has no literal value in the files (its frame is unknown)")
    if id(d) not in scope.frames:
        if type_ == "TOOLDATA":
            scope.frames[id(d)] = WRIST_IN_FLANGE @ tool_frame(d.file, d.value, d.name)
        else:
            scope.frames[id(d)] = work_object_frame(d.file, d.value, d.name)
    return id(d), scope.frames[id(d)]


def _procedure(named: list[Procedure], call: Call) -> Procedure | None:
    """The PROC a call names (`named`: the files' PROCs of that name): its own module's, else a global one (None:
    not in the files)."""
    return next((p for p in named if p.module == call.module), None) or next((p for p in named if not p.local), None)


def _program_target(files: dict[str, str], t: _Target) -> ProgramTarget:
    """The ProgramTarget of a target read, with its one pair of frames (refusing a target used with two)."""
    tool, base = WRIST_IN_FLANGE, IDENTITY
    if t.uses:
        first = t.uses[0]
        other = next((u for u in t.uses if u.frames != first.frames), None)
        if other is not None:
            raise fail(
                t.file,
                other.line,
                f"{t.name} is used with tool {first.names[0]} in work object "
                f"{first.names[1]} (line {first.line}) and with tool {other.names[0]} in "
                f"{other.names[1]}: one corrected value cannot serve both",
            )
        tool, base = first.tool, first.base
    motion = ", ".join(dict.fromkeys(u.label for u in t.uses))
    text = files[t.file][t.node.start : t.node.end]
    if t.joint:
        robax = jointtarget(t.file, t.node, t.name)
        value = np.array([value_of(n) for n in robax], dtype=float)
        render = joint_renderer(text, t.node.start, robax)
        return ProgramTarget(
            t.file,
            t.node.start,
            t.node.end,
            t.node.line,
            t.name,
            True,
            value,
            IDENTITY.copy(),
            IDENTITY.copy(),
            (),
            _any_joints,
            render,
            motion,
        )
    rt = robtarget(t.file, t.node, t.name)
    render = robtarget_renderer(text, t.node.start, rt.trans, rt.rot)
    return ProgramTarget(
        t.file,
        t.node.start,
        t.node.end,
        t.node.line,
        t.name,
        False,
        rt.pose,
        base.copy(),
        tool.copy(),
        rt.config,
        config_accepts(rt.config),
        render,
        motion,
    )


def _any_joints(q_deg: np.ndarray) -> bool:
    """A joint target carries no configuration: any joint values are its own."""
    return True
