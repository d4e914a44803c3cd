"""RAPID aggregates (`[..]` literals) as read from the tokens, and the data types program filtering needs from them.

Layouts, from ABB "Technical reference manual - RAPID Instructions, Functions and Data types" (3HAC050917-001, RobotWare
6/7), section 3 (data types):
- pos `[x, y, z]` mm; orient `[q1, q2, q3, q4]`, a unit quaternion with q1 the scalar part; pose `[trans, rot]`;
- robtarget `[trans pos, rot orient, robconf confdata, extax extjoint]`: the TCP's position and the tool frame's
  orientation in the work object's object frame; confdata `[cf1, cf4, cf6, cfx]`; extjoint `[eax_a .. eax_f]`, 9E9
  for an axis not used;
- jointtarget `[robax robjoint, extax extjoint]`, robjoint `[rax_1 .. rax_6]` in degrees;
- tooldata `[robhold bool, tframe pose, tload loaddata]`: tframe the TCP in the wrist (flange) frame, robhold FALSE a
  stationary tool; loaddata `[mass, cog pos, aom orient, ix, iy, iz]`;
- wobjdata `[robhold bool, ufprog bool, ufmec string, uframe pose, oframe pose]`: uframe in the world frame, oframe in
  the user frame (the target's base = uframe * oframe); robhold TRUE the robot holds the work object (a stationary
  tool), ufprog FALSE / ufmec a mechanical unit: a coordinated (moving) work object.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from trackcal.drivers.abb.rapid_tokens import Token, fail, number_value


class Node(NamedTuple):
    """One element of a literal: kind "list" (`items`), "num" (`value`, its text includes a unary sign), "bool",
    "str", or "expr" (anything else: a name, a call, arithmetic; not read). text[start:end] of its file."""

    kind: str
    start: int
    end: int
    line: int
    value: float | bool | str | None = None
    items: tuple[Node, ...] = ()


def parse_literal(file: str, tokens: list[Token], i: int) -> tuple[Node, int]:
    """The literal starting at tokens[i] and the index after it: an aggregate `[a, b, ...]` (nested), a signed
    number, TRUE/FALSE, a string, or an expression up to the next `,` `]` `;` outside brackets."""
    if i >= len(tokens):
        raise fail(file, tokens[-1].line if tokens else 1, "the file ends inside a value (expected a value)")
    t = tokens[i]
    if t.text == "[":
        items = []
        i += 1
        while True:
            node, i = parse_literal(file, tokens, i)
            items.append(node)
            if i >= len(tokens):
                raise fail(file, t.line, "an aggregate '[' not closed (expected ']')")
            if tokens[i].text == "]":
                return Node("list", t.start, tokens[i].end, t.line, items=tuple(items)), i + 1
            if tokens[i].text != ",":
                raise fail(file, tokens[i].line, f"expected ',' or ']' in an aggregate, found {tokens[i].text!r}")
            i += 1
    if t.text in ("+", "-") and i + 1 < len(tokens) and tokens[i + 1].kind == "num" and _ends_value(tokens, i + 2):
        sign = -1.0 if t.text == "-" else 1.0
        return Node("num", t.start, tokens[i + 1].end, t.line, sign * number_value(tokens[i + 1].text)), i + 2
    if t.kind == "num" and _ends_value(tokens, i + 1):
        return Node("num", t.start, t.end, t.line, number_value(t.text)), i + 1
    if t.upper in ("TRUE", "FALSE") and _ends_value(tokens, i + 1):
        return Node("bool", t.start, t.end, t.line, t.upper == "TRUE"), i + 1
    if t.kind == "str" and _ends_value(tokens, i + 1):
        return Node("str", t.start, t.end, t.line, t.text), i + 1
    return _expression(file, tokens, i)


def _ends_value(tokens: list[Token], i: int) -> bool:
    return i >= len(tokens) or tokens[i].text in (",", "]", ";")


def _expression(file: str, tokens: list[Token], i: int) -> tuple[Node, int]:
    """An expression not read (a name, a call, arithmetic) up to the next `,` `]` `;` outside brackets."""
    first, depth, j = tokens[i], 0, i
    while j < len(tokens):
        text = tokens[j].text
        if depth == 0 and text in (",", "]", ";"):
            break
        depth += (text in ("(", "[", "{")) - (text in (")", "]", "}"))
        if depth < 0:
            raise fail(file, tokens[j].line, f"unbalanced {text!r} in a value")
        j += 1
    if j == i:
        raise fail(file, first.line, f"expected a value, found {first.text!r}")
    return Node("expr", first.start, tokens[j - 1].end, first.line), j


# ---- the data types ------------------------------------------------------------------------------------------------


def _items(file: str, node: Node, n: int, what: str) -> tuple[Node, ...]:
    if node.kind != "list" or len(node.items) != n:
        raise fail(file, node.line, f"expected {what}")
    return node.items


def numbers(file: str, node: Node, n: int, what: str) -> list[Node]:
    """The `n` number leaves of an aggregate `[a, b, ...]`, or the error naming what was expected."""
    items = _items(file, node, n, what)
    for item in items:
        if item.kind != "num":
            raise fail(file, item.line, f"expected a number in {what}")
    return list(items)


def value_of(node: Node) -> float:
    """The number of a "num" leaf (`numbers` has checked the kind)."""
    return float(node.value) if isinstance(node.value, int | float) else float("nan")


def quaternion_matrix(q: np.ndarray) -> np.ndarray:
    """The rotation matrix of the quaternion (q1 scalar, q2..q4 vector), normalised first."""
    w, x, y, z = np.asarray(q, dtype=float) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def matrix_quaternion(r: np.ndarray) -> np.ndarray:
    """A unit quaternion (q1 scalar) of a rotation matrix (Shepperd's method: the largest of the four squares first,
    so no division by a small number)."""
    r = np.asarray(r, dtype=float)
    squares = [
        1 + r[0, 0] + r[1, 1] + r[2, 2],
        1 + r[0, 0] - r[1, 1] - r[2, 2],
        1 - r[0, 0] + r[1, 1] - r[2, 2],
        1 - r[0, 0] - r[1, 1] + r[2, 2],
    ]
    k = int(np.argmax(squares))
    s = 2.0 * np.sqrt(max(squares[k], 1e-300))
    if k == 0:
        q = [s / 4, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s]
    elif k == 1:
        q = [(r[2, 1] - r[1, 2]) / s, s / 4, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s]
    elif k == 2:
        q = [(r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, s / 4, (r[1, 2] + r[2, 1]) / s]
    else:
        q = [(r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, s / 4]
    q = np.array(q)
    return q / np.linalg.norm(q)


def pose_matrix(file: str, node: Node, what: str) -> np.ndarray:
    """The 4 x 4 transform of a pose `[[x, y, z], [q1, q2, q3, q4]]` (mm)."""
    trans, rot = _items(file, node, 2, f"{what} as [[x, y, z], [q1, q2, q3, q4]]")
    return frame_matrix(
        file, numbers(file, trans, 3, f"{what}'s [x, y, z]"), numbers(file, rot, 4, f"{what}'s [q1, q2, q3, q4]"), what
    )


def frame_matrix(file: str, trans: list[Node], rot: list[Node], what: str) -> np.ndarray:
    """The 4 x 4 transform of a position (mm) and an orientation quaternion, each given as number leaves."""
    p = np.array([value_of(n) for n in trans], dtype=float)
    q = np.array([value_of(n) for n in rot], dtype=float)
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(q))):
        raise fail(file, trans[0].line, f"{what}: a number out of range")
    norm = float(np.linalg.norm(q))
    if not 0.5 < norm < 1.5:  # the manual: the quaternion is normalised (q1^2 + q2^2 + q3^2 + q4^2 = 1)
        raise fail(file, rot[0].line, f"{what}: the quaternion [q1, q2, q3, q4] is not normalised (norm {norm:.6g})")
    m = np.eye(4)
    m[:3, :3] = quaternion_matrix(q)
    m[:3, 3] = p
    return m


@dataclass(frozen=True)
class RobTarget:
    """A robtarget literal read: its leaves (the numbers of trans and rot), its configuration, its pose."""

    trans: list[Node]
    rot: list[Node]
    config: tuple[int, int, int, int]
    pose: np.ndarray  # 4 x 4, mm, in the object frame of the work object it is used with


def robtarget(file: str, node: Node, name: str) -> RobTarget:
    """A robtarget `[[x, y, z], [q1, q2, q3, q4], [cf1, cf4, cf6, cfx], [6 external axes]]`."""
    what = f"robtarget {name}"
    trans, rot, conf, extax = _items(file, node, 4, f"{what} as [[x,y,z],[q1,q2,q3,q4],[cf1,cf4,cf6,cfx],[extax]]")
    t = numbers(file, trans, 3, f"{what}'s trans [x, y, z]")
    r = numbers(file, rot, 4, f"{what}'s rot [q1, q2, q3, q4]")
    cf = numbers(file, conf, 4, f"{what}'s robconf [cf1, cf4, cf6, cfx]")
    if not all(value_of(c).is_integer() for c in cf):
        raise fail(file, conf.line, f"{what}: robconf [cf1, cf4, cf6, cfx] must be integers")
    _items(file, extax, 6, f"{what}'s extax of 6 values")
    cf1, cf4, cf6, cfx = (int(value_of(c)) for c in cf)
    return RobTarget(t, r, (cf1, cf4, cf6, cfx), frame_matrix(file, t, r, what))


def jointtarget(file: str, node: Node, name: str) -> list[Node]:
    """The robax leaves (6 numbers, degrees) of a jointtarget `[[rax_1 .. rax_6], [6 external axes]]`."""
    robax, extax = _items(file, node, 2, f"jointtarget {name} as [[rax_1, .., rax_6], [extax]]")
    _items(file, extax, 6, f"jointtarget {name}'s extax of 6 values")
    leaves = numbers(file, robax, 6, f"jointtarget {name}'s robax [rax_1, .., rax_6]")
    if not all(np.isfinite(value_of(n)) for n in leaves):
        raise fail(file, robax.line, f"jointtarget {name}: a number out of range")
    return leaves


def tool_frame(file: str, node: Node, name: str) -> np.ndarray:
    """The TCP in the flange frame of a tooldata `[robhold, [[x,y,z],[q1..q4]], [loaddata]]` the robot holds."""
    robhold, tframe, _load = _items(file, node, 3, f"tooldata {name} as [robhold, tframe, tload]")
    if robhold.kind != "bool":
        raise fail(file, robhold.line, f"tooldata {name}: expected TRUE or FALSE for robhold")
    if not robhold.value:
        raise fail(file, robhold.line, f"tooldata {name}: a stationary tool (robhold FALSE) is not supported")
    return pose_matrix(file, tframe, f"tooldata {name}'s tframe")


def work_object_frame(file: str, node: Node, name: str) -> np.ndarray:
    """The object frame (uframe * oframe) in the robot's world frame of a wobjdata
    `[robhold, ufprog, ufmec, uframe, oframe]` fixed in the cell."""
    robhold, ufprog, ufmec, uframe, oframe = _items(
        file, node, 5, f"wobjdata {name} as [robhold, ufprog, ufmec, uframe, oframe]"
    )
    for flag, what in ((robhold, "robhold"), (ufprog, "ufprog")):
        if flag.kind != "bool":
            raise fail(file, flag.line, f"wobjdata {name}: expected TRUE or FALSE for {what}")
    if ufmec.kind != "str":
        raise fail(file, ufmec.line, f"wobjdata {name}: expected a string for ufmec")
    if robhold.value:
        raise fail(
            file,
            robhold.line,
            f"wobjdata {name}: a work object held by the robot (robhold TRUE, a stationary tool) is not supported",
        )
    if not ufprog.value or ufmec.value:
        raise fail(
            file,
            ufprog.line,
            f"wobjdata {name}: a coordinated work object (ufprog FALSE or ufmec "
            f"{ufmec.value!r}, moved by a mechanical unit) is not supported",
        )
    user = pose_matrix(file, uframe, f"wobjdata {name}'s uframe")
    return user @ pose_matrix(file, oframe, f"wobjdata {name}'s oframe")
