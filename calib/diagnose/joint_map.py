"""The joint error map (cause `cyclic_error`): its form and its features; its search and ridge fit are
`calib.diagnose.joint_map_fit`, which only diagnose needs (identify, predict and model files read this module).

Form: the angle a joint really takes is the angle the controller reports plus a map of that angle, per joint a
Fourier series in the joint's own angle,

    q_true_j = q_j + e_j(q_j),   e_j(q) = sum_{h=1..H} a_jh sin(h q) + b_jh cos(h q)   (rad)

Coefficients are named s<h>_<joint> and c<h>_<joint> (joint 1-based). A map is only known over the arc of
angles it was fitted on (`Arc.covering`: the circle minus the largest gap between the fitted angles);
outside that arc it takes its value at the nearest end of the arc, a constant continuation, never an
extrapolated Fourier series, and `outside_arcs` says which rows left it (predict and compensate warn).

Features: `map_extension`, the extension `calib.diagnose.extensions.build_extension` gives for cyclic_error.

Value of a fitted map: `map_curve`.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from trackcal.calib.errors import CalibError
from trackcal.calib.identify.solver import Identification
from trackcal.calib.model.extension import (
    UNIT_FACTORS,
    Extension,
    ExtensionError,
    JointFeatures,
    select_columns,
)

CAUSE = "cyclic_error"


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


@functools.lru_cache(maxsize=32)
def _groups(names: tuple[str, ...]) -> tuple[tuple[str, int, slice | list[int], np.ndarray], ...]:
    """(sine or cosine, joint, columns, harmonics) of the coefficients `names` grouped by joint and sine/cosine, in
    order of first appearance; parsed once per list of names (the map's search and held-out tests ask for a few lists
    hundreds of times: their 51,000 parses were 3 % of a diagnosis of Series B under cProfile, issue 41). The columns
    are a slice when evenly spaced (a map's names, s1 c1 s2 c2 ...: what is written to them is written in place)."""
    groups: dict[tuple[str, int], tuple[list[int], list[int]]] = {}
    for i, name in enumerate(names):
        kind, h, j = parse_name(name)
        cols, hs = groups.setdefault((kind, j), ([], []))
        cols.append(i)
        hs.append(h)
    out = []
    for (kind, j), (cols, hs) in groups.items():
        h = np.array(hs, dtype=float)
        h.flags.writeable = False  # shared by every call with these names
        out.append((kind, j, _span(cols), h))
    return tuple(out)


def _span(cols: list[int]) -> slice | list[int]:
    """Increasing columns as a slice when evenly spaced, else themselves."""
    step = cols[1] - cols[0] if len(cols) > 1 else 1
    if step > 0 and all(b - a == step for a, b in zip(cols[:-1], cols[1:], strict=True)):
        return slice(cols[0], cols[-1] + 1, step)
    return cols


def harmonics_by_joint(q: np.ndarray, names: list[str], arcs: dict[int, Arc]):
    """(joint, columns (a slice or a list), values (N, number of columns)) of the coefficients `names` grouped by joint
    and sine/cosine, each joint's angle clamped to its arc: one sine or cosine call per group (a call per coefficient
    cost 1.4 s of a diagnosis of Series B, issue 26), the same products h * q and the same values."""
    clamped = {j: arc.clamp(q[:, j])[0] for j, arc in arcs.items()}
    for kind, j, cols, hs in _groups(tuple(names)):
        yield j, cols, (np.sin if kind == "s" else np.cos)(hs * clamped[j][:, None])


def map_features(q: np.ndarray, names: list[str], arcs: dict[int, Arc]) -> np.ndarray:
    """(N, n, e) features: dq_j = features @ c for the coefficients `names`, each joint's angle clamped to its arc."""
    feats = np.zeros((q.shape[0], q.shape[1], len(names)))
    for j, cols, values in harmonics_by_joint(q, names, arcs):
        feats[:, j, cols] = values
    return feats


def map_blocks(q: np.ndarray, names: list[str], arcs: dict[int, Arc]) -> JointFeatures:
    """The features of `map_features` in per-joint block form (a coefficient moves its own joint only): the same
    values, N e of them where the dense array holds N n e."""
    values, joint = np.empty((q.shape[0], len(names))), np.empty(len(names), dtype=int)
    for j, cols, vals in harmonics_by_joint(q, names, arcs):
        values[:, cols], joint[cols] = vals, j
    return JointFeatures(values, joint, q.shape[1])


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
        for j in sorted(arcs)
        if out[:, j].any()
    )
    return (
        f"{rows} of {len(q)} rows leave the joint error map's fitted range ({per_joint}); the map's value at "
        "the nearest covered angle is used there"
    )


def map_extension(
    q: np.ndarray, harmonics: int = 2, names: list[str] | None = None, arcs: dict[int, Arc] | None = None
) -> Extension:
    """The cyclic_error extension for joint angles q (N, n) rad: the coefficients `names` over the fitted `arcs`,
    or (names None) every varying coefficient of harmonics 1..`harmonics` over the arcs (default: q's own)."""
    arcs = {j: Arc.covering(q[:, j]) for j in range(q.shape[1])} if arcs is None else arcs
    if names is None:
        candidates = [nm for j in sorted(arcs) for nm in harmonic_names(j, harmonics)]
        feats, kept = select_columns(map_features(q, candidates, arcs), candidates, None)
    else:
        kept = _map_names(names, arcs)
        feats = map_blocks(q, kept, arcs)
    return Extension(
        CAUSE,
        kept,
        ["deg"] * len(kept),
        np.full(len(kept), UNIT_FACTORS["deg"]),
        feats,
        meta={"arcs": {j: arcs[j] for j in sorted({parse_name(nm)[2] for nm in kept})}},
    )


def _map_names(wanted: list[str], arcs: dict[int, Arc]) -> list[str]:
    """The wanted cyclic_error coefficient names, checked against the joints the arcs cover."""
    bad = []
    for nm in wanted:
        try:
            kind, h, j = parse_name(nm)
        except JointMapError:
            bad.append(nm)
            continue
        if kind not in "sc" or h < 1 or j not in arcs:
            bad.append(nm)
    if bad:
        raise ExtensionError(f"unknown extension parameter(s) {', '.join(bad)}")
    return list(wanted)


def map_curve(res: Identification, joint: int, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(value, standard deviation) of a fitted joint error map of `joint` (0-based) at angles q (rad), clamped
    to its fitted arc; from an identification whose extension carries cyclic_error (alone or combined)."""
    ext = res.extension
    at = 0
    for cause, names in ext.parts():
        if cause == CAUSE:
            break
        at += len(names)
    else:
        raise JointMapError("the fitted model has no joint error map")
    sel = [at + i for i, nm in enumerate(names) if parse_name(nm)[2] == joint]
    rows = np.zeros((len(q), res.chain.dof))
    rows[:, joint] = q
    phi = map_features(rows, [ext.names[i] for i in sel], {joint: ext.meta["arcs"][joint]})[:, joint, :]
    idx = len(res.params) + np.array(sel, dtype=int)
    cov = res.cov[np.ix_(idx, idx)]
    return phi @ res.ext[sel], np.sqrt(np.maximum(np.einsum("ni,ij,nj->n", phi, cov, phi), 0.0))
