"""URScript programs read for filtering (`trackcal filter`): their targets, their tool and feature frames.

What the reader relies on (Universal Robots, "The URScript Programming Language", 3.x/5.x, modules motion and math):
- a pose literal is `p[x, y, z, rx, ry, rz]`: a position in metres and a rotation vector (axis times angle, rad);
  a joint position is a list `[q1, .., q6]` in radians;
- `movej(q, a, v, t, r)`, `movel(pose, a, v, t, r)`, `movep(pose, a, v, r)`: q or pose the target (movej takes a pose
  as well: the controller's IK then picks the solution nearest the current joints); `movec(pose_via, pose_to, a, v,
  r, mode)`: both poses are targets;
- `set_tcp(pose)`: the TCP in the tool flange frame for the moves that follow;
- `pose_trans(p_from, p_from_to)`: p_from_to expressed in the frame p_from (a feature plane taught on the pendant is
  a pose variable: `pose_trans(feature, p[...])` is the target in the feature);
- `#` starts a comment to the line's end; names are letters, digits and underscores; strings are in double or single
  quotes; `name = value` assigns (optionally after `global` or `local`).
Everything else (logic, speeds, blends, function calls) is kept as text; a pose that is not a literal (computed at run
time, e.g. `get_actual_tcp_pose()`) is not a target. A variable holding a literal that several moves use is one
target (its literal is written once); the frames of its first use are its own. Control flow is read in text order.
"""

from __future__ import annotations

import bisect
import re
from dataclasses import dataclass

import numpy as np

from trackcal.drivers.program_text import ProgramRead, ProgramReadError, ProgramTarget

LANGUAGE = "URScript"
MOVES = ("movej", "movel", "movep", "movec")
MIN_DECIMALS = 6  # written values carry at least 1e-6 m (1 um) and 1e-6 rad
_TOKEN = re.compile(
    r"(?P<space>[ \t\f\v\r\n]+)|(?P<comment>#[^\r\n]*)"
    r"|(?P<number>(?:\d+\.\d*|\.\d+|\d+)(?:[eE][+-]?\d+)?)|(?P<name>[A-Za-z_][A-Za-z0-9_]*)"
    r"|(?P<string>\"(?:[^\"\\\r\n]|\\.)*\"|'(?:[^'\\\r\n]|\\.)*')|(?P<op>[()\[\]{},:=+\-*/%<>!.&|^~;@])"
)
_CLOSE = {"(": ")", "[": "]", "{": "}"}


@dataclass(frozen=True)
class Token:
    kind: str  # number, name, string, op
    text: str
    start: int
    end: int


@dataclass
class Literal:
    """A list of numbers in the text: a pose `p[...]` (pose True) or a joint list `[...]`."""

    pose: bool
    spans: list[tuple[int, int]]  # each number's text (its sign included)
    values: list[float]
    start: int  # first number's start, last number's end: the text a corrected value replaces
    end: int
    name: str  # the variable's name, "" inline


class _Lines:
    def __init__(self, file: str, text: str) -> None:
        self.file, self.starts = file, [0] + [m.end() for m in re.finditer(r"\n", text)]

    def of(self, pos: int) -> int:
        return bisect.bisect_right(self.starts, pos)

    def error(self, pos: int, what: str) -> ProgramReadError:
        return ProgramReadError(f"{self.file}: line {self.of(pos)}: {what}")


def tokenize(file: str, text: str) -> list[Token]:
    """The tokens of a script (spaces and comments dropped), brackets checked; ProgramReadError names the line."""
    lines, out, stack, pos = _Lines(file, text), [], [], 0
    while pos < len(text):
        m = _TOKEN.match(text, pos)
        if m is None:
            ch = text[pos]
            what = "a string without its closing quote" if ch in "\"'" else f"unexpected character {ch!r}"
            raise lines.error(pos, what)
        kind = m.lastgroup or ""
        if kind not in ("space", "comment"):
            tok = Token(kind, m.group(), m.start(), m.end())
            if tok.text in _CLOSE:
                stack.append(tok)
            elif tok.text in _CLOSE.values():
                if not stack or _CLOSE[stack[-1].text] != tok.text:
                    raise lines.error(tok.start, f"{tok.text!r} closes nothing open")
                stack.pop()
            out.append(tok)
        pos = m.end()
    if stack:
        raise lines.error(stack[-1].start, f"{stack[-1].text!r} is never closed")
    return out


def _decimals(text: str) -> int:
    mantissa = text.lstrip("+-").split("e")[0].split("E")[0]
    return len(mantissa.split(".")[1]) if "." in mantissa else 0


def _number_list(toks: list[Token], i: int) -> tuple[list[tuple[int, int]], list[float], int] | None:
    """At toks[i] == '[': (spans, values, index after ']') when the list holds only signed numbers, else None."""
    spans, values, j = [], [], i + 1
    while j < len(toks):
        sign = toks[j].text if toks[j].text in "+-" and toks[j].kind == "op" else ""
        k = j + (1 if sign else 0)
        if k >= len(toks) or toks[k].kind != "number":
            return None
        spans.append((toks[j].start, toks[k].end))
        values.append(float(sign + toks[k].text))
        nxt = toks[k + 1].text if k + 1 < len(toks) else ""
        if nxt == "]":
            return spans, values, k + 2
        if nxt != ",":
            return None
        j = k + 2
    return None


def _literal(toks: list[Token], i: int, lines: _Lines, name: str = "") -> tuple[Literal | None, int]:
    """(the literal at toks[i] (`p[` or `[`), index after it) or (None, i) when there is none there."""
    pose = toks[i].text == "p" and i + 1 < len(toks) and toks[i + 1].text == "["
    at = i + 1 if pose else i
    if at >= len(toks) or toks[at].text != "[":
        return None, i
    got = _number_list(toks, at)
    if got is None:
        return None, i
    spans, values, after = got
    if len(values) != 6:
        if pose:
            raise lines.error(toks[i].start, f"a pose p[x, y, z, rx, ry, rz] needs 6 numbers, got {len(values)}")
        return None, i  # a list of other length: no joint position
    return Literal(pose, spans, values, spans[0][0], spans[-1][1], name), after


def _arguments(toks: list[Token], i: int) -> tuple[list[tuple[int, int]], int]:
    """At toks[i] == '(': the top-level arguments as token index ranges [a, b), and the index after ')'."""
    args, depth, first = [], 0, i + 1
    for j in range(i, len(toks)):
        t = toks[j].text
        if t in _CLOSE:
            depth += 1
        elif t in _CLOSE.values():
            depth -= 1
            if depth == 0:
                args.append((first, j))
                return [a for a in args if a[0] < a[1]], j + 1
        elif t == "," and depth == 1:
            args.append((first, j))
            first = j + 1
    return args, len(toks)  # unreachable after tokenize's bracket check


@dataclass
class _Scan:
    """The state of a script's scan: pose/list variables, the current TCP, the targets found (by literal)."""

    toks: list[Token]
    lines: _Lines
    variables: dict[str, Literal]
    tool: np.ndarray
    used: dict[int, tuple[Literal, np.ndarray, np.ndarray, str]]  # id(literal) -> (literal, base, tool, motion)

    def value(self, a: int, b: int) -> Literal | None:
        """The literal an argument toks[a:b] is: inline or a variable's."""
        if b - a == 1 and self.toks[a].kind == "name":
            return self.variables.get(self.toks[a].text)
        lit, after = _literal(self.toks, a, self.lines)
        return lit if lit is not None and after == b else None

    def target(self, a: int, b: int, motion: str) -> None:
        """An argument of a move: a literal, a variable, or pose_trans(feature, pose)."""
        base = np.eye(4)
        toks = self.toks
        if b - a > 3 and toks[a].text == "pose_trans" and toks[a + 1].text == "(":
            inner, after = _arguments(toks, a + 1)
            if after != b or len(inner) != 2:
                return
            feature = self.value(*inner[0])
            if feature is None or not feature.pose:
                return
            base, (a, b) = pose_matrix(feature.values), inner[1]
        lit = self.value(a, b)
        if lit is not None and id(lit) not in self.used and (lit.pose or np.array_equal(base, np.eye(4))):
            self.used[id(lit)] = (lit, base, self.tool, motion)


def _scan(file: str, text: str) -> _Scan:
    toks = tokenize(file, text)
    scan = _Scan(toks, _Lines(file, text), {}, np.eye(4), {})
    i = 0
    while i < len(toks):
        t = toks[i]
        nxt = toks[i + 1].text if i + 1 < len(toks) else ""
        if t.kind == "name" and nxt == "=" and i + 2 < len(toks) and toks[i + 2].text != "=":
            lit, after = _literal(toks, i + 2, scan.lines, t.text)
            if lit is not None:
                scan.variables[t.text] = lit
                i = after
                continue
            scan.variables.pop(t.text, None)  # reassigned to something that is no literal
        elif t.kind == "name" and nxt == "(" and t.text in (*MOVES, "set_tcp"):
            args, after = _arguments(toks, i + 1)
            if t.text == "set_tcp":
                tcp = scan.value(*args[0]) if args else None
                scan.tool = pose_matrix(tcp.values) if tcp is not None and tcp.pose else scan.tool
            else:
                for a, b in args[: 2 if t.text == "movec" else 1]:
                    scan.target(a, b, t.text)
        i += 1
    return scan


def pose_matrix(values) -> np.ndarray:
    """4 x 4 (mm) of a URScript pose [x, y, z (m), rx, ry, rz (rotation vector, rad)]."""
    x = np.asarray(values, dtype=float)
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = _exp(x[3:]), 1000.0 * x[:3]
    return out


def _exp(w: np.ndarray) -> np.ndarray:
    angle = float(np.linalg.norm(w))
    k = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    if angle < 1e-12:
        return np.eye(3) + k
    return np.eye(3) + np.sin(angle) / angle * k + (1.0 - np.cos(angle)) / angle**2 * (k @ k)


def pose_values(m: np.ndarray, near=None) -> np.ndarray:
    """[x, y, z (m), rx, ry, rz] of a 4 x 4 pose (mm): the rotation vector of angle in [0, pi], or the same rotation's
    vector of angle 2 pi - angle about the opposite axis when that one is nearer the rotation vector `near` (the
    source's: a half turn written as -2.59, -1.78, 0 stays so)."""
    r = np.asarray(m, dtype=float)[:3, :3]
    s = 0.5 * np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    c = 0.5 * (np.trace(r) - 1.0)
    angle = float(np.arctan2(np.linalg.norm(s), c))
    if angle < 1e-12:
        w = s
    elif np.pi - angle < 1e-6:  # near a half turn: the axis from the symmetric part
        b = 0.5 * (r + np.eye(3))
        axis = b[int(np.argmax(np.diag(b)))]
        axis = axis / np.linalg.norm(axis)
        w = angle * (axis if axis @ s >= 0 else -axis)
    else:
        w = angle / np.sin(angle) * s
    if near is not None and angle > 1e-12:
        other = w * (1.0 - 2.0 * np.pi / angle)
        w = other if np.linalg.norm(other - near) < np.linalg.norm(w - near) else w
    return np.concatenate([np.asarray(m, dtype=float)[:3, 3] / 1000.0, w])


def _renderer(text: str, lit: Literal):
    """The literal's replacement text for a corrected value: the source's separators, each number with the source's
    decimals (at least MIN_DECIMALS)."""
    seps = [text[e:s] for (_, e), (s, _) in zip(lit.spans, lit.spans[1:], strict=False)]
    decimals = [max(_decimals(text[s:e]), MIN_DECIMALS) for s, e in lit.spans]

    def render(value: np.ndarray) -> str:
        nums = pose_values(value, lit.values[3:]) if lit.pose else np.radians(np.asarray(value, dtype=float))
        parts = [f"{v:.{d}f}" for v, d in zip(nums, decimals, strict=True)]
        parts = [p[1:] if p.startswith("-") and float(p) == 0.0 else p for p in parts]
        return "".join(p + s for p, s in zip(parts, [*seps, ""], strict=True))

    return render


def read_urscript(files: dict[str, str]) -> ProgramRead:
    """Every file of a URScript program read (module docstring); ProgramReadError names the file and the line of
    what cannot be read."""
    targets = []
    for file, text in files.items():
        if not isinstance(text, str):
            raise ProgramReadError(f"{file}: not a text")
        scan = _scan(file, text)
        for lit, base, tool, motion in sorted(scan.used.values(), key=lambda u: u[0].start):
            line = scan.lines.of(lit.start)
            value = pose_matrix(lit.values) if lit.pose else np.degrees(lit.values)
            targets.append(
                ProgramTarget(
                    file=file,
                    start=lit.start,
                    end=lit.end,
                    line=line,
                    name=lit.name or f"line {line}",
                    joint=not lit.pose,
                    value=value,
                    base=base,
                    tool=tool,
                    config=(),
                    accepts=lambda q: True,
                    render=_renderer(text, lit),
                    motion=motion,
                )
            )
    return ProgramRead(language=LANGUAGE, files=dict(files), targets=targets, comment="#")
