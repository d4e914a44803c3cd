"""The complete model of paper section 3, step 1, and its reduction to an irreducible set, for joint axes in any
direction.

Complete (redundant) model, per revolute joint j:  R_{e_j}(q_j + dq_j) . [T_u T_v R_u R_v]_Lj
with u, v the two coordinate axes orthogonal to e_j, translations first, then rotations (x before y
before z), as in eq. (4)/(5). It is complete for any nominal geometry (the fixed rotation R_nom,j of the
chain may point the next axis anywhere): a link error is a twist, 6 numbers; its rotation about e_j is dq_j
and its translation along e_j commutes with the joint, so it moves back a link (and to the base in the end).
The base and every tracker station are free 6-dof transforms and the reference points are free 3-vectors in
the last joint's frame (position-only measurements, several points per pose), so:

- dq_1 merges into the base (station) transform (remark 2);
- dq_n and every parameter of the last link merge into the tool points (remarks 2, 3 and 4);
- each pair of consecutive joints (k, k+1) leaves exactly one linear dependency. In link k's frame (origin O at
  the end of its translation t), let a be joint k's axis and d joint k+1's axis, d = cos(th) a + w with w
  orthogonal to a (|w| = sin th). Joint k's offset is the twist (a, a x t) at O (a rotation about a line through
  O - t), joint k+1's the twist (d, 0), so
      dq_{k+1} = cos(th) dq_k - cos(th) T_{a x t} + R_w,
  a dependency among dq_k, dq_{k+1}, link k's translations across the common normal and its rotations about
  the axes orthogonal to a. One of link k's four parameters goes: the one with the largest coefficient, rotations
  weighed at the chain's reach, so that the set kept is the best conditioned (with the last rule below, the
  dependencies are eliminated row by row, so that the parameters dropped are independent of each other).
  Perpendicular axes (th = 90 deg):
  the rotation about the next axis merges with dq_{k+1} (rule 1). Parallel and near-parallel axes (tan th below
  |a x t| / reach): the translation orthogonal to the nominal common normal goes and both rotations stay, the
  second one being Hayati's beta (Hayati & Mirmirani 1985, J. Robotic Systems 2(4) 397-413), where DH's d along
  an ill-defined common normal would be (rule 2; the paper says "T_u or T_v": which one matters). Skew or
  intersecting tilted axes (a x t = 0 for intersecting ones): the rotation about the in-plane part of the next
  axis goes, as for perpendicular axes. Two parallel axes on one line (a x t = 0, w = 0) are refused;
- a translation along the last axis e_n, in the link before it, commutes with joint n and merges into the tool
  points; carried back (its part along a joint's axis commutes with that joint) it is a combination of link
  translations, and the one with the largest coefficient goes (this is how T_x,L5 of eq. (4) goes). When every
  axis from there back to the base is parallel to e_n it reaches the base instead, and nothing goes.

Counting: 5n - 1 - 5 - (n - 1) - 1 = 4n - 6 kept for n revolute joints: Everett, Driels & Mooring's 4R + 2P + 6
for a complete and irreducible model of the whole chain with its base and tool (Everett, Driels, Mooring 1987,
"Kinematic modelling for robot calibration", IEEE ICRA), less the 6 of the free station and the 6 of the free tool
points (the paper's footnote 1; Zhuang, Roth & Hamano 1992, "A complete and parametrically continuous kinematic
model for robot manipulators", IEEE T-RA 8(4) 451-463, count the same for their CPC model, whose continuity near
parallel axes the choice above keeps). He, Zhao, Yang & Yang 2010 (IEEE T-RO 26(3) 461-471) show the same
completeness for the product-of-exponentials form: a link twist modulo the joint's own twist and the translation
along its axis, which is the reduction done here. One more parameter stays where the chain ends in a run of axes
parallel all the way to the base (the planar arm of section 6.2).

The result is verified numerically in `calib.model.identifiability` and, for random chains with tilted and skew
axes, against central differences of all six deviations of every link (tests/test_chains.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trackcal.calib.model.chain import Chain, ChainError
from trackcal.calib.model.rigid import AXIS_NAME


@dataclass(frozen=True)
class Param:
    """One geometric parameter: `dq` joint offset, `p` link translation or `phi` link rotation."""

    joint: int  # 0-based joint index
    kind: str  # "dq" | "p" | "phi"
    axis: int = -1  # coordinate axis of the link frame for p / phi

    @property
    def name(self) -> str:
        if self.kind == "dq":
            return f"dq{self.joint + 1}"
        return f"{self.kind}{AXIS_NAME[self.axis]}{self.joint + 1}"

    @property
    def is_length(self) -> bool:
        return self.kind == "p"


@dataclass(frozen=True)
class Eliminated:
    param: Param
    reason: str


def complete_params(chain: Chain) -> list[Param]:
    """Every parameter of the complete model (4 link parameters + 1 offset per joint)."""
    out: list[Param] = []
    for j, joint in enumerate(chain.joints):
        others = [a for a in range(3) if a != joint.axis]
        out.append(Param(j, "dq"))
        out.extend(Param(j, "p", a) for a in others)
        out.extend(Param(j, "phi", a) for a in others)
    return out


def param_by_name(chain: Chain, name: str) -> Param:
    for p in complete_params(chain):
        if p.name == name:
            return p
    raise ChainError(f"unknown parameter {name!r} for chain {chain.name}")


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def next_axis_direction(chain: Chain, j: int) -> np.ndarray:
    """Unit direction of joint j+1's axis in link j's frame (the frame where link j's p and phi act)."""
    return _unit(chain.joints[j].rotation @ np.eye(3)[chain.joints[j + 1].axis])


def reach_mm(chain: Chain) -> float:
    """The lever at which a link rotation is weighed against a link translation: the chain's reach (the sum of its
    nominal link lengths), so that a parameter's column in the identification Jacobian is compared at the size of
    the point displacement it causes (a rotation of 1 rad moves the far end by about the reach)."""
    return max(float(sum(np.linalg.norm(jt.translation) for jt in chain.joints)), 1.0)


# Below this a dependency coefficient is zero: the aligned robots' geometry is exact to ~1e-16 and datasheet DH
# angles turned into rotations to ~1e-15; the old aligned-axis test used the same 1e-9.
TOL = 1e-9
# A dependency coefficient below this share of its row's scale is no pivot (the scale: the lever for the pair rows,
# whose joint offsets move the far end by about the lever; 1 for the tool row, a direction): its parameter moves the
# far end by less than 1e-6 of what the row's others do, the relative precision of a laser tracker and the rank
# tolerance of the identifiability checks (tests/test_chains.py: RTOL). Two intersecting axes tilted by 1.7e-12 rad
# (a hypothesis draw) made a rotation the pivot at 1e-9 mm and the kept set was rank deficient by one; such axes
# now coincide, and the chain is refused as redundant.
PIVOT_SHARE = 1e-6


Row = dict[Param, float]  # a linear dependency among parameter columns: coefficient of each (rotations at the lever)


def _pair_row(chain: Chain, k: int, lever: float) -> Row:
    """The one dependency between link k's parameters and the offsets of joints k+1 and k+2, derived at the nominal
    geometry (module docstring): dq_{k+2} - cos(th) dq_{k+1} + cos(th) T_{a x t} - R_w = 0."""
    joint = chain.joints[k]
    a = np.eye(3)[joint.axis]
    d = next_axis_direction(chain, k)
    c = float(d @ a)  # cos of the angle between the axes
    w = d - c * a  # sin(angle) times the in-plane direction of the next axis
    n = c * np.cross(a, joint.translation)  # cos(angle) times the offset across the common normal, mm
    row: Row = {Param(k + 1, "dq"): 1.0, Param(k, "dq"): -c}
    for i in range(3):
        if i != joint.axis:
            row[Param(k, "p", i)] = float(n[i])
            row[Param(k, "phi", i)] = -float(w[i]) * lever
    return row


def _tool_row(chain: Chain) -> Row:
    """The translation along the last joint's axis in the link before it commutes with the last joint (tool points);
    carried back through the links (its part along a joint's axis commutes with that joint too) it is a combination
    of link translations: their coefficients. Empty when it reaches the base (every axis parallel back there)."""
    n = chain.dof
    row: Row = {}
    v = next_axis_direction(chain, n - 2)
    for k in range(n - 2, -1, -1):
        a_k = chain.joints[k].axis
        row.update({Param(k, "p", i): float(v[i]) for i in range(3) if i != a_k})
        if k == 0 or abs(v[a_k]) <= TOL:
            break
        v = v[a_k] * (chain.joints[k - 1].rotation @ np.eye(3)[a_k])  # the part along joint k's axis, one link back
    return row


def _eliminate(rows: list[tuple[Row, str, float]], droppable: set[Param], offsets: set[Param]) -> dict[Param, int]:
    """One parameter per dependency such that the rest are independent: Gaussian elimination row by row, each row's
    pivot the droppable parameter with the largest coefficient once the earlier pivots are eliminated from it (the
    first of equals), so that the set kept is the best conditioned. Returns {parameter: row index}; a row with no
    droppable coefficient left but a joint offset that is kept (a dependency among those offsets alone) is a
    ChainError with the row's text. A coefficient below PIVOT_SHARE of the row's scale (its third item) is none."""
    done: list[tuple[Row, Param]] = []
    out: dict[Param, int] = {}
    for r, (row, why, scale) in enumerate(rows):
        row, negligible = dict(row), PIVOT_SHARE * scale
        for prev, piv in done:
            f = row.get(piv, 0.0) / prev[piv]
            if f:
                for key, val in prev.items():
                    row[key] = row.get(key, 0.0) - f * val
        best = None
        for key, val in row.items():
            if key not in droppable or key in out or abs(val) <= negligible:
                continue
            if best is None or abs(val) > abs(row[best]) * (1 + 1e-12):
                best = key
        if best is None:
            if any(abs(v) > TOL for key, v in row.items() if key in offsets):
                raise ChainError(why)
            continue
        done.append((row, best))
        out[best] = r
    return out


def irreducible_params(chain: Chain) -> tuple[list[Param], list[Eliminated]]:
    """Apply the elimination rules; returns (kept parameters in model order, eliminated with reasons)."""
    n = chain.dof
    if n < 2:
        raise ChainError("a chain needs at least two joints to be calibrated")
    removed: dict[Param, str] = {}
    removed[Param(0, "dq")] = "offset of the first joint merges into the base/station transform"
    removed[Param(n - 1, "dq")] = "offset of the last joint merges into the tool points"
    for p in complete_params(chain):
        if p.joint == n - 1 and p.kind != "dq":
            removed[p] = "last-link parameter merges into the tool points"

    lever = reach_mm(chain)
    rows = [
        (
            _pair_row(chain, k, lever),
            f"joints {k + 1} and {k + 2} are parallel and coincide nominally; such a chain is redundant",
            lever,
        )
        for k in range(n - 1)
    ]
    rows.append((_tool_row(chain), f"chain {chain.name}: the translation along the last axis cannot be separated", 1.0))
    free = [p for p in complete_params(chain) if p not in removed]
    for p, r in _eliminate(rows, {p for p in free if p.kind != "dq"}, {p for p in free if p.kind == "dq"}).items():
        if r == n - 1:
            removed[p] = f"translation along the last joint axis commutes with joints {p.joint + 2}..{n}: tool points"
            continue
        cos = abs(next_axis_direction(chain, r) @ np.eye(3)[chain.joints[r].axis])
        if p.kind == "phi" and cos <= TOL:
            removed[p] = f"rotation about the axis of joint {r + 2} merges with dq{r + 2}"
        elif p.kind == "phi":
            removed[p] = (
                f"joints {r + 1} and {r + 2} are tilted: the rotation about joint {r + 2}'s axis is "
                f"dq{r + 1} plus this rotation, so it merges with dq{r + 1} and dq{r + 2}"
            )
        else:
            nearly = "" if abs(cos - 1) <= TOL else " or nearly"
            removed[p] = (
                f"joints {r + 1} and {r + 2} are parallel{nearly}: this translation is a rotation of the "
                f"common normal, already described by dq{r + 1} and dq{r + 2}"
            )

    kept = [p for p in complete_params(chain) if p not in removed]
    eliminated = [Eliminated(p, removed[p]) for p in complete_params(chain) if p in removed]
    return kept, eliminated
