"""The KRL program reader for program filtering (`trackcal filter`): a KUKA program (KR C2 / KSS 5.x, KR C4 /
KSS 8.x) as a ProgramRead, every target with its text's place, frames, status and turn.

`read_krl(files)` takes {name: text}: the program's `.src`, its `.dat` (same stem) when given, and the cell's
`$config.dat` (TOOL_DATA, BASE_DATA, XHOME ...) when given. The `.dat` files are read first ($config.dat, then the
others), then the `.src` line by line, in text order (the inline forms set their frames in each fold; calls to other
programs and control flow are not followed).

What is a target:
- a POS / E6POS / FRAME value (Cartesian: X, Y, Z mm, A, B, C deg as Rz(A) Ry(B) Rx(C), krl_values) or an AXIS /
  E6AXIS value (joint: A1..A6 deg; E1..E6 kept as written), declared (`DECL E6POS XP1={...}`, in a .dat or the .src),
  assigned (`XP1={...}`), or written inline in a move (`PTP {A1 0,...}`: named "line N");
- that a move uses: PTP, LIN, CIRC (the auxiliary and the end point), and KSS 8's SPTP, SLIN, SCIRC. A value is the
  one its variable holds at the move (`XP2 = XP1` makes XP1's value the one XP2 moves to). Joint values of the
  program's own files are targets even when no move uses them (motion ""); a Cartesian value no move uses is not
  (nothing says which frames it is in), nor is a value of `$config.dat` no move of the program uses;
- `motion`: the moves using it, comma-separated in order ("PTP", "PTP,LIN"). A relative move's value (PTP_REL,
  LIN_REL, ...: an offset, not a pose) and a value used inside an expression (`LIN XP1:{X 10}`) are listed but not
  filterable: their `accepts` accepts no joint values, so the filter keeps them as written; their motion reads
  "LIN_REL" or "LIN (expression)".
The frames rule: a Cartesian target's `base` is the $BASE in force at its moves and `tool` the $TOOL (krl_frames:
BASE_DATA / TOOL_DATA of $config.dat, a frame set in the program, BAS(#BASE, n), FDAT_ACT's BASE_NO / TOOL_NO);
$NULLFRAME and the flange (identity) where the program sets none. $WORLD is taken as the robot's base ($ROBROOT =
$NULLFRAME: $ROBROOT is machine data, not in these files). Refused, with a one-line ProgramReadError naming the file
and line (the safer choice: never a target read in frames it may not be in): a Cartesian target moved to in a frame
the given files do not define (BASE_DATA[3] without a $config.dat that has it) or that the reader cannot evaluate, in
an external-TCP mode (IPO_FRAME #TCP), or in two different frames (one taught value cannot be corrected for both).
`config` is (S, T), -1 for one not written; `accepts` checks them as krl_values.status_turn says.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from trackcal.drivers.kuka import krl_frames
from trackcal.drivers.kuka.krl_frames import NULL, Frame, FrameState
from trackcal.drivers.kuka.krl_tokens import Token, statements, tokenize, where
from trackcal.drivers.kuka.krl_values import (
    AXIS_KEYS,
    POSE_KEYS,
    Aggregate,
    parse_aggregate,
    renderer,
    rot_zyx,
    status_turn,
)
from trackcal.drivers.program_text import ProgramRead, ProgramReadError, ProgramTarget

POSITION_TYPES = {"POS": False, "E6POS": False, "FRAME": False, "AXIS": True, "E6AXIS": True}  # -> joint
TWO_POINTS = ("CIRC", "SCIRC", "CIRC_REL", "SCIRC_REL")
MOVES = ("PTP", "LIN", "SPTP", "SLIN", "PTP_REL", "LIN_REL", "SPTP_REL", "SLIN_REL", *TWO_POINTS)
TAIL = ("C_PTP", "C_DIS", "C_VEL", "C_ORI", "C_SPL", "CA", "WITH")  # words that may follow a move's points
FRAME_NAMES = ("$BASE", "$TOOL", "$IPO_MODE", "$ROBROOT", "FDAT_ACT")
BLOCKS = {"DEF": "END", "DEFFCT": "ENDFCT", "DEFDAT": "ENDDAT"}


@dataclass(frozen=True)
class _Use:
    file: str
    line: int
    motion: str
    base: Frame
    tool: Frame
    external: str
    plain: bool  # an absolute move to the value itself (not relative, not inside an expression)


@dataclass
class _Site:
    """A value written in the program: a declaration's, an assignment's or a move's aggregate."""

    file: str
    agg: Aggregate
    name: str
    joint: bool
    relative: bool = False
    uses: list[_Use] = field(default_factory=list)


def _never(q: np.ndarray) -> bool:
    return False


def _always(q: np.ndarray) -> bool:
    return True


class _Walk:
    """The program's statements followed in order: variables, frames, moves."""

    def __init__(self, files: dict[str, str]) -> None:
        self.files = files
        self.state = FrameState()
        self.variables: dict[str, _Site | None] = {}
        self.types: dict[str, str] = {}
        self.sites: list[_Site] = []

    def file(self, name: str) -> None:
        text = self.files[name]
        stmts = statements(tokenize(name, text))
        _check_blocks(name, stmts, max(1, text.count("\n") + (not text.endswith("\n"))))
        for toks in stmts:
            self.statement(name, toks, text)

    def statement(self, file: str, toks: list[Token], text: str) -> None:
        _expression_end(file, toks, 0, ())  # every line's brackets pair up
        words = [t.upper for t in toks]
        head = words[1] if words[0] == "GLOBAL" and len(words) > 1 else words[0]
        if head in BLOCKS or head in BLOCKS.values() or head in ("STRUC", "ENUM", "EXT", "EXTFCT"):
            return
        if _is_declaration(toks, words):
            self.declaration(file, toks, text)
        elif head in MOVES:
            self.move(file, toks, text)
        elif head == "BAS" and len(toks) > 2 and toks[1].text == "(" and toks[-1].text == ")":
            krl_frames.bas_call(toks[2:-1], self.state)
        else:
            eq = _assignment(toks)
            if eq:
                self.assignment(file, toks, eq, text)

    def declaration(self, file: str, toks: list[Token], text: str) -> None:
        j = 0
        while j < len(toks) and toks[j].upper in ("GLOBAL", "DECL", "CONST"):
            j += 1
        if j + 1 >= len(toks) or toks[j].kind != "name":
            raise ProgramReadError(f"{where(file, toks[0].line)}: expected a type and a name after DECL")
        kind = toks[j].upper
        j += 1
        while True:
            if j >= len(toks) or toks[j].kind != "name":
                raise ProgramReadError(f"{where(file, toks[0].line)}: expected a name in the {kind} declaration")
            key = toks[j].upper
            self.types[key] = kind
            self.variables[key] = None
            j += 1
            if j < len(toks) and toks[j].text == "[":
                j = _skip_group(file, toks, j)
            if j < len(toks) and toks[j].text == "=":
                end = _expression_end(file, toks, j + 1, (",",))
                self.value(file, key, kind, toks[j + 1 : end], text)
                j = end
            if j == len(toks):
                return
            if toks[j].text != ",":
                raise ProgramReadError(
                    f"{where(file, toks[j].line)}: expected , = or the line's end in the {kind} "
                    f"declaration, got {toks[j].text!r}"
                )
            j += 1

    def value(self, file: str, key: str, kind: str, rhs: list[Token], text: str) -> None:
        """`key` (a variable, or an array element "NAME[2]") now holds `rhs`."""
        self.state.data.pop(key, None)
        self.variables[key] = None
        if rhs and rhs[0].text == "{":
            agg, j = parse_aggregate(file, rhs, 0, text)
            if j != len(rhs):
                return  # an aggregate in an expression: a computed value
            self.state.data[key] = agg
            joint = POSITION_TYPES.get(kind)
            if joint is not None and agg.has_all(AXIS_KEYS if joint else POSE_KEYS):
                self.variables[key] = _Site(file, agg, key, joint)
                self.sites.append(self.variables[key])  # type: ignore[arg-type]
        elif len(rhs) == 1 and rhs[0].kind == "name":
            self.variables[key] = self.variables.get(rhs[0].upper)
            if rhs[0].upper in self.state.data:
                self.state.data[key] = self.state.data[rhs[0].upper]

    def assignment(self, file: str, toks: list[Token], eq: int, text: str) -> None:
        lhs = toks[:eq]
        name = lhs[0].upper
        if [t.upper for t in lhs] == [name] and name in FRAME_NAMES:
            krl_frames.assign(file, name, toks[eq + 1 :], text, self.state)
            return
        if len(lhs) == 1 or (len(lhs) == 4 and lhs[1].text == "[" and lhs[2].text.isdigit() and lhs[3].text == "]"):
            key = name if len(lhs) == 1 else f"{name}[{int(lhs[2].text)}]"
            self.value(file, key, self.types.get(name, ""), toks[eq + 1 :], text)
        else:  # a member or an element computed (XP1.X = ...): the variable's value is the program's, not ours
            self.variables.pop(name, None)
            self.state.data.pop(name, None)

    def move(self, file: str, toks: list[Token], text: str) -> None:
        word = toks[0].upper
        frames = krl_frames.with_clause(file, _with_pairs(file, toks), text, self.state)
        j = 1
        for k in range(2 if word in TWO_POINTS else 1):
            if k:
                if j >= len(toks) or toks[j].text != ",":
                    raise ProgramReadError(
                        f"{where(file, toks[0].line)}: expected , and the end point after "
                        f"{toks[0].text}'s auxiliary point"
                    )
                j += 1
            if j >= len(toks) or toks[j].upper in TAIL or toks[j].text == ",":
                raise ProgramReadError(f"{where(file, toks[0].line)}: expected a point after {toks[0].text}")
            j = self.point(file, toks, j, word, text, frames)

    def point(
        self, file: str, toks: list[Token], j: int, word: str, text: str, frames: tuple[Frame, Frame, str]
    ) -> int:
        """Record the point starting at toks[j] of a `word` move in `frames` (base, tool, external TCP); the index
        after it."""
        end = _expression_end(file, toks, j, (",", *TAIL), stop_enum=True)
        part = toks[j:end]
        relative = word.endswith("_REL")
        use = _Use(file, toks[0].line, word, *frames, not relative)
        if part[0].text == "{" and part[-1].text == "}" and parse_aggregate(file, part, 0, text)[1] == len(part):
            agg = parse_aggregate(file, part, 0, text)[0]
            joint = agg.has_all(AXIS_KEYS)
            if joint or agg.has_all(POSE_KEYS) or relative:
                site = _Site(file, agg, f"line {agg.line}", joint, relative, [use])
                self.sites.append(site)
            return end
        key = _plain_name(part)
        if key is not None:
            site = self.variables.get(key)
            if site is not None:
                site.uses.append(use)
            return end
        if len(part) > 3 and part[0].kind == "name" and part[1].text == "[" and _skip_group(file, part, 1) == len(part):
            elements = f"{part[0].upper}["  # an element by a computed index (a loop's): each element may be it
            for name, site in self.variables.items():
                if name.startswith(elements) and site is not None:
                    site.uses.append(use)
            return end
        for tok in part:  # an expression: the values it names are used, not moved to as written
            site = self.variables.get(tok.upper) if tok.kind == "name" else None
            if site is not None:
                site.uses.append(_Use(file, use.line, f"{word} (expression)", use.base, use.tool, use.external, False))
        return end


def _with_pairs(file: str, toks: list[Token]) -> list[tuple[str, list[Token]]]:
    """The (system variable, value tokens) a spline move's `WITH $A = x, $B = y` assigns; [] without WITH."""
    words = [t.upper for t in toks]
    if "WITH" not in words:
        return []
    j, out = words.index("WITH") + 1, []
    while j < len(toks):
        end = _expression_end(file, toks, j, (",",))
        part = toks[j:end]
        eq = _assignment(part)
        if eq:
            out.append(("".join(t.upper for t in part[:eq]), part[eq + 1 :]))
        j = end + 1
    return out


def _is_declaration(toks: list[Token], words: list[str]) -> bool:
    """DECL ..., or a declaration of a position or inline-form data type without DECL (`E6POS XP1={...}`)."""
    j = 1 if words[0] == "GLOBAL" else 0
    if j < len(words) and words[j] == "DECL":
        return True
    typed = j < len(words) and (words[j] in POSITION_TYPES or words[j] in ("FDAT", "PDAT", "LDAT"))
    return typed and j + 1 < len(toks) and toks[j + 1].kind == "name"


def _plain_name(part: list[Token]) -> str | None:
    """NAME or NAME[n] as a variable key, None for anything else."""
    if len(part) == 1 and part[0].kind == "name":
        return part[0].upper
    if (
        len(part) == 4
        and part[0].kind == "name"
        and part[1].text == "["
        and part[2].text.isdigit()
        and part[3].text == "]"
    ):
        return f"{part[0].upper}[{int(part[2].text)}]"
    return None


def _skip_group(file: str, toks: list[Token], j: int) -> int:
    """The index after the bracket group opened at toks[j]."""
    return _expression_end(file, toks, j, (), stop_enum=False, one_group=True)


CLOSE = {"(": ")", "[": "]", "{": "}"}


def _expression_end(
    file: str, toks: list[Token], j: int, stops: tuple[str, ...], stop_enum: bool = False, one_group: bool = False
) -> int:
    """Index of the first token from j at bracket depth 0 whose upper text is in `stops` (or an ENUM when
    `stop_enum`), or of the line's end; brackets must match (ProgramReadError otherwise)."""
    depth: list[Token] = []
    for k in range(j, len(toks)):
        tok = toks[k]
        if not depth and (tok.upper in stops or (stop_enum and tok.kind == "enum")) and k > j:
            return k
        if tok.text in CLOSE:
            depth.append(tok)
        elif tok.text in CLOSE.values():
            if not depth or CLOSE[depth[-1].text] != tok.text:
                want = f"{CLOSE[depth[-1].text]!r}" if depth else "no closing bracket"
                raise ProgramReadError(f"{where(file, tok.line)}: expected {want}, got {tok.text!r}")
            depth.pop()
            if one_group and not depth:
                return k + 1
    if depth:
        raise ProgramReadError(
            f"{where(file, depth[-1].line)}: expected {CLOSE[depth[-1].text]!r} to close "
            f"{depth[-1].text!r} before the line's end"
        )
    return len(toks)


def _assignment(toks: list[Token]) -> int:
    """Index of the `=` of `lvalue = ...` (lvalue: a name, its [..] elements and .members), 0 when not one."""
    j = 0
    while j < len(toks) and toks[j].kind == "name":
        j += 1
        while j < len(toks) and toks[j].text == "[":
            depth, k = 0, j
            while k < len(toks):
                depth += (toks[k].text == "[") - (toks[k].text == "]")
                k += 1
                if depth == 0:
                    break
            j = k
        if j < len(toks) and toks[j].text == ".":
            j += 1
            continue
        break
    return j if 0 < j < len(toks) and toks[j].text == "=" else 0


def _check_blocks(file: str, stmts: list[list[Token]], last_line: int) -> None:
    """DEF/END, DEFFCT/ENDFCT and DEFDAT/ENDDAT pair up; nothing stands outside them."""
    open_: tuple[str, int] | None = None
    for toks in stmts:
        words = [t.upper for t in toks]
        head = words[1] if words[0] == "GLOBAL" and len(words) > 1 else words[0]
        if head in BLOCKS:
            if open_:
                raise ProgramReadError(
                    f"{where(file, toks[0].line)}: expected {open_[0]} (for line {open_[1]}) before {toks[0].text}"
                )
            if len(toks) < 2 + (words[0] == "GLOBAL") or toks[1 + (words[0] == "GLOBAL")].kind != "name":
                raise ProgramReadError(f"{where(file, toks[0].line)}: expected a name after {head}")
            open_ = (BLOCKS[head], toks[0].line)
        elif head in BLOCKS.values():
            if not open_ or open_[0] != head:
                want = f"{open_[0]} (for line {open_[1]})" if open_ else "DEF, DEFFCT or DEFDAT first"
                raise ProgramReadError(f"{where(file, toks[0].line)}: expected {want}, got {toks[0].text}")
            open_ = None
        elif not open_:
            raise ProgramReadError(
                f"{where(file, toks[0].line)}: expected DEF, DEFFCT or DEFDAT before {toks[0].text!r}"
            )
    if open_:
        raise ProgramReadError(
            f"{where(file, last_line)}: expected {open_[0]} (for line {open_[1]}) before the file's end"
        )


def _config(site: _Site) -> tuple[int, int]:
    """(S, T) of a Cartesian value, -1 for one not written."""
    out = []
    for key, top in (("S", 255), ("T", 255)):
        m = site.agg.members.get(key)
        if m is None:
            out.append(-1)
            continue
        v = m.value if m.kind in ("number", "bits") else None
        if v is None or v != int(v) or not 0 <= v <= top:  # type: ignore[operator, arg-type]
            raise ProgramReadError(
                f"{where(site.file, site.agg.line)}: {key} of {site.name} must be a whole "
                f"number 0..{top} or a bit pattern like 'B010', got {m.text!r}"
            )
        out.append(int(v))  # type: ignore[call-overload]
    return out[0], out[1]


def _same(a: Frame, b: Frame) -> bool:
    return a.pose is not None and b.pose is not None and bool(np.array_equal(a.pose, b.pose))


def _frames(site: _Site) -> tuple[np.ndarray, np.ndarray]:
    """(base, tool) of a Cartesian target moved to as written; ProgramReadError when not one known pair."""
    first = None
    for u in site.uses:
        if not u.plain:
            continue
        at = f"{where(u.file, u.line)}: {site.name}'s {u.motion}"
        if u.external:
            raise ProgramReadError(f"{at} runs with an external tool ({u.external}): not read")
        for what, frame in (("base", u.base), ("tool", u.tool)):
            if frame.pose is None:
                raise ProgramReadError(f"{at}: its {what} is {frame.label}")
        if first is None:
            first = u
        elif not (_same(u.base, first.base) and _same(u.tool, first.tool)):
            raise ProgramReadError(
                f"{at} is in base {u.base.label}, tool {u.tool.label}, and at line {first.line} "
                f"in base {first.base.label}, tool {first.tool.label}: one taught value cannot "
                "be corrected for both"
            )
    return (NULL, NULL) if first is None else (first.base.pose, first.tool.pose)  # type: ignore[return-value]


def _target(site: _Site, text: str, config_file: bool) -> ProgramTarget | None:
    if not site.uses and (config_file or not site.joint):
        return None
    fixed = site.relative or any(not u.plain for u in site.uses)
    motion = ",".join(dict.fromkeys(u.motion for u in site.uses))
    keys = AXIS_KEYS if site.joint else POSE_KEYS
    source = text[site.agg.start : site.agg.end]
    render = (lambda v: source) if site.relative else renderer(site.agg, text, keys, site.joint)
    values = [site.agg.number(k) or 0.0 for k in keys]
    if site.joint or fixed:
        value = np.array(values) if site.joint else _pose(values)
        return ProgramTarget(
            site.file,
            site.agg.start,
            site.agg.end,
            site.agg.line,
            site.name,
            site.joint,
            value,
            NULL.copy(),
            NULL.copy(),
            (),
            _never if fixed else _always,
            render,
            motion,
        )
    base, tool = _frames(site)
    s, t = _config(site)
    return ProgramTarget(
        site.file,
        site.agg.start,
        site.agg.end,
        site.agg.line,
        site.name,
        False,
        _pose(values),
        base.copy(),
        tool.copy(),
        (s, t),
        status_turn(None if s < 0 else s, None if t < 0 else t),
        render,
        motion,
    )


def _pose(values: list[float]) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = rot_zyx(*values[3:6])
    out[:3, 3] = values[:3]
    return out


def _order(name: str) -> int:
    low = name.lower()
    return 0 if low.endswith("$config.dat") else 1 if low.endswith(".dat") else 2


def read_krl(files: dict[str, str]) -> ProgramRead:
    """The program `files` ({name: text}) as read; ProgramReadError (file:line: what was expected) otherwise."""
    walk = _Walk(files)
    for name in sorted(files, key=_order):
        walk.file(name)
    targets = [_target(s, files[s.file], _order(s.file) == 0) for s in walk.sites]
    names = list(files)
    found = sorted((t for t in targets if t is not None), key=lambda t: (names.index(t.file), t.start))
    return ProgramRead(language="KRL", files=dict(files), targets=found, comment=";")
