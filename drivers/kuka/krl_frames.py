"""The base and tool frames a KRL program's moves run in, followed line by line as the interpreter sets them.

What sets them (KSS 5.x and 8.x; the KSS templates and inline forms as printed in public forum threads and
OrangeEdit's documentation): `$BASE = BASE_DATA[n]`, `$TOOL = TOOL_DATA[n]` (the frames the cell's `$config.dat`
holds), `$BASE = {X ..,A ..}` set directly, `$BASE = $NULLFRAME`, `$BASE = NAME` (a FRAME of the program's data),
`BAS(#BASE, n)` / `BAS(#TOOL, n)` (the BAS package's commands), and the inline forms' `FDAT_ACT = FNAME`, whose
TOOL_NO / BASE_NO name TOOL_DATA / BASE_DATA (0: the flange / $NULLFRAME) and whose IPO_FRAME #TCP, like
`$IPO_MODE = #TCP`, means a fixed (external) tool: then the base is the tool and the tool the workpiece.
A frame set any other way (an expression, a function's result, `$ROBROOT` changed) is unknown: a Cartesian target
moved to in it is refused (ProgramReadError naming the line), never read in a frame it may not be in.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from trackcal.drivers.kuka.krl_tokens import Token
from trackcal.drivers.kuka.krl_values import POSE_KEYS, Aggregate, parse_aggregate, pose_of

NULL = np.eye(4)


@dataclass(frozen=True)
class Frame:
    label: str  # how the program names it: "BASE_DATA[2]", "$NULLFRAME", "{...} at line 12", ...
    pose: np.ndarray | None  # 4 x 4 (mm); None: unknown (the label says why)


@dataclass
class FrameState:
    """The frames in force at a line, and the frame data read so far (TOOL_DATA / BASE_DATA elements, FRAME and
    FDAT variables, by upper-case name)."""

    base: Frame = field(default_factory=lambda: Frame("$NULLFRAME (none set)", NULL))
    tool: Frame = field(default_factory=lambda: Frame("the flange (no $TOOL set)", NULL))
    external_tcp: str = ""  # the line that made the tool external ("" : the tool is on the flange)
    data: dict[str, Aggregate] = field(default_factory=dict)  # "TOOL_DATA[1]", "FP1", "MYFRAME" -> its value


def _table(state: FrameState, table: str, n: int) -> Frame:
    label = f"{table}[{n}]"
    if n == 0:
        return Frame(f"{label} ({'the flange' if table == 'TOOL_DATA' else '$NULLFRAME'})", NULL)
    agg = state.data.get(label)
    if agg is None or not agg.has_all(POSE_KEYS):
        return Frame(f"{label}, which the given files do not define (give the cell's $config.dat)", None)
    return Frame(label, pose_of(agg))


def _numbered(fdat: Aggregate, key: str, state: FrameState, table: str) -> Frame:
    """The frame an FDAT's TOOL_NO / BASE_NO names."""
    n = fdat.number(key)
    if n is None or n != int(n) or n < 0:
        return Frame(f"{key} {fdat.members[key].text if key in fdat.members else 'missing'} of an FDAT", None)
    return _table(state, table, int(n))


def _expression(file: str, toks: list[Token], text: str, state: FrameState, table: str) -> Frame:
    """The frame an assignment's right-hand side `toks` gives."""
    words = [t.upper for t in toks]
    shown = " ".join(t.text for t in toks)
    if len(toks) == 4 and words[0] == table and words[1] == "[" and toks[2].text.isdigit() and words[3] == "]":
        return _table(state, table, int(toks[2].text))
    if words == ["$NULLFRAME"]:
        return Frame("$NULLFRAME", NULL)
    if toks and toks[0].text == "{":
        agg, j = parse_aggregate(file, toks, 0, text)
        if j == len(toks) and agg.has_all(POSE_KEYS):
            return Frame(f"{text[agg.start : agg.end]} at line {agg.line}", pose_of(agg))
    if len(toks) == 1 and toks[0].kind == "name" and words[0] in state.data:
        agg = state.data[words[0]]
        if agg.has_all(POSE_KEYS):
            return Frame(toks[0].text, pose_of(agg))
    return Frame(f"{shown} (line {toks[0].line if toks else '?'}), which this reader cannot evaluate", None)


def assign(file: str, lhs: str, rhs: list[Token], text: str, state: FrameState) -> None:
    """Follow `lhs = rhs` where it sets a frame ($BASE, $TOOL, $IPO_MODE, $ROBROOT, FDAT_ACT)."""
    line = rhs[0].line if rhs else 0
    if lhs == "$BASE":
        state.base = _expression(file, rhs, text, state, "BASE_DATA")
    elif lhs == "$TOOL":
        state.tool = _expression(file, rhs, text, state, "TOOL_DATA")
    elif lhs == "$IPO_MODE":
        state.external_tcp = f"$IPO_MODE = #TCP at line {line}" if [t.upper for t in rhs] == ["#TCP"] else ""
    elif lhs == "$ROBROOT":
        state.base = Frame(f"a base after $ROBROOT was changed at line {line}", None)
    elif lhs == "FDAT_ACT":
        fdat = state.data.get(rhs[0].upper) if len(rhs) == 1 else None
        if fdat is None:
            shown = " ".join(t.text for t in rhs)
            state.base = state.tool = Frame(f"FDAT_ACT = {shown} (line {line}), not in the given files", None)
            return
        state.tool = _numbered(fdat, "TOOL_NO", state, "TOOL_DATA")
        state.base = _numbered(fdat, "BASE_NO", state, "BASE_DATA")
        ipo = fdat.members.get("IPO_FRAME")
        tcp = ipo is not None and str(ipo.value).upper() == "#TCP"
        state.external_tcp = f"{rhs[0].text}'s IPO_FRAME #TCP (line {line})" if tcp else ""


def bas_call(args: list[Token], state: FrameState) -> None:
    """Follow `BAS(#TOOL, n)` / `BAS(#BASE, n)`; the BAS package's other commands set no frame."""
    words = [t.upper for t in args]
    if len(args) >= 3 and words[0] in ("#TOOL", "#BASE") and words[1] == ",":
        table = "TOOL_DATA" if words[0] == "#TOOL" else "BASE_DATA"
        frame = (
            _table(state, table, int(args[2].text))
            if len(args) == 3 and args[2].text.isdigit()
            else Frame(f"BAS({' '.join(t.text for t in args)}), which this reader cannot evaluate", None)
        )
        if table == "TOOL_DATA":
            state.tool = frame
        else:
            state.base = frame


def _fdat_argument(rhs: list[Token], state: FrameState) -> Aggregate | None:
    """The FDAT named in a spline inline form's `STOOL2(FP1)`, `SBASE(FP1.BASE_NO)`, `SIPO_MODE(FP1.IPO_FRAME)`."""
    if len(rhs) >= 4 and rhs[0].kind == "name" and rhs[1].text == "(" and rhs[2].kind == "name" and rhs[-1].text == ")":
        return state.data.get(rhs[2].upper)
    return None


def with_clause(
    file: str, pairs: list[tuple[str, list[Token]]], text: str, state: FrameState
) -> tuple[Frame, Frame, str]:
    """(base, tool, external-TCP reason) of a KSS 8 spline move whose WITH clause assigns `pairs` (system variable,
    value tokens) for that move: `$TOOL = STOOL2(FP1)`, `$BASE = SBASE(FP1.BASE_NO)`, `$IPO_MODE =
    SIPO_MODE(FP1.IPO_FRAME)` as the inline forms write them, or the forms `assign` knows."""
    base, tool, external = state.base, state.tool, state.external_tcp
    for lhs, rhs in pairs:
        fdat = _fdat_argument(rhs, state)
        line = rhs[0].line if rhs else 0
        if lhs == "$TOOL":
            tool = (
                _numbered(fdat, "TOOL_NO", state, "TOOL_DATA")
                if fdat
                else _expression(file, rhs, text, state, "TOOL_DATA")
            )
        elif lhs == "$BASE":
            base = (
                _numbered(fdat, "BASE_NO", state, "BASE_DATA")
                if fdat
                else _expression(file, rhs, text, state, "BASE_DATA")
            )
        elif lhs == "$IPO_MODE":
            ipo = fdat.members.get("IPO_FRAME") if fdat else None
            words = [t.upper for t in rhs]
            tcp = (ipo is not None and str(ipo.value).upper() == "#TCP") or words == ["#TCP"]
            known = fdat is not None or words in (["#TCP"], ["#BASE"])
            external = f"WITH $IPO_MODE at line {line}" if tcp or not known else ""
    return base, tool, external
