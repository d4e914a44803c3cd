"""The complete model of paper section 3, step 1, and its reduction by the elimination rules of step 2.

Complete (redundant) model, per revolute joint j:  R_{e_j}(q_j + dq_j) . [T_u T_v R_u R_v]_Lj
with u, v the two coordinate axes orthogonal to e_j, translations first, then rotations (x before y
before z), as in eq. (4)/(5). The base and every tracker station are free 6-dof transforms and the
reference points are free 3-vectors in the last joint's frame (position-only measurements), so:

- dq_1 merges into the base (station) transform (remark 2);
- dq_n and every parameter of the last link merge into the tool points (remarks 2, 3 and 4);
- e_j perpendicular to e_{j-1}: R about e_j in link j-1 merges with dq_j (rule 1);
- e_j parallel to e_{j-1}: the in-plane translation of link j-1 orthogonal to the nominal common
  normal is a rotation of the normal, which (dq_{j-1}, dq_j) already describe (rule 2). The paper
  says "T_u or T_v"; which one matters: the one orthogonal to the nominal link vector goes;
- a translation along the last axis e_n, in the last link before a run of joints parallel to e_n,
  commutes with those joints and merges into the tool points (this is how T_x,L5 of eq. (4) goes).

The result is verified numerically in `calib.model.identifiability`.
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


def _aligned_axis(v: np.ndarray, where: str) -> int:
    k = int(np.argmax(np.abs(v)))
    if abs(abs(v[k]) - 1.0) > 1e-9:
        raise ChainError(f"{where}: joint axes must be parallel or perpendicular (got direction {v})")
    return k


def next_axis_in_link(chain: Chain, j: int) -> int:
    """Coordinate axis of link j's frame along which joint j+1 rotates."""
    joint = chain.joints[j]
    e_next = np.eye(3)[chain.joints[j + 1].axis]
    return _aligned_axis(joint.rotation @ e_next, f"joints {j + 1}-{j + 2}")


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

    for j in range(1, n):
        prev = chain.joints[j - 1]
        a_next = next_axis_in_link(chain, j - 1)
        if a_next != prev.axis:  # perpendicular
            removed.setdefault(
                Param(j - 1, "phi", a_next), f"rotation about the axis of joint {j + 1} merges with dq{j + 1}"
            )
        else:  # parallel: drop the in-plane translation orthogonal to the nominal common normal
            in_plane = [a for a in range(3) if a != prev.axis]
            t = prev.translation
            if max(abs(t[a]) for a in in_plane) < 1e-9:
                raise ChainError(
                    f"joints {j} and {j + 1} are parallel and coincide nominally; such a chain is redundant"
                )
            drop = min(in_plane, key=lambda a: abs(t[a]))
            removed.setdefault(
                Param(j - 1, "p", drop),
                f"joints {j} and {j + 1} are parallel: this translation is a rotation of the common normal, "
                f"already described by dq{j} and dq{j + 1}",
            )

    # translation along the last axis, before the run of joints parallel to it
    k = n - 1
    v = np.eye(3)[chain.joints[k].axis]
    while k > 0:
        v = chain.joints[k - 1].rotation @ v
        a = _aligned_axis(v, f"joints {k}-{k + 1}")
        if a != chain.joints[k - 1].axis:
            removed.setdefault(
                Param(k - 1, "p", a),
                f"translation along the last joint axis commutes with joints {k + 1}..{n}: tool points",
            )
            break
        k -= 1

    kept = [p for p in complete_params(chain) if p not in removed]
    eliminated = [Eliminated(p, removed[p]) for p in complete_params(chain) if p in removed]
    return kept, eliminated
