"""Batched forward kinematics of a chain with geometric deviations, and its analytic Jacobians.

For N rows at once (a row = joint vector + tool point) this returns the point in the robot base frame,
its derivative with respect to any chosen list of parameters (the identification Jacobian, paper eq. 1,
position rows), to the tool point coordinates and to the joint angles. Every elementary transform of
the complete model is applied, so a deviation of any parameter is honoured exactly, and its
Jacobian column is the exact derivative at the current deviations (not only at nominal):
  translation along axis a of frame F:  dp = R_F[:, a]
  rotation about axis a of frame F:     dp = R_F[:, a] x (p - o_F)
"""

from __future__ import annotations

import dataclasses
from functools import cached_property

import numpy as np

from trackcal.calib.model.chain import Chain, ChainError
from trackcal.calib.model.params import Param, complete_params
from trackcal.calib.model.rigid import rot_axis, skew


class PointJacobian:
    """Point and Jacobians of N rows, built from the frames of their M distinct poses (`rows` gives each row's
    pose). Every column is linear in the point p of its row: a rotation about axis w through o gives
    w x (p - o) = (o x w) - [p]x w, so per pose the chain leaves (o x w) and w, and per row one batched
    product [p]x w remains. The derivatives are computed when first asked for (identification never needs
    the joint columns)."""

    def __init__(self, p, r_end, pose_p, pose_w, joint_o, joint_w, rows):
        self.p = p  # (N, 3) point in the robot base frame, mm
        self._r_end, self._rows = r_end, rows
        self._pose_p, self._pose_w = pose_p, pose_w  # (M, 3, k): translation axis | o x w; 0 | w
        self._joint_o, self._joint_w = joint_o, joint_w  # (M, 3, n): origin and axis of every joint

    def _per_row(self, per_pose: np.ndarray) -> np.ndarray:
        return per_pose if self._rows is None else per_pose[self._rows]

    def _columns(self, pose_p: np.ndarray, pose_w: np.ndarray) -> np.ndarray:
        return self._per_row(pose_p) - skew(self.p) @ self._per_row(pose_w)

    @cached_property
    def d_params(self) -> np.ndarray:
        """(N, 3, k) derivative w.r.t. the selected parameters (mm/mm, mm/rad)."""
        return self._columns(self._pose_p, self._pose_w)

    @cached_property
    def d_point(self) -> np.ndarray:
        """(N, 3, 3) derivative w.r.t. the tool point coordinates (= end rotation)."""
        return self._per_row(self._r_end)

    @cached_property
    def d_q(self) -> np.ndarray:
        """(N, 3, n) derivative w.r.t. the joint angles (mm/rad)."""
        return self._columns(cross3(self._joint_o, self._joint_w), self._joint_w)

    @cached_property
    def joint_axes(self) -> np.ndarray:
        """(N, 3, n) unit axis of each joint in the base frame (signed)."""
        return self._per_row(self._joint_w)

    @cached_property
    def rot_axes(self) -> np.ndarray:
        """(N, 3, k) axis of each rotational parameter (zeros for translations)."""
        return self._per_row(self._pose_w)


def cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product along axis 1 with broadcasting (faster than np.cross for small batched arrays)."""
    return np.stack(
        [a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
         a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]],
        axis=1,
    )  # fmt: skip


def turned(r: np.ndarray, axis: int, cos, sin) -> np.ndarray:
    """r @ rot_axis(axis, angle) for rotations r (N, 3, 3): the turn mixes two columns of r (cos, sin of the
    angle: scalars or (N, 1))."""
    i, j = (axis + 1) % 3, (axis + 2) % 3
    out = np.empty_like(r)
    out[:, :, axis] = r[:, :, axis]
    out[:, :, i] = r[:, :, i] * cos + r[:, :, j] * sin
    out[:, :, j] = r[:, :, j] * cos - r[:, :, i] * sin
    return out


class Kinematics:
    """Forward kinematics of `chain`; the deviation vector is laid out as `params`."""

    def __init__(self, chain: Chain, params: list[Param]):
        self.chain = chain
        self.params = list(params)
        self.index = {p: i for i, p in enumerate(self.params)}
        self._plain = [np.array_equal(joint.rotation, np.eye(3)) for joint in chain.joints]  # no fixed rotation
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
        return r, o

    def _forward(self, q: np.ndarray, dev: np.ndarray | None, record: bool):
        chain = self.chain
        n_rows = q.shape[0]
        if q.shape[1] != chain.dof:
            raise ChainError(f"expected {chain.dof} joint values per row, got {q.shape[1]}")
        dq, dt, dphi = self._split(np.zeros(len(self.params)) if dev is None else dev)
        r = np.broadcast_to(chain.base[:3, :3], (n_rows, 3, 3)).copy()
        o = np.broadcast_to(chain.base[:3, 3], (n_rows, 3)).copy()
        # r and o are replaced, never changed in place, so the recorded frames may share their memory
        frames: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}
        for j, joint in enumerate(chain.joints):
            if record:
                frames[(j, "dq")] = (joint.sign * r[:, :, joint.axis], o)
            angle = joint.sign * (q[:, j, None] + dq[j])
            r = turned(r, joint.axis, np.cos(angle), np.sin(angle))
            if record:
                frames[(j, "p")] = (r, None)
            o = o + r @ (joint.translation + dt[j])
            for a in range(3):
                if a == joint.axis:
                    continue
                if record:
                    frames[(j, "phi", a)] = (r[:, :, a], o)
                if dphi[j, a] != 0.0:
                    r = turned(r, a, np.cos(dphi[j, a]), np.sin(dphi[j, a]))
            if not self._plain[j]:
                r = r @ joint.rotation
        return r, o, frames

    def points(
        self, q: np.ndarray, tool: np.ndarray, dev: np.ndarray | None = None, rows: np.ndarray | None = None
    ) -> np.ndarray:
        """Points (N, 3) in the base frame; q (N, n) rad, tool (N, 3) or (3,) in the last joint frame; with
        `rows` (N,) q holds the distinct poses and rows[i] is the pose of row i, as in `jacobian`."""
        r, o = self.end_frames(q, dev)
        if rows is not None:
            r, o = r[rows], o[rows]
        tool = np.broadcast_to(np.asarray(tool, dtype=float), o.shape)
        return o + np.einsum("nij,nj->ni", r, tool)

    def jacobian(
        self, q: np.ndarray, tool: np.ndarray, dev: np.ndarray | None = None, rows: np.ndarray | None = None
    ) -> PointJacobian:
        """Point and Jacobians of N rows. q (N, n) rad, one pose per row; or, with `rows` (N,) giving each
        row's pose, q (M, n) holds the M distinct poses and the chain is walked once per pose (rows measuring
        several points of one pose, or one point from several stations, share its frames)."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        r, o, frames = self._forward(q, dev, record=True)
        k, n = len(self.params), self.chain.dof
        pose_t, pose_w, pose_o = (np.zeros((len(q), 3, k)) for _ in range(3))
        for i, par in enumerate(self.params):
            if par.kind == "p":
                pose_t[:, :, i] = frames[(par.joint, "p")][0][:, :, par.axis]
            else:
                key = (par.joint, "dq") if par.kind == "dq" else (par.joint, "phi", par.axis)
                pose_w[:, :, i], pose_o[:, :, i] = frames[key]
        joint_w = np.stack([frames[(j, "dq")][0] for j in range(n)], axis=2)
        joint_o = np.stack([frames[(j, "dq")][1] for j in range(n)], axis=2)
        r_rows, o_rows = (r, o) if rows is None else (r[rows], o[rows])
        tool = np.broadcast_to(np.asarray(tool, dtype=float), o_rows.shape)
        p = o_rows + (r_rows @ tool[:, :, None])[:, :, 0]
        return PointJacobian(p, r, pose_t + cross3(pose_o, pose_w), pose_w, joint_o, joint_w, rows)

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
