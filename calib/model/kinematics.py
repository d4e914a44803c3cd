"""Batched forward kinematics of a chain with geometric deviations, and its analytic Jacobians.

For N rows at once (a row = joint vector + tool point) this returns the point in the robot base frame,
its derivative with respect to any chosen list of parameters (the identification Jacobian, paper eq. 1,
position rows), to the tool point coordinates and to the joint angles. Every elementary transform of
the complete model is applied, so a deviation of any parameter is honoured exactly, and its
Jacobian column is the exact derivative at the current deviations (not only at nominal):
  translation along axis a of frame F:  dp = R_F[:, a]
  rotation about axis a of frame F:     dp = R_F[:, a] x (p - o_F)

Layout: the chain is walked with the coordinate first and the rows last, a rotation held by its columns
r (3, 3, N) (r[a] is the a-th column of every row's rotation, (3, N)) and an origin as o (3, N). Every step of
the walk is then a handful of numpy operations on contiguous arrays of all the rows, where the rows-first
layout (N, 3, 3) took one small BLAS call per row for each product with a fixed matrix or vector (issue 26: a
forward pass of the UR10's 1495 rows cost ~2 ms). The products with a fixed vector or matrix are sums over the
three columns in a fixed order (`_combine`, `_times`), so that a row's result never depends on the others; the
deviations of a link's rotation and its nominal rotation are multiplied once and applied in one product.
`PointJacobian` keeps this layout (its `*_t` arrays, what the solver uses) and gives the rows-first arrays
(N, 3, ...) of its public properties.
"""

from __future__ import annotations

import dataclasses
from functools import cached_property

import numpy as np

from trackcal.calib.model.chain import Chain, ChainError
from trackcal.calib.model.params import Param, complete_params
from trackcal.calib.model.rigid import rot_axis


def _rows_first(a: np.ndarray) -> np.ndarray:
    """(3, k, N) -> (N, 3, k), contiguous."""
    return np.ascontiguousarray(a.transpose(2, 0, 1))


class PointJacobian:
    """Point and Jacobians of N rows, built from the frames of their M distinct poses (`rows` gives each row's
    pose): per pose the chain leaves the axis of every translation and the axis w and a point o of every
    rotation, and per row a rotation's column is w x (p - o) = (o - p) x w. The derivatives are computed when first
    asked for (identification never needs the joint columns), each column written in place from its frame: stacking
    the frames of every parameter first (zeros for the other kind) moved three times as much memory as the columns
    (issue 41: half the cost of the identification Jacobian of the UR10's 1495 poses). The `*_t` arrays have the
    coordinate first and the rows last (the layout of the walk); the public properties are rows first."""

    def __init__(self, p_t, r_end, frames, joints, rows):
        self.p_t = p_t  # (3, N) point in the robot base frame, mm
        self._r_end, self._rows = r_end, rows  # columns (3, 3, M) of the last joint frame's rotation
        self._frames = frames  # per parameter (axis (3, M), point (3, M) of a rotation's axis | None: a translation)
        self._joints = joints  # per joint its axis and origin, (3, M) each

    def _per_row(self, per_pose: np.ndarray) -> np.ndarray:
        return per_pose if self._rows is None else _gathered(per_pose, self._rows)

    def _columns(self, frames: list[tuple[np.ndarray, np.ndarray | None]]) -> np.ndarray:
        """(3, c, N): per frame, the axis of a translation or the column (o - p) x w of a rotation about the axis w
        through o (o - p formed once per point o: a joint's rotations share it)."""
        out = np.empty((3, len(frames), self.p_t.shape[1]))
        arms: dict[int, np.ndarray] = {}
        for i, (w, o) in enumerate(frames):
            if o is None:
                out[:, i] = self._per_row(w)
                continue
            if id(o) not in arms:
                arms[id(o)] = self._per_row(o) - self.p_t
            cross3(arms[id(o)], self._per_row(w), axis=0, out=out[:, i])
        return out

    @cached_property
    def d_params_t(self) -> np.ndarray:
        """(3, k, N) derivative w.r.t. the selected parameters (mm/mm, mm/rad), coordinate first: a rotation's
        column (o - p) x w, a translation's its axis."""
        return self._columns(self._frames)

    @cached_property
    def d_point_t(self) -> np.ndarray:
        """(3, 3, N) derivative w.r.t. the tool point coordinates (= end rotation), coordinate first."""
        return self._per_row(self._r_end.transpose(1, 0, 2))

    @cached_property
    def d_q_t(self) -> np.ndarray:
        """(3, n, N) derivative w.r.t. the joint angles (mm/rad), coordinate first."""
        return self._columns(self._joints)

    @cached_property
    def p(self) -> np.ndarray:
        """(N, 3) point in the robot base frame, mm."""
        return np.ascontiguousarray(self.p_t.T)

    @cached_property
    def d_params(self) -> np.ndarray:
        """(N, 3, k) derivative w.r.t. the selected parameters (mm/mm, mm/rad)."""
        return _rows_first(self.d_params_t)

    @cached_property
    def d_point(self) -> np.ndarray:
        """(N, 3, 3) derivative w.r.t. the tool point coordinates (= end rotation)."""
        return _rows_first(self.d_point_t)

    @cached_property
    def d_q(self) -> np.ndarray:
        """(N, 3, n) derivative w.r.t. the joint angles (mm/rad)."""
        return _rows_first(self.d_q_t)

    @cached_property
    def joint_axes(self) -> np.ndarray:
        """(N, 3, n) unit axis of each joint in the base frame (signed)."""
        return _rows_first(self._per_row(np.stack([w for w, _ in self._joints], axis=1)))

    @cached_property
    def rot_axes(self) -> np.ndarray:
        """(N, 3, k) axis of each rotational parameter (zeros for translations)."""
        axes = [w if o is not None else np.zeros_like(w) for w, o in self._frames]
        return _rows_first(self._per_row(np.stack(axes, axis=1)))


def cross3(a: np.ndarray, b: np.ndarray, axis: int = 1, out: np.ndarray | None = None) -> np.ndarray:
    """Cross product along `axis` (the vectors' coordinates) with broadcasting (faster than np.cross for small
    batched arrays), written into one output (`out` if given) with one scratch array (few temporaries). The axis is
    moved to the front by a transpose (np.moveaxis and np.broadcast_shapes took 16 us a call, ten times the
    products of a column of the UR10's 1495 poses)."""
    a, b = _front(a, axis), _front(b, axis)
    if out is None:
        shape = np.broadcast_shapes(a.shape, b.shape)
        out = np.empty(shape[1 : axis + 1] + (3,) + shape[axis + 1 :])
    out_c = _front(out, axis)
    scratch = np.empty(out_c.shape[1:])
    for i in range(3):
        j, k = (i + 1) % 3, (i + 2) % 3
        np.multiply(a[j], b[k], out=out_c[i])
        np.subtract(out_c[i], np.multiply(a[k], b[j], out=scratch), out=out_c[i])
    return out


def _front(a: np.ndarray, axis: int) -> np.ndarray:
    """a with `axis` moved to the front (np.moveaxis(a, axis, 0) for axis >= 0), a view."""
    return a if axis == 0 else a.transpose((axis, *range(axis), *range(axis + 1, a.ndim)))


def turned(r: np.ndarray, axis: int, cos, sin) -> np.ndarray:
    """r @ rot_axis(axis, angle) for rotations given by their columns r (3, 3, N) (r[a]: the a-th column of each):
    the turn mixes two columns (cos, sin of the angle: scalars or (N,))."""
    i, j = (axis + 1) % 3, (axis + 2) % 3
    out = np.empty_like(r)
    out[axis] = r[axis]
    np.multiply(r[i], cos, out=out[i])
    out[i] += r[j] * sin
    np.multiply(r[j], cos, out=out[j])
    out[j] -= r[i] * sin
    return out


def _combine(vectors: np.ndarray, coef: np.ndarray) -> np.ndarray | None:
    """sum_a coef[a] * vectors[a] over the three stacked vectors (3, 3, N), in the order a = 0, 1, 2, terms with a
    zero coefficient left out and a unit one not multiplied (the same sum, exactly); None when every one is zero.
    May return a view of `vectors`."""
    out = None
    for a in range(3):
        if coef[a] != 0.0:
            term = vectors[a] if coef[a] == 1.0 else vectors[a] * coef[a]
            out = term if out is None else out + term
    return out


def _times(r: np.ndarray, m: np.ndarray) -> np.ndarray:
    """r @ m for rotations given by their columns r (3, 3, N) and one fixed matrix m (3, 3): column b of the
    product is sum_a m[a, b] r[a] (einsum's loop sums in that order, the same as `_combine`)."""
    return np.einsum("ab,aim->bim", m, r)


class Kinematics:
    """Forward kinematics of `chain`; the deviation vector is laid out as `params`."""

    def __init__(self, chain: Chain, params: list[Param]):
        self.chain = chain
        self.params = list(params)
        self.index = {p: i for i, p in enumerate(self.params)}
        self._plain = [np.array_equal(joint.rotation, np.eye(3)) for joint in chain.joints]  # no fixed rotation
        self._signs = np.array([joint.sign for joint in chain.joints], dtype=float)
        complete = set(complete_params(chain))
        for p in self.params:
            if p not in complete:
                raise ChainError(f"parameter {p.name} is not part of chain {chain.name}")

    def _split(self, dev: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        n = self.chain.dof
        dq, dt, dphi = np.zeros(n), np.zeros((n, 3)), np.zeros((n, 3))
        for p, v in zip(self.params, np.asarray(dev, dtype=float), strict=True):
            if p.kind == "dq":
                dq[p.joint] = v
            elif p.kind == "p":
                dt[p.joint, p.axis] = v
            else:
                dphi[p.joint, p.axis] = v
        return dq, dt, dphi

    def end_frames(self, q: np.ndarray, dev: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(R, o): rotation (N, 3, 3) and origin (N, 3) of the last joint frame in the base frame."""
        r, o, _ = self._forward(np.atleast_2d(q), dev, record=False)
        return np.ascontiguousarray(r.transpose(2, 1, 0)), np.ascontiguousarray(o.T)

    def _forward(self, q: np.ndarray, dev: np.ndarray | None, record: bool):
        """The last joint frame of every row of q (M, n): its rotation by columns r (3, 3, M) and its origin o
        (3, M); with `record`, the frame (axis | rotation, origin) each parameter acts in."""
        chain = self.chain
        n_rows = q.shape[0]
        if q.shape[1] != chain.dof:
            raise ChainError(f"expected {chain.dof} joint values per row, got {q.shape[1]}")
        dq, dt, dphi = self._split(np.zeros(len(self.params)) if dev is None else dev)
        # (n, M), each joint's angles contiguous: the turns read them once per joint (strided, a turn took 1.5x as long)
        angle = np.ascontiguousarray((q + dq).T) * self._signs[:, None]
        cos, sin = np.cos(angle), np.sin(angle)
        r = np.repeat(chain.base[:3, :3].T[:, :, None], n_rows, axis=2)
        o = np.repeat(chain.base[:3, 3, None], n_rows, axis=1)
        # r and o are replaced, never changed in place, so the recorded frames may share their memory
        frames: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}
        for j, joint in enumerate(chain.joints):
            if record:
                frames[(j, "dq")] = (r[joint.axis] if joint.sign == 1.0 else joint.sign * r[joint.axis], o)
            r = turned(r, joint.axis, cos[j], sin[j])
            if record:
                frames[(j, "p")] = (r, None)
            step = _combine(r, joint.translation + dt[j])
            if step is not None:
                o = o + step
            # the rest of the link is one fixed rotation: the deviations about the other two axes, in order, then
            # the nominal rotation, multiplied once and applied in one product
            link = None  # the deviations' rotations so far (None: none)
            for a in range(3):
                if a == joint.axis:
                    continue
                if record:
                    frames[(j, "phi", a)] = (r[a] if link is None else _combine(r, link[:, a]), o)  # r @ link, axis a
                if dphi[j, a] != 0.0:
                    link = rot_axis(a, dphi[j, a]) if link is None else link @ rot_axis(a, dphi[j, a])
            if link is not None:
                r = _times(r, link @ joint.rotation)
            elif not self._plain[j]:
                r = _times(r, joint.rotation)
        return r, o, frames

    def points(
        self, q: np.ndarray, tool: np.ndarray, dev: np.ndarray | None = None, rows: np.ndarray | None = None
    ) -> np.ndarray:
        """Points (N, 3) in the base frame; q (N, n) rad, tool (N, 3) or (3,) in the last joint frame; with
        `rows` (N,) q holds the distinct poses and rows[i] is the pose of row i, as in `jacobian`."""
        r, o, _ = self._forward(np.atleast_2d(q), dev, record=False)
        return np.ascontiguousarray(_tool_point(r, o, tool, rows).T)

    def jacobian(
        self, q: np.ndarray, tool: np.ndarray, dev: np.ndarray | None = None, rows: np.ndarray | None = None
    ) -> PointJacobian:
        """Point and Jacobians of N rows. q (N, n) rad, one pose per row; or, with `rows` (N,) giving each
        row's pose, q (M, n) holds the M distinct poses and the chain is walked once per pose (rows measuring
        several points of one pose, or one point from several stations, share its frames)."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        r, o, frames = self._forward(q, dev, record=True)
        acts = []  # per parameter the frame it acts in: a translation's axis (and None), a rotation's axis and point
        for par in self.params:
            if par.kind == "p":
                acts.append((frames[(par.joint, "p")][0][par.axis], None))
            else:
                acts.append(frames[(par.joint, "dq")] if par.kind == "dq" else frames[(par.joint, "phi", par.axis)])
        joints = [frames[(j, "dq")] for j in range(self.chain.dof)]
        return PointJacobian(_tool_point(r, o, tool, rows), r, acts, joints, rows)

    def upstream(self) -> np.ndarray:
        """(k, n) bool: parameter i acts before the rotation of joint j (so that rotation moves only p)."""
        out = np.zeros((len(self.params), self.chain.dof), dtype=bool)
        for i, par in enumerate(self.params):
            first = par.joint if par.kind == "dq" else par.joint + 1
            out[i, first:] = True
        return out

    def d_params_dq(self, jac: PointJacobian) -> np.ndarray:
        """(N, 3, k, n): derivative of the identification Jacobian w.r.t. the joint angles.

        A rotation of joint j turns everything downstream of it about its axis w_j, so a downstream
        column c changes by w_j x c; for a parameter upstream of joint j only the point moves, so a
        rotation column w x (p - o) changes by w x (dp/dq_j) and a translation column not at all.
        """
        wj = jac.joint_axes[:, :, None, :]
        out = cross3(wj, jac.d_params[:, :, :, None])
        up = cross3(jac.rot_axes[:, :, :, None], jac.d_q[:, :, None, :])
        mask = self.upstream()[None, None]
        return np.where(mask, up, out)


def _tool_point(r: np.ndarray, o: np.ndarray, tool: np.ndarray, rows: np.ndarray | None) -> np.ndarray:
    """(3, N) the tool point (N, 3) or (3,) of every row from its pose's frame (columns r (3, 3, M), origin
    (3, M)); `rows` gives each row's pose (None: a pose per row)."""
    if rows is not None:
        r, o = _gathered(r, rows), _gathered(o, rows)
    t = np.asarray(tool, dtype=float).T
    t = t[:, None] if t.ndim == 1 else t
    return o + (r[0] * t[0] + r[1] * t[1] + r[2] * t[2])


def row_runs(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(first row of each run of equal rows of a 2-D array that follow each other, run of each row). A table measures
    a pose's points, and its stations, one after the other: the chain is walked once per run, its frames gathered to
    the rows (`points(..., rows=)`), the same numbers as walked per row (a row's frames never depend on the others)."""
    new = np.empty(len(a), dtype=bool)
    new[:1] = True
    np.any(a[1:] != a[:-1], axis=1, out=new[1:])
    return np.flatnonzero(new), np.cumsum(new) - 1


def _gathered(per_pose: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """per_pose[..., rows]: np.take along the last axis, the same array in half the time of the index (issue 41)."""
    return np.take(per_pose, rows, axis=-1)


def calibrated_chain(chain: Chain, params: list[Param], dev: np.ndarray) -> Chain:
    """The chain with the deviations `dev` of `params` folded into its nominal geometry: its forward kinematics at
    zero deviation are `chain`'s at `dev`, exactly. Joint j's offset turns about its own axis, so it commutes with
    the joint's rotation and joins the link that follows: link = R_e(s dq) . Trans(t + dt) . R_phi . R_nom, the
    order of `Kinematics._forward` (rotations about x, y, z in that order)."""
    dq, dt, dphi = Kinematics(chain, params)._split(dev)
    joints = []
    for j, jt in enumerate(chain.joints):
        turn = rot_axis(jt.axis, jt.sign * dq[j])
        r = np.eye(3)
        for a in range(3):
            if a != jt.axis and dphi[j, a] != 0.0:
                r = r @ rot_axis(a, dphi[j, a])
        joints.append(
            dataclasses.replace(jt, translation=turn @ (jt.translation + dt[j]), rotation=turn @ r @ jt.rotation)
        )
    return Chain(chain.name, chain.base.copy(), tuple(joints))
