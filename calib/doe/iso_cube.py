"""The ISO 9283 test cube and its five poses (ISO 9283:1998, 6.8: definitions of poses to be tested).

The cube has its edges parallel to the base frame and the largest volume the usable workspace allows; the poses
lie on the diagonal plane C1-C2-C7-C8, the rectangle through two opposite edges of the cube: P1 at the centre of
the cube, P2..P5 on the plane's two diagonals at 10 % of the diagonal length L from the corners (the standard
allows 10 +- 2 %). trackcal numbers the corners so that C1-C2 is the lower front edge and C7-C8 the upper back edge
(C1 = min x, min y, min z; C2 = max x, min y, min z; C7 = max x, max y, max z; C8 = min x, max y, max z); P2, P3,
P4, P5 are the poses near C1, C2, C7, C8. The plane's diagonals are the cube's space diagonals, L = side * sqrt(3).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trackcal.calib.doe.design import design_for_cell
from trackcal.calib.doe.poses import random_poses
from trackcal.calib.errors import CalibError
from trackcal.calib.model.cell import Cell, usable_limits_deg
from trackcal.calib.model.inverse import reach_points
from trackcal.calib.model.kinematics import Kinematics

CORNER_FRACTION = 0.10  # ISO 9283:1998, 6.8: P2..P5 at (10 +- 2) % of the diagonal from the corners
# One test cycle visits P1, P5, P4, P3, P2 (ISO 9283:1998, 7.2), each approached in the same direction.
CYCLE_ORDER = (0, 4, 3, 2, 1)
POSE_NAMES = ("P1", "P2", "P3", "P4", "P5")
# Multi-directional pose accuracy variation (ISO 9283:1998, 7.2): poses P1, P2 and P4, each approached from three
# orthogonal directions parallel to the base axes. trackcal comes in from an approach point on one side of the pose
# along each axis, the side towards the cube's centre (so the approach points stay inside the cube, where the robot
# was shown to reach; P1's on the - sides); the standard fixes the directions, not their sides.
VAP_POSES = (0, 1, 3)
AXES = ("x", "y", "z")
APPROACH_FRACTION = 0.10  # the approach point lies this fraction of the cube's side before the pose: inside the cube


class CubeError(CalibError):
    """A cube that does not fit the cell or is not a cube."""


@dataclass(frozen=True)
class IsoCube:
    centre_mm: tuple[float, float, float]
    side_mm: float

    def __post_init__(self):
        if not (np.isfinite(self.side_mm) and self.side_mm > 0) or not np.isfinite(self.centre_mm).all():
            raise CubeError(f"ISO cube: side {self.side_mm!r} mm, centre {self.centre_mm!r}: finite, side > 0 needed")

    @property
    def diagonal_mm(self) -> float:
        """L, the diagonal of the plane C1-C2-C7-C8 (a space diagonal of the cube)."""
        return self.side_mm * float(np.sqrt(3.0))

    def corners(self) -> np.ndarray:
        """C1..C8, (8, 3): C1..C4 the lower face (z min), C5..C8 the upper face, numbered as the module says."""
        lo = np.asarray(self.centre_mm, float) - self.side_mm / 2
        s = self.side_mm
        unit = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]])
        return lo + s * unit

    def plane_corners(self) -> np.ndarray:
        """C1, C2, C7, C8: the corners of the measuring plane, (4, 3)."""
        return self.corners()[[0, 1, 6, 7]]

    def poses(self, fraction: float = CORNER_FRACTION) -> np.ndarray:
        """P1..P5, (5, 3): the centre, then a point on each plane diagonal `fraction` of L from C1, C2, C7, C8."""
        if not 0.08 <= fraction <= 0.12:
            raise CubeError(f"ISO cube: poses at {fraction:.0%} of the diagonal; the standard allows 8-12 %")
        c = np.asarray(self.centre_mm, float)
        near = self.plane_corners()
        return np.vstack([c, near + fraction * 2.0 * (c - near)])


def largest_cube(box_min, box_max, centre=None) -> IsoCube:
    """The largest cube with edges parallel to the base frame inside the box [box_min, box_max] (the cell's box),
    centred on `centre` (default the box's centre)."""
    lo, hi = np.asarray(box_min, float), np.asarray(box_max, float)
    if lo.shape != (3,) or hi.shape != (3,) or not (hi > lo).all():
        raise CubeError(f"ISO cube: the box {lo.tolist()} .. {hi.tolist()} is empty")
    c = (lo + hi) / 2 if centre is None else np.asarray(centre, float)
    if c.shape != (3,) or not ((c > lo) & (c < hi)).all():
        raise CubeError(f"ISO cube: the centre {np.asarray(centre).tolist()} is not inside the box")
    half = float(np.min(np.minimum(c - lo, hi - c)))
    return IsoCube(tuple(float(v) for v in c), 2.0 * half)


@dataclass(frozen=True)
class IsoPlan:
    """The five ISO poses of a cell: joints (5, n) rad putting the TCP on P1..P5 with the test pose's orientation,
    the reflector point measured and the station measuring it, and where the nominal model puts that point."""

    cube: IsoCube
    fraction: float
    q_rad: np.ndarray
    tcp_mm: np.ndarray  # (5, 3) the TCP at q_rad, base frame (= the cube's poses)
    point: str
    station: str
    commanded_mm: np.ndarray  # (5, 3) the measured point at q_rad by the nominal model, base frame


LEVER_MM = 100.0  # three points 100 mm apart fix the orientation of the last frame (as compensation does)
HOMOTOPY = 8  # steps from P1 to each other pose
# conditioning (smallest / largest singular value of the 3-point Jacobian) below which a pose is near a singularity,
# the threshold of compensation (calib.compensate.NEAR_SINGULAR, same Jacobian)
NEAR_SINGULAR = 2e-3
SHRINK = 0.9  # a cube some pose of which is out of reach is shrunk by this factor about its centre
MIN_SIDE_MM = 50.0
# The reference points stay this far inside the cell box at the nominal poses, so that the compensated targets of a
# calibrated robot (corrections of a few mm at most: the KR-270's Table 8 deviations) stay inside it too
BOX_MARGIN_MM = 10.0
BISECTIONS = 7  # the side found to within (largest - 50 mm) / 128


def _reach(cell: Cell, kin: Kinematics, cube: IsoCube, fraction: float, q_ref: np.ndarray):
    """Joints (5, n) for the cube's poses, or why not (the first pose that fails and its reason). P1 is reached from
    q_ref, and each other pose from P1's joints along the straight line to it in HOMOTOPY steps, so that all five
    stay on one branch of the inverse kinematics (no wrist flip between two poses of the test)."""
    r0, _ = kin.end_frames(q_ref)
    tools = cell.tcp + np.array([[0.0, 0.0, 0.0], [LEVER_MM, 0.0, 0.0], [0.0, LEVER_MM, 0.0]])
    tcp = cube.poses(fraction)
    target = tcp[:, None, :] + np.einsum("ij,kj->ki", r0[0], tools - cell.tcp)[None]
    q1, _, ok1 = reach_points(kin, tools, target[:1], q_ref, max_iter=50)
    if not ok1[0]:
        return None, "P1 cannot be reached with the reference pose's orientation"
    q = np.repeat(q1, 5, axis=0)
    for s in np.linspace(0.0, 1.0, HOMOTOPY + 1)[1:]:
        q, _, ok = reach_points(kin, tools, target[:1] + s * (target - target[:1]), q, max_iter=50)
        if not ok.all():
            return None, f"P{int(np.argmin(ok)) + 1} cannot be reached with the reference pose's orientation"
    lim = np.radians(usable_limits_deg(cell))
    inside = np.all((q >= lim[:, 0]) & (q <= lim[:, 1]), axis=1)
    if cell.box_min is not None:  # every reference point BOX_MARGIN_MM inside: compensated targets move them a little
        for p in cell.tool_points.values():
            x = kin.points(q, p)
            inside &= np.all((x >= cell.box_min + BOX_MARGIN_MM) & (x <= cell.box_max - BOX_MARGIN_MM), axis=1)
    if not inside.all():
        return None, f"P{int(np.argmin(inside)) + 1} leaves the joint limits or the cell box"
    jq = kin.jacobian(np.repeat(q, 3, axis=0), np.tile(tools, (5, 1))).d_q.reshape(5, 9, -1)
    sv = np.linalg.svd(jq, compute_uv=False)
    if (sv[:, -1] / sv[:, 0] < NEAR_SINGULAR).any():
        return None, f"P{int(np.argmin(sv[:, -1] / sv[:, 0])) + 1} is near a singularity"
    return q, ""


def approach_sides(plan: IsoPlan, poses=VAP_POSES) -> list[list[str]]:
    """Per pose, the side of its approach point along x, y and z ("-x" or "+x", ...): towards the cube's centre."""
    centre = np.asarray(plan.cube.centre_mm, float)
    out = []
    for i in poses:
        toward = centre - plan.tcp_mm[i]
        out.append([("+" if toward[a] > 1e-9 else "-") + axis for a, axis in enumerate(AXES)])
    return out


def approach_joints(cell: Cell, plan: IsoPlan, poses=VAP_POSES, fraction: float = APPROACH_FRACTION):
    """Joints (len(poses), 3, n) rad of the approach points of `poses`: the TCP `fraction` of the side away from the
    pose along x, y and z on the side approach_sides gives, the tool orientation of the test, reached from the pose's
    joints (same branch of the inverse kinematics, so the move from the approach point into the pose is short and
    direct). Raises CubeError when one is out of reach, outside the joint limits or puts a reference point outside
    the cell box."""
    kin = Kinematics(cell.chain, [])
    tools = cell.tcp + np.array([[0.0, 0.0, 0.0], [LEVER_MM, 0.0, 0.0], [0.0, LEVER_MM, 0.0]])
    q_pose = plan.q_rad[list(poses)]
    r, o = kin.end_frames(q_pose)
    now = o[:, None, :] + np.einsum("nij,kj->nki", r, tools)  # (P, 3 tool points, 3)
    sign = np.array([[1.0 if side[0] == "+" else -1.0 for side in sides] for sides in approach_sides(plan, poses)])
    step = fraction * plan.cube.side_mm * sign[:, :, None] * np.eye(3)[None]  # (P, 3 axes, 3)
    target = now[:, None, :, :] + step[:, :, None, :]  # (P, 3 axes, 3 points, 3)
    start = np.repeat(q_pose, len(AXES), axis=0)
    q, _, ok = reach_points(kin, tools, target.reshape(-1, len(tools), 3), start, max_iter=50)
    q = q.reshape(len(poses), len(AXES), -1)
    ok = ok.reshape(len(poses), len(AXES))
    lim = np.radians(usable_limits_deg(cell))
    inside = np.all((q >= lim[:, 0]) & (q <= lim[:, 1]), axis=2)
    if cell.box_min is not None:
        for p in cell.tool_points.values():
            x = kin.points(q.reshape(-1, q.shape[-1]), p).reshape(*q.shape[:2], 3)
            inside &= np.all((x >= cell.box_min + BOX_MARGIN_MM) & (x <= cell.box_max - BOX_MARGIN_MM), axis=2)
    bad = np.argwhere(~(ok & inside))
    if len(bad):
        i, k = bad[0]
        raise CubeError(
            f"the approach point of {POSE_NAMES[poses[i]]} along {AXES[k]} (vAP, ISO 9283:1998, 7.2) "
            "is out of reach, outside the joint limits or puts a reference point outside the cell box"
        )
    return q


def _measured_pair(cell: Cell, q: np.ndarray) -> tuple[str, str] | None:
    """(station, point) seeing the point at every pose with the largest worst-case margin; None if none does."""
    design = design_for_cell(cell, [], q0=cell.test_pose, visibility=True)
    pids, sids = sorted(cell.tool_points), list(cell.stations)
    margins = design.visibility_margins(q).reshape(len(q), len(pids), len(sids))
    worst = margins.min(axis=0)  # (points, stations)
    k, s = np.unravel_index(int(np.argmax(worst)), worst.shape)
    return (sids[s], pids[k]) if worst[k, s] >= 0.0 else None


def _plan_at(
    cell: Cell, kin: Kinematics, q_ref: np.ndarray, side_mm, centre_mm, fraction: float, at_least: float = MIN_SIDE_MM
):
    """The largest cube about `centre_mm` (default: the TCP at q_ref) reached with q_ref's tool orientation, or
    the given side; (IsoPlan, "") or (None, why). A cube smaller than `at_least` is not looked for."""
    if centre_mm is None:
        r0, o0 = kin.end_frames(q_ref)
        centre_mm = o0[0] + r0[0] @ cell.tcp
    lo = cell.box_min if cell.box_min is not None else np.full(3, -np.inf)
    hi = cell.box_max if cell.box_max is not None else np.full(3, np.inf)
    if side_mm is not None:
        side = float(side_mm)
    elif np.isfinite(lo).all() and np.isfinite(hi).all() and ((centre_mm > lo) & (centre_mm < hi)).all():
        side = largest_cube(lo, hi, centre_mm).side_mm
    else:
        return None, "the cube's centre is outside the cell box (or the cell has none): give the side"
    if side_mm is not None:
        return _cube_plan(cell, kin, q_ref, IsoCube(tuple(float(v) for v in centre_mm), side), fraction, lo, hi)
    # the largest side that fits, by bisection between MIN_SIDE_MM and the box's largest (fitting is monotone in
    # practice: a smaller cube about the same centre needs smaller moves from the reference pose)
    best, why = _cube_plan(cell, kin, q_ref, IsoCube(tuple(float(v) for v in centre_mm), side), fraction, lo, hi)
    if best is not None:
        return best, ""
    small, big = at_least, side
    if small >= big:
        return None, f"no cube larger than {at_least:.0f} mm fits"
    if at_least > MIN_SIDE_MM:  # a candidate that cannot beat the best cube so far costs one evaluation
        best, why = _cube_plan(cell, kin, q_ref, IsoCube(tuple(float(v) for v in centre_mm), small), fraction, lo, hi)
        if best is None:
            return None, why
    for _ in range(BISECTIONS):
        mid = 0.5 * (small + big)
        plan, reason = _cube_plan(cell, kin, q_ref, IsoCube(tuple(float(v) for v in centre_mm), mid), fraction, lo, hi)
        if plan is None:
            big, why = mid, reason
        else:
            small, best = mid, plan
    return (best, "") if best is not None else (None, why)


def _cube_plan(cell, kin, q_ref, cube: IsoCube, fraction: float, lo, hi):
    """(IsoPlan, "") for this cube, or (None, why)."""
    corners = cube.corners()
    if (corners < lo).any() or (corners > hi).any():
        return None, f"ISO cube of side {cube.side_mm:.0f} mm: it leaves the cell box"
    q, why = _reach(cell, kin, cube, fraction, q_ref)
    if q is None:
        return None, f"ISO cube of side {cube.side_mm:.0f} mm: {why}"
    pair = _measured_pair(cell, q)
    if pair is None:
        return None, f"ISO cube of side {cube.side_mm:.0f} mm: no station sees one reflector point at all five poses"
    station, point = pair
    commanded = kin.points(q, cell.tool_points[point])
    return IsoPlan(cube, fraction, q, cube.poses(fraction), point, station, commanded), ""


CANDIDATES = 40  # random feasible tool orientations drawn when the test pose's gives no cube
TRIED = 40  # of which the ones a station sees best are tried first
BEAT = 1.02  # a later candidate is explored only if it holds a cube 2 % larger than the best so far


def _candidates(cell: Cell, rng: np.random.Generator) -> np.ndarray:
    """Random poses within the limits and the box, the TRIED whose best (station, point) visibility margin is largest
    first: a cube about a pose no station sees well cannot keep one point in view at all five poses."""
    q = random_poses(cell, CANDIDATES, rng)
    design = design_for_cell(cell, [], q0=cell.test_pose, visibility=True)
    margins = design.visibility_margins(q).reshape(len(q), -1)
    best = margins.max(axis=1)
    order = np.argsort(-best, kind="stable")[:TRIED]
    return q[order[best[order] >= 0.0]]


def iso_plan(
    cell: Cell, side_mm: float | None = None, centre_mm=None, fraction: float = CORNER_FRACTION, seed: int = 0
) -> IsoPlan:
    """The ISO 9283 cube of a cell and its five poses, the TCP keeping one tool orientation (the standard's poses
    differ in position only). First about the TCP at the cell's test pose with its orientation (the part of the
    workspace the cell is used in); if no cube fits there, the largest cube over random feasible poses (`seed`),
    each about its own TCP with its own orientation. A cube fits when the robot reaches its five poses within the
    joint limits less the cell's margin, every reference point in the cell box, and one station sees one reflector
    point at every pose. `side_mm` and `centre_mm` fix the cube instead (refused if it does not fit)."""
    if cell.test_pose is None or cell.tcp is None:
        raise CubeError(f"cell {cell.name} needs a test pose and a TCP for the ISO cube")
    kin = Kinematics(cell.chain, [])
    centre = None if centre_mm is None else np.asarray(centre_mm, dtype=float)
    plan, why = _plan_at(cell, kin, np.atleast_2d(cell.test_pose), side_mm, centre, fraction)
    if plan is not None:
        return plan
    best = None
    for q in _candidates(cell, np.random.default_rng(seed)):
        at_least = MIN_SIDE_MM if best is None or side_mm is not None else best.cube.side_mm * BEAT
        other, _ = _plan_at(cell, kin, q[None], side_mm, centre, fraction, at_least)
        if other is not None and (best is None or other.cube.side_mm > best.cube.side_mm):
            best = other
    if best is None:
        raise CubeError(f"{why}; no other tool orientation of {CANDIDATES} tried fits a cube either")
    return best
