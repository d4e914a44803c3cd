"""KRL aggregate values (`{X 1.0,Y 2.0,...}`): read from tokens with every member's place, turned into poses, and
written back with only the position members changed.

Conventions (public sources):
- POS / E6POS / FRAME: X, Y, Z in mm and A, B, C in degrees, the orientation being Rz(A) Ry(B) Rx(C) (rotations
  about Z, then the new Y, then the new X): RoboDK's "KUKA_2_Pose"/"Pose_2_KUKA" (RoboDK/RoboDK-API,
  Matlab/Pose_2_KUKA.m: "the Euler conversion used is the same one used by KUKA KRC controllers",
  A = atan2(r21, r11), B = atan2(-r31, sqrt(r11^2 + r21^2)), C = atan2(r32, r33)).
- AXIS / E6AXIS: A1..A6 in degrees (E1..E6 the external axes, kept as written).
- S (status) and T (turn) of a POS / E6POS, from the KUKA Robot Forum thread "KUKA KR5 Status and Turn bits"
  (robot-forum.com, thread 13092; the KSS manuals' table restated) and ISG's "Status & Turn" page (same definitions):
  T bit i (i = 0..5) is 1 when A(i+1) < 0, 0 when A(i+1) >= 0;
  S bit 0 is 0 when the wrist point (where A4, A5, A6 meet) has a positive x in the A1 frame (the robot root's frame
  turned with A1): the basic area; 1 in the overhead area;
  S bit 1 is 1 when A3 >= phi, phi being the angle at which the wrist point lies on the line through A2 and A3
  (0 deg when A3 and A4 do not have an offset; a few degrees on arms with one: it depends on the robot type);
  S bit 2 is 1 when -180 <= A5 < 0 or A5 >= 180, 0 when 0 <= A5 < 180 or A5 < -180.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from trackcal.drivers.kuka.krl_tokens import Token, where
from trackcal.drivers.program_text import ProgramReadError

POSE_KEYS = ("X", "Y", "Z", "A", "B", "C")
AXIS_KEYS = ("A1", "A2", "A3", "A4", "A5", "A6")
# S bit 1 flips at phi, which depends on the arm's A3-A4 offset (a few degrees: atan(41 / 1200) = 2 deg on the
# KR 270 of the paper); within this band of A3 = 0 both values are accepted (the arm is near its stretched position)
PHI_BAND_DEG = 10.0
# S bit 0 from the joints alone: the wrist point is certainly in the basic area (x > 0 in the A1 frame) when the
# upper arm (A2: 0 horizontal forward, -90 deg up) and the forearm (A2 + A3 up to the offset's phi) both point
# forward, the shoulder offset being >= 0 on KUKA's arms; this margin keeps phi and the offset inside
FORWARD_MARGIN_DEG = 10.0


@dataclass(frozen=True)
class Member:
    name: str  # upper case
    kind: str  # number, bits, string, enum, name, aggregate
    value: object  # float (number), int (bits), str, or an Aggregate
    start: int  # the value's text (a number's sign included)
    end: int
    text: str


@dataclass(frozen=True)
class Aggregate:
    start: int  # text[start:end] is `{...}`
    end: int
    line: int
    members: dict[str, Member]

    def number(self, key: str) -> float | None:
        m = self.members.get(key)
        return float(m.value) if m is not None and m.kind == "number" else None  # type: ignore[arg-type]

    def has_all(self, keys: tuple[str, ...]) -> bool:
        return all(self.number(k) is not None for k in keys)


def _value(file: str, toks: list[Token], i: int, text: str) -> tuple[str, object, int, int]:
    """(kind, value, start, next index) of the member value starting at toks[i]."""
    if i >= len(toks):
        raise ProgramReadError(f"{where(file, toks[-1].line)}: expected a value before the line's end")
    tok = toks[i]
    if tok.text == "{":
        agg, j = parse_aggregate(file, toks, i, text)
        return "aggregate", agg, tok.start, j
    if tok.text in ("+", "-") and i + 1 < len(toks) and toks[i + 1].kind == "number":
        v = _finite(file, toks[i + 1])
        return "number", -v if tok.text == "-" else v, tok.start, i + 2
    if tok.kind == "number":
        return "number", _finite(file, tok), tok.start, i + 1
    if tok.kind == "bits":
        return "bits", int(tok.text[2:-1], 2 if tok.text[1] in "Bb" else 16), tok.start, i + 1
    if tok.kind in ("string", "enum", "name"):
        return tok.kind, tok.text, tok.start, i + 1
    raise ProgramReadError(f"{where(file, tok.line)}: expected a value, got {tok.text!r}")


def _finite(file: str, tok: Token) -> float:
    v = float(tok.text)
    if not math.isfinite(v):
        raise ProgramReadError(f"{where(file, tok.line)}: the number {tok.text} is out of range")
    return v


def parse_aggregate(file: str, toks: list[Token], i: int, text: str) -> tuple[Aggregate, int]:
    """The aggregate `{[TYPE:] NAME value, ...}` starting at toks[i] == "{" and the index after its `}`."""
    line = toks[i].line
    j = i + 1
    if j + 1 < len(toks) and toks[j].kind == "name" and toks[j + 1].text == ":":
        j += 2  # a typed aggregate {E6POS: X 1, ...}
    members: dict[str, Member] = {}
    while True:
        if j >= len(toks):
            raise ProgramReadError(f"{where(file, line)}: expected }} to close the aggregate opened here")
        if toks[j].text == "}" and not members:
            return Aggregate(toks[i].start, toks[j].end, line, members), j + 1
        name = toks[j]
        if name.kind != "name":
            raise ProgramReadError(
                f"{where(file, name.line)}: expected a member name in the aggregate, got {name.text!r}"
            )
        j += 1
        if j + 1 < len(toks) and toks[j].text == "[" and toks[j + 1].text == "]":
            j += 2  # an array member given whole: POINT2[] " "
        kind, value, start, j = _value(file, toks, j, text)
        if name.upper in members:
            raise ProgramReadError(f"{where(file, name.line)}: member {name.text} given twice in the aggregate")
        members[name.upper] = Member(name.upper, kind, value, start, toks[j - 1].end, text[start : toks[j - 1].end])
        if j < len(toks) and toks[j].text == "}":
            return Aggregate(toks[i].start, toks[j].end, line, members), j + 1
        if j >= len(toks) or toks[j].text != ",":
            got = toks[j].text if j < len(toks) else "the line's end"
            raise ProgramReadError(f"{where(file, name.line)}: expected , or }} after member {name.text}, got {got!r}")
        j += 1


def rot_zyx(a_deg: float, b_deg: float, c_deg: float) -> np.ndarray:
    """Rz(A) Ry(B) Rx(C), KUKA's orientation of A, B, C (degrees)."""
    a, b, c = np.radians([a_deg, b_deg, c_deg])
    rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    rx = np.array([[1, 0, 0], [0, np.cos(c), -np.sin(c)], [0, np.sin(c), np.cos(c)]])
    return rz @ ry @ rx


def pose_of(agg: Aggregate) -> np.ndarray:
    """4 x 4 pose (mm) of an aggregate with X, Y, Z, A, B, C."""
    x, y, z, a, b, c = (agg.number(k) for k in POSE_KEYS)
    out = np.eye(4)
    out[:3, :3] = rot_zyx(a, b, c)  # type: ignore[arg-type]
    out[:3, 3] = [x, y, z]
    return out


def _wrap(angle: float, near: float) -> float:
    """angle + k 360 (deg) nearest `near` (180, not -180, next to a written 180), within [-180, 180] up to rounding."""
    out = angle + 360.0 * round((near - angle) / 360.0)
    return out if abs(out) <= 180.0 + 1e-6 else (out + 180.0) % 360.0 - 180.0


def abc_of(rot: np.ndarray, near: tuple[float, float, float]) -> tuple[float, float, float]:
    """A, B, C (deg) of a rotation: of its two ZYX solutions (and at B = +-90 deg, A kept at `near`'s), the one
    nearest `near` (the value it replaces), so a small correction gives small changes of the written angles."""
    cb = math.hypot(rot[0, 0], rot[1, 0])
    first = math.atan2(rot[1, 0], rot[0, 0]) if cb > 1e-9 else math.radians(near[0])
    best: tuple[float, ...] = (0.0, 0.0, 0.0)
    cost = math.inf
    for a in (first, first + math.pi) if cb > 1e-9 else (first,):
        m = np.array([[math.cos(a), math.sin(a), 0], [-math.sin(a), math.cos(a), 0], [0, 0, 1]]) @ rot  # Rz(-A) R
        b, c = math.atan2(-m[2, 0], m[0, 0]), math.atan2(-m[1, 2], m[1, 1])
        abc = (math.degrees(a), math.degrees(b), math.degrees(c))
        abc = tuple(_wrap(v, n) for v, n in zip(abc, near, strict=True))
        d = sum(abs((v - n + 180.0) % 360.0 - 180.0) for v, n in zip(abc, near, strict=True))
        if d < cost:
            best, cost = abc, d
    return best[0], best[1], best[2]


def _number_text(v: float, source: str, minimum: int) -> str:
    """v written with the source number's decimals, at least `minimum`; never -0."""
    digits = source.lstrip("+- ").split("E")[0].split("e")[0]
    decimals = max(minimum, len(digits.partition(".")[2]))
    out = f"{v:.{decimals}f}"
    return out[1:] if out.startswith("-") and float(out) == 0.0 else out


def renderer(agg: Aggregate, text: str, keys: tuple[str, ...], joint: bool) -> Callable[[np.ndarray], str]:
    """value -> the aggregate's text with the members `keys` rewritten, every other byte as it was. A pose value is
    4 x 4 (mm) and written as X..C (mm with 4 decimals at least, degrees with 5); joint values are A1..A6 (5)."""
    source = text[agg.start : agg.end]
    near = tuple(agg.number(k) for k in ("A", "B", "C")) if not joint else ()

    def render(value: np.ndarray) -> str:
        v = np.asarray(value, dtype=float)
        if v.shape != ((6,) if joint else (4, 4)) or not np.all(np.isfinite(v)):
            raise ProgramReadError(
                f"line {agg.line}: a {'6 joint values' if joint else '4 x 4 pose'} value expected, got shape {v.shape}"
            )
        numbers = list(v) if joint else [*v[:3, 3], *abc_of(v[:3, :3], near)]  # type: ignore[arg-type]
        out, last = [], agg.start
        for key, number in sorted(zip(keys, numbers, strict=True), key=lambda kv: agg.members[kv[0]].start):
            m = agg.members[key]
            minimum = 5 if joint or key in ("A", "B", "C") else 4
            out += [text[last : m.start], _number_text(float(number), m.text, minimum)]
            last = m.end
        out.append(text[last : agg.end])
        return "".join(out) if out else source

    return render


def _bit(v: int, i: int) -> int:
    return (v >> i) & 1


def status_turn(s: int | None, t: int | None) -> Callable[[np.ndarray], bool]:
    """accepts(q_deg): whether joint values (A1..A6, deg) are in the configuration S, T (None: not given, any).
    T and S bit 2 are checked exactly; S bit 1 outside +-PHI_BAND_DEG of A3 = 0; S bit 0 only where the joints alone
    decide it (both arm links pointing forward: the basic area); elsewhere bit 0 needs the arm's lengths and is not
    checked (the filter takes the accepted solution nearest the target's own)."""

    def accepts(q_deg: np.ndarray) -> bool:
        q = np.asarray(q_deg, dtype=float).ravel()
        if q.size < 6 or not np.all(np.isfinite(q[:6])):
            return False
        if t is not None and any(_bit(t, i) != (q[i] < 0) for i in range(6)):
            return False
        if s is None:
            return True
        a2, a3, a5 = q[1], q[2], q[4]
        if _bit(s, 2) != ((-180.0 <= a5 < 0.0) or a5 >= 180.0):
            return False
        if abs(a3) >= PHI_BAND_DEG and _bit(s, 1) != (a3 >= 0.0):
            return False
        forearm = (a2 + a3 + 180.0) % 360.0 - 180.0
        forward = math.cos(math.radians(a2)) >= 0.0 and abs(forearm) <= 90.0 - FORWARD_MARGIN_DEG
        return not (forward and _bit(s, 0) == 1)

    return accepts
