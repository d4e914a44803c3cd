"""The form of the joint error map (cause `cyclic_error`): per joint, a Fourier series in the joint's own angle.

    q_true_j = q_j + e_j(q_j),   e_j(q) = sum_{h=1..H} a_jh sin(h q) + b_jh cos(h q)   (rad)

Coefficients are named s<h>_<joint> and c<h>_<joint> (joint 1-based). A map is only known over the arc of
angles it was fitted on (`Arc.covering`: the circle minus the largest gap between the fitted angles);
outside that arc it takes its value at the nearest end of the arc, a constant continuation, never an
extrapolated Fourier series, and `outside_arcs` says which rows left it (predict and compensate warn).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trackcal.calib.errors import CalibError


class JointMapError(CalibError):
    """A joint error map that cannot be built or read: no angles, a malformed coefficient name, no map."""


@dataclass(frozen=True)
class Arc:
    """Angles start .. start + length (rad) on the circle, the range a joint's map was fitted over."""

    start: float
    length: float

    @staticmethod
    def covering(q: np.ndarray) -> Arc:
        """The smallest arc holding every angle of q: the circle minus its largest gap between angles."""
        a = np.sort(np.mod(np.asarray(q, dtype=float), 2 * np.pi))
        if len(a) == 0:
            raise JointMapError("no angles to cover")
        gaps = np.diff(np.append(a, a[0] + 2 * np.pi))
        g = int(np.argmax(gaps))
        start = a[(g + 1) % len(a)]
        return Arc(float(start), float(2 * np.pi - gaps[g]))

    def clamp(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(angles moved to the nearest end of the arc when outside it, outside mask)."""
        q = np.asarray(q, dtype=float)
        u = np.mod(q - self.start, 2 * np.pi)
        outside = u > self.length + 1e-12
        to_end = u - self.length
        to_start = 2 * np.pi - u
        target = np.where(to_end <= to_start, self.start + self.length, self.start)
        return np.where(outside, target, q), outside

    def to_doc(self) -> dict:
        lo = np.degrees(self.start)
        lo = (lo + 180.0) % 360.0 - 180.0
        return {"from_deg": float(lo), "to_deg": float(lo + np.degrees(self.length))}

    @staticmethod
    def from_doc(doc: dict) -> Arc:
        lo, hi = float(doc["from_deg"]), float(doc["to_deg"])
        return Arc(float(np.radians(lo)), float(np.radians(hi - lo)))


def harmonic_names(joint: int, order: int) -> list[str]:
    """Coefficient names of one joint (0-based) up to `order`: s1_j, c1_j, s2_j, ..."""
    return [f"{label}{h}_{joint + 1}" for h in range(1, order + 1) for label in ("s", "c")]


def parse_name(name: str) -> tuple[str, int, int]:
    """'s12_3' -> ('s', 12, 2): sine/cosine, harmonic, 0-based joint."""
    try:
        head, joint = name.split("_")
        return head[0], int(head[1:]), int(joint) - 1
    except (ValueError, IndexError):  # not two parts, not integers, an empty head
        raise JointMapError(f"{name!r} is not a joint error map coefficient (s<h>_<joint> or c<h>_<joint>)") from None


def map_features(q: np.ndarray, names: list[str], arcs: dict[int, Arc]) -> np.ndarray:
    """(N, n, e) features: dq_j = features @ c for the coefficients `names`, each joint's angle clamped to its arc."""
    n_rows, n = q.shape
    clamped = {j: arc.clamp(q[:, j])[0] for j, arc in arcs.items()}
    feats = np.zeros((n_rows, n, len(names)))
    for i, name in enumerate(names):
        kind, h, j = parse_name(name)
        feats[:, j, i] = (np.sin if kind == "s" else np.cos)(h * clamped[j])
    return feats


def outside_arcs(q: np.ndarray, arcs: dict[int, Arc]) -> np.ndarray:
    """(N, n) bool: the rows' angles outside the arc their joint's map was fitted over."""
    out = np.zeros(q.shape, dtype=bool)
    for j, arc in arcs.items():
        out[:, j] = arc.clamp(q[:, j])[1]
    return out


def range_warning(q: np.ndarray, arcs: dict[int, Arc]) -> str | None:
    """One line saying which rows leave the fitted arcs (None when none does), for predict and compensate."""
    out = outside_arcs(q, arcs)
    rows = int(out.any(axis=1).sum())
    if rows == 0:
        return None
    per_joint = ", ".join(
        f"joint {j + 1}: {int(out[:, j].sum())} (fitted {arcs[j].to_doc()['from_deg']:.1f} .. "
        f"{arcs[j].to_doc()['to_deg']:.1f} deg)"
        for j in sorted(arcs) if out[:, j].any()
    )  # fmt: skip
    return (f"{rows} of {len(q)} rows leave the joint error map's fitted range ({per_joint}); the map's value at "
            "the nearest covered angle is used there")  # fmt: skip
