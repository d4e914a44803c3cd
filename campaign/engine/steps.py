"""Campaign plans: a deterministic generator of steps from a cell and a measurement plan.

The order of the measurements is the one campaign order (`calib.doe.order`: station by station, point by
point, drift revisits of a reference pose, alternating passes), on the nominal model's visibility. Around
it come the operator's steps: a prompt when the station or the point changes, and after every prompt an
explicit `resume` step: motion only resumes once the operator has left the cell, closed the door and
acknowledged.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from enum import StrEnum

import numpy as np

from trackcal.calib.doe.design import design_for_cell
from trackcal.calib.doe.iso_cube import AXES, CYCLE_ORDER, POSE_NAMES
from trackcal.calib.doe.order import campaign_order, iso9283_order
from trackcal.calib.doe.poses import points_in_box
from trackcal.calib.io import fields
from trackcal.calib.io.table import IDS, XYZ, joint_columns, row_limit
from trackcal.calib.model.cell import Cell, usable_limits_deg
from trackcal.campaign.errors import CampaignError


class StepKind(StrEnum):
    """What a step does; the value is what the session store records."""

    CHANGE_STATION = "change_station"  # operator: set the tracker up at a station
    MOVE_REFLECTOR = "move_reflector"  # operator: put the reflector on a reference point
    RESUME = "resume"  # operator: leave the cell, close the door, acknowledge
    MOVE = "move"
    SETTLE = "settle"
    MEASURE = "measure"


PROMPTS = (StepKind.CHANGE_STATION, StepKind.MOVE_REFLECTOR)  # the steps that ask the operator to act in the cell


def next_prompts(steps: list[Step]) -> list[str]:
    """The label of the first prompt after each step ("" when none follows): what the progress line names next, for
    every step in one pass from the end (a scan of the steps after each step was quadratic in the campaign's length:
    a fuzzed plan of 10^6 passes ran for minutes before its first measurement)."""
    out, label = [""] * len(steps), ""
    for k in range(len(steps) - 1, -1, -1):
        out[k] = label
        if steps[k].kind in PROMPTS:
            label = steps[k].label
    return out


@dataclass(frozen=True)
class Step:
    kind: StepKind
    station: str = ""
    point: str = ""
    pose: str = ""
    q_deg: tuple[float, ...] = ()
    drift: bool = False  # a drift-check measurement of the block's reference pose
    # ISO 9283 vAP (7.2): the side the pose is approached from ("-x", "-y", "-z"); `via` marks the move to (and the
    # settle at) the approach point before the pose, a move with no measurement
    approach: str = ""
    via: bool = False
    # ISO 9283 test velocity (6.7): the move's speed override in % of the rated velocity; 0: the session's setting
    speed_pct: float = 0.0
    warm_up: bool = False  # ISO 9283 warm-up (6.2): a move of the cycles before the test, nothing measured
    # ISO 9283 drift test (7.6): the group (1, 2, ...) of the P1 measurements, and for a group's first move the
    # campaign time (s) it waits for: the groups spread over the test's hours
    group: int = 0
    not_before_s: float = 0.0
    check: bool = False  # the field check's measurement of a known length (ISO 10360-10), not the robot's test

    def to_dict(self) -> dict:
        d = asdict(self)
        d["kind"] = str(self.kind)
        d["q_deg"] = list(self.q_deg)
        # only where set: the steps of every other plan are recorded as before
        for key in ("approach", "via", "speed_pct", "warm_up", "group", "not_before_s", "check"):
            if not d[key]:
                del d[key]
        return d

    @property
    def label(self) -> str:
        if self.kind == StepKind.CHANGE_STATION:
            return f"move the tracker to station {self.station}"
        if self.kind == StepKind.MOVE_REFLECTOR:
            return f"put the reflector on {self.point}"
        if self.kind == StepKind.RESUME:
            return "leave the cell, close the door, acknowledge"
        measure = f" ({self.point} from {self.station})" if self.kind == StepKind.MEASURE else ""
        if self.warm_up:
            return f"{self.kind} {self.pose} (warm-up: nothing is measured)"
        if self.via and self.approach:
            return f"{self.kind} to the approach point of {self.pose} on its {self.approach} side"
        if self.via:
            return f"{self.kind} {self.pose} (an approach: nothing is measured)"
        side = f" from its {self.approach} side" if self.approach else ""
        speed = f" at {self.speed_pct:g} %" if self.speed_pct and self.kind == StepKind.MOVE else ""
        return f"{self.kind} {self.pose}{side}{speed}{measure}"


class PlanError(CampaignError):
    """A plan that cannot be carried out in this cell (e.g. a point no station can see)."""


def visibility(cell: Cell, poses_deg: np.ndarray) -> dict[tuple[str, str], np.ndarray]:
    """(station, point) -> (m,) bool: the nominal model says the reflector faces the station."""
    design = design_for_cell(cell, [], q0=np.zeros(cell.chain.dof), visibility=True)
    q = np.radians(np.atleast_2d(poses_deg))
    margins = design.visibility_margins(q)  # (m * P, S) in design order: pose-major, points sorted
    pids = sorted(cell.tool_points)
    sids = list(cell.stations)
    out = {}
    for s, sid in enumerate(sids):
        m = margins[:, s].reshape(len(q), len(pids)) >= 0.0
        for k, pid in enumerate(pids):
            out[(sid, pid)] = m[:, k]
    return out


def _poses(rows: np.ndarray) -> str:
    names = [f"Q{i + 1}" for i in rows[:3]]
    more = f" and {len(rows) - 3} more" if len(rows) > 3 else ""
    return ("pose " if len(rows) == 1 else "poses ") + ", ".join(names) + more


def check_plan(cell: Cell, poses_deg: np.ndarray) -> tuple[list[str], dict[tuple[str, str], np.ndarray] | None]:
    """Problems that stop a campaign before its first prompt, for the whole plan as the controller gets it
    (4 decimals): no stations; a pose the robot cannot take (not a finite joint vector of its joints, or a joint
    outside its limits less the cell's joint_margin_deg); a pose putting a reference point outside the cell box;
    a point no station sees. With them the visibility it computed (None for poses that are not joint vectors of
    the robot), so that the steps are built from the same one."""
    if not cell.stations:
        raise PlanError(f"cell {cell.name} lists no tracker stations")
    poses = np.atleast_2d(np.asarray(poses_deg, dtype=float))
    if poses.shape[1] != cell.chain.dof or not np.all(np.isfinite(poses)):
        return [f"every pose needs {cell.chain.dof} finite joint angles (the plan has rows of {poses.shape[1]})"], None
    problems = []
    lim = usable_limits_deg(cell)
    outside = (poses < lim[:, 0]) | (poses > lim[:, 1])
    rows = np.flatnonzero(outside.any(axis=1))
    if rows.size:
        i = rows[0]
        j = int(np.flatnonzero(outside[i])[0])
        name = cell.chain.joints[j].name
        problems.append(
            f"{_poses(rows)} outside the joint limits less the {cell.joint_margin_deg:g} deg margin "
            f"(Q{i + 1}: {name} = {poses[i, j]:g} deg, usable {lim[j, 0]:g}..{lim[j, 1]:g})"
        )
    rows = np.flatnonzero(~points_in_box(cell, np.radians(poses)))
    if rows.size:
        problems.append(f"{_poses(rows)} put a reference point outside the cell box")
    vis = visibility(cell, poses)
    for pid in sorted(cell.tool_points):
        if not any(vis[(sid, pid)].any() for sid in cell.stations):
            problems.append(f"point {pid} is not visible from any station at any pose of the plan")
    return problems, vis


def _checked_vap(iso: dict, cell: Cell) -> dict | None:
    """The plan's multi-directional (vAP) block, its approach poses checked as the campaign's are."""
    vap = vap_block(iso, cell)
    if vap is None:
        return None
    problems, _ = check_plan(cell, vap["approach_deg"].reshape(-1, cell.chain.dof))
    names = [f"{POSE_NAMES[i]}'s approach along {axis}" for i in vap["poses"] for axis in AXES]
    problems = [
        re.sub(r"Q(\d+)", lambda m: names[int(m.group(1)) - 1], re.sub(r"\bposes? (?=Q)", "", p))
        for p in problems
        if not p.startswith("point ")
    ]
    if problems:
        raise PlanError("plan refused before anything moves: vAP " + "; ".join(problems))
    return vap


def _vap_steps(iso: dict, vap: dict, poses: np.ndarray, ids: list[str]) -> Iterator[Step]:
    """The multi-directional test's cycles (ISO 9283:1998, 7.2): each pose approached from each side."""
    station, point = iso["station"], iso["point"]
    speed = iso_velocities(iso)[0]  # the multi-directional test at the first test velocity (the standard's 100 %)
    for _ in range(vap["cycles"]):
        for i, pose in enumerate(vap["poses"]):
            q = tuple(float(x) for x in poses[pose])
            for k, side in enumerate(vap["approaches"][i]):
                a = tuple(float(x) for x in vap["approach_deg"][i, k])
                common = {"station": station, "point": point, "pose": ids[pose], "approach": side, "speed_pct": speed}
                yield Step(StepKind.MOVE, q_deg=a, via=True, **common)
                yield Step(StepKind.SETTLE, q_deg=a, via=True, **common)
                yield Step(StepKind.MOVE, q_deg=q, **common)
                yield Step(StepKind.SETTLE, q_deg=q, **common)
                yield Step(StepKind.MEASURE, q_deg=q, **common)


def campaign_steps(
    cell: Cell, poses_deg: np.ndarray, repeat: int = 1, iso: dict | None = None, approached: bool = True
) -> Iterator[Step]:
    """The steps of a plan: the one campaign order (calib.doe.order; `approached` as there), or with `iso` (the
    plan's `iso9283` block) the ISO 9283 pose test: its one point from its one station, cycle after cycle."""
    poses = np.round(np.atleast_2d(np.asarray(poses_deg, dtype=float)), 4)  # as the controller gets them
    problems, vis = check_plan(cell, poses)  # the visibility of the check: computed once
    if iso is not None:
        station = iso["station"]
        problems = [p for p in problems if not p.startswith("point ")]  # only the test's point must be seen
        for pid in iso_points(iso):
            if vis is not None and not vis[(station, pid)].all():
                problems.append(f"station {station} does not see point {pid} at every pose of the ISO test")
        for pid in (iso.get("field_check") or {}).get("points", []):
            if vis is not None and (pid not in cell.tool_points or not vis[(station, pid)][CYCLE_ORDER[0]]):
                problems.append(f"station {station} does not see point {pid} at P1 for the field check")
    if problems:
        raise PlanError("plan refused before anything moves: " + "; ".join(problems))
    ids = [f"Q{i + 1}" for i in range(len(poses))]
    if iso is not None and iso.get("drift"):
        yield from _drift_steps(iso, poses, ids)
        return
    if iso is None:
        visits = campaign_order(len(poses), list(cell.stations), sorted(cell.tool_points), vis, repeat, approached)
    else:
        # each test velocity (6.7) a test of its own, all its cycles in a row, every point in turn
        visits = [
            (v, speed)
            for pid in iso_points(iso)
            for speed in iso_velocities(iso)
            for v in iso9283_order(iso["station"], pid, repeat, CYCLE_ORDER)
        ]
    vap = _checked_vap(iso, cell) if iso is not None else None
    where = None
    for v, speed in visits if iso is not None else ((v, 0.0) for v in visits):
        if where is None or v.station != where[0]:
            yield Step(StepKind.CHANGE_STATION, station=v.station)
            yield Step(StepKind.RESUME, station=v.station)
            if iso is not None and where is None:  # the tracker's field check, the robot standing at P1
                yield from field_check_steps(iso, poses, ids, v.station)
        if (v.station, v.point) != where:
            yield Step(StepKind.MOVE_REFLECTOR, station=v.station, point=v.point)
            yield Step(StepKind.RESUME, station=v.station, point=v.point)
            if iso is not None and where is None:  # the warm-up (6.2): the test's cycles, nothing measured
                yield from warm_up_steps(iso, poses, ids, v.station, v.point)
            if iso is not None:  # the first cycle's P1 approached from the cycle's last pose, as every later one
                last = CYCLE_ORDER[-1]
                q = tuple(float(x) for x in poses[last])
                for kind in (StepKind.MOVE, StepKind.SETTLE):
                    yield Step(
                        kind, station=v.station, point=v.point, pose=ids[last], q_deg=q, via=True, speed_pct=speed
                    )
        where = (v.station, v.point)
        q = tuple(float(x) for x in poses[v.pose])
        at = {"station": v.station, "point": v.point, "pose": ids[v.pose], "q_deg": q, "speed_pct": speed}
        yield Step(StepKind.MOVE, **at)
        yield Step(StepKind.SETTLE, **at)
        yield Step(StepKind.MEASURE, drift=v.drift, **at)
    if vap is not None:
        yield from _vap_steps(iso, vap, poses, ids)


def drift_block(iso: dict) -> dict | None:
    """The drift test of an ISO plan (`iso9283.drift`, ISO 9283:1998, 7.6), checked: `hours` > 0, `groups` >= 2
    and `cycles` >= 2 (each group's P1 measurements); None when the plan has none."""
    block = iso.get("drift")
    if block is None:
        return None
    block = fields.mapping(block, "plan: iso9283.drift", PlanError)
    hours = fields.number(block.get("hours"), "plan: iso9283.drift.hours", PlanError)
    groups = fields.integer(block.get("groups"), "plan: iso9283.drift.groups", PlanError)
    cycles = fields.integer(block.get("cycles"), "plan: iso9283.drift.cycles", PlanError)
    if not (0 < hours < float("inf")) or groups < 2 or cycles < 2:
        raise PlanError(f"plan: iso9283.drift: expected hours > 0, groups >= 2 and cycles >= 2, got {block}")
    return {"hours": hours, "groups": groups, "cycles": cycles}


def _drift_steps(iso: dict, poses: np.ndarray, ids: list[str]) -> Iterator[Step]:
    """The drift test (7.6): `groups` groups spread evenly over `hours` (the first at once, the last at the end),
    each `cycles` cycles of the test's poses at the first test velocity, P1 measured in each cycle, the other poses
    moved through unmeasured; between groups the robot stands until the next group's time."""
    block = drift_block(iso) or {}
    station, point, speed = iso["station"], iso["point"], iso_velocities(iso)[0]
    yield Step(StepKind.CHANGE_STATION, station=station)
    yield Step(StepKind.RESUME, station=station)
    yield Step(StepKind.MOVE_REFLECTOR, station=station, point=point)
    yield Step(StepKind.RESUME, station=station, point=point)
    interval_s = block["hours"] * 3600.0 / (block["groups"] - 1)
    for g in range(block["groups"]):
        for c in range(block["cycles"]):
            for k, i in enumerate(CYCLE_ORDER):
                q = tuple(float(x) for x in poses[i])
                at = {
                    "station": station,
                    "point": point,
                    "pose": ids[i],
                    "q_deg": q,
                    "speed_pct": speed,
                    "group": g + 1,
                }
                wait = round(g * interval_s, 3) if c == 0 and k == 0 else 0.0
                measured = i == CYCLE_ORDER[0]
                yield Step(StepKind.MOVE, via=not measured, not_before_s=wait, **at)
                yield Step(StepKind.SETTLE, via=not measured, **at)
                if measured:
                    yield Step(StepKind.MEASURE, **at)


def field_check_steps(iso: dict, poses: np.ndarray, ids: list[str], station: str) -> Iterator[Step]:
    """The field check of an ISO plan (`iso9283.field_check`: two tool points whose distance is certified): the
    reflector on each point in turn, measured with the robot at P1, before the test."""
    block = iso.get("field_check")
    if not block:
        return
    points = fields.sequence(block.get("points"), "plan: iso9283.field_check.points", PlanError)
    if len(points) != 2 or points[0] == points[1] or any(not isinstance(p, str) for p in points):
        raise PlanError(f"plan: iso9283.field_check.points: expected two reference points, got {points!r}")
    q = tuple(float(x) for x in poses[CYCLE_ORDER[0]])
    for point in points:
        yield Step(StepKind.MOVE_REFLECTOR, station=station, point=point)
        yield Step(StepKind.RESUME, station=station, point=point)
        at = {"station": station, "point": point, "pose": ids[CYCLE_ORDER[0]], "q_deg": q, "check": True}
        yield Step(StepKind.MOVE, **at)
        yield Step(StepKind.SETTLE, **at)
        yield Step(StepKind.MEASURE, **at)


def warm_up_cycles(iso: dict) -> int:
    """The warm-up cycles of an ISO plan (`iso9283.warm_up_cycles`, ISO 9283:1998, 6.2), checked: an integer >= 0."""
    n = fields.integer(iso.get("warm_up_cycles", 0), "plan: iso9283.warm_up_cycles", PlanError)
    if n < 0:
        raise PlanError(f"plan: iso9283.warm_up_cycles: expected an integer >= 0, got {n}")
    return n


def warm_up_steps(iso: dict, poses: np.ndarray, ids: list[str], station: str, point: str) -> Iterator[Step]:
    """The warm-up before the test (6.2): its cycles of the test's poses in the test's order at the first test
    velocity, each pose moved to and settled at, nothing measured."""
    speed = iso_velocities(iso)[0]
    for _ in range(warm_up_cycles(iso)):
        for i in CYCLE_ORDER:
            q = tuple(float(x) for x in poses[i])
            for kind in (StepKind.MOVE, StepKind.SETTLE):
                yield Step(
                    kind, station=station, point=point, pose=ids[i], q_deg=q, via=True, speed_pct=speed, warm_up=True
                )


def plan_arrays(plan_doc: dict) -> tuple[np.ndarray, int]:
    """The poses (a list of joint vectors of JSON numbers) and the passes (an integer >= 1) of a plan."""
    poses = fields.rows(plan_doc.get("poses_deg"), "plan: poses_deg", PlanError)
    repeat = fields.integer(plan_doc.get("repeat", 1), "plan: repeat", PlanError)
    if repeat < 1:
        raise PlanError(f"plan: repeat: expected an integer >= 1, got {repeat}")
    return poses, repeat


def iso_block(plan_doc: dict, cell: Cell, n_poses: int) -> dict | None:
    """The `iso9283` block of an ISO 9283 plan (`order: iso9283`), checked: a station and a point of the cell and
    five poses; None for a calibration plan."""
    order = plan_doc.get("order", "campaign")
    if order == "campaign":
        return None
    if order != "iso9283":
        raise PlanError(f"plan: order: expected campaign or iso9283, got {order!r}")
    iso = fields.mapping(plan_doc.get("iso9283"), "plan: iso9283", PlanError)
    if iso.get("station") not in cell.stations:
        raise PlanError(f"plan: iso9283.station: {iso.get('station')!r} is no station of cell {cell.name}")
    if iso.get("point") not in cell.tool_points:
        raise PlanError(f"plan: iso9283.point: {iso.get('point')!r} is no reference point of cell {cell.name}")
    points = iso.get("points")
    if points is not None and (
        not isinstance(points, list)
        or not points
        or points[-1] != iso["point"]
        or any(p not in cell.tool_points for p in points)
        or len(set(points)) != len(points)
    ):
        raise PlanError(
            f"plan: iso9283.points: expected distinct reference points of cell {cell.name}, the test's "
            f"point {iso['point']!r} last"
        )
    if n_poses != len(CYCLE_ORDER):
        raise PlanError(f"plan: an ISO 9283 plan has {len(CYCLE_ORDER)} poses (P1..P5), this one has {n_poses}")
    iso_velocities(iso)  # checked before anything moves
    warm_up_cycles(iso)
    drift_block(iso)
    return iso


def iso_velocities(iso: dict) -> list[float]:
    """The test velocities of an ISO plan (`iso9283.velocities`, ISO 9283:1998, 6.7: % of the rated velocity, each
    a test of its own), checked: numbers in (0, 100], none twice; [0.0] (the session's speed setting) for a plan
    written before they were planned."""
    given = iso.get("velocities")
    if given is None:
        return [0.0]
    values = fields.sequence(given, "plan: iso9283.velocities", PlanError)
    if (
        not values
        or any(isinstance(v, bool) or not isinstance(v, int | float) or not 0 < v <= 100 for v in values)
        or len(set(values)) != len(values)
    ):
        raise PlanError(
            f"plan: iso9283.velocities: expected distinct percentages of the rated velocity in (0, 100], got {given!r}"
        )
    return [float(v) for v in values]


def iso_points(iso: dict) -> list[str]:
    """The points an ISO test measures in turn, each over all its cycles: `points` (the orientation test: every point
    of the tool, the test's `point` last, ISO 9283:1998, 7.2), else the one `point`."""
    return list(iso.get("points") or [iso["point"]])


def vap_block(iso: dict, cell: Cell) -> dict | None:
    """The multi-directional test of an ISO plan (`iso9283.vap`, ISO 9283:1998, 7.2), checked: `cycles` (an integer
    >= 0), `poses` (names among P1..P5), `approaches` (per pose its sides along x, y, z) and `approach_deg` (per pose,
    the joints of each approach point, as the controller gets them: 4 decimals); None when the plan has none or zero
    cycles."""
    block = iso.get("vap")
    if block is None:
        return None
    block = fields.mapping(block, "plan: iso9283.vap", PlanError)
    cycles = fields.integer(block.get("cycles", 0), "plan: iso9283.vap.cycles", PlanError)
    if cycles < 0:
        raise PlanError(f"plan: iso9283.vap.cycles: expected an integer >= 0, got {cycles}")
    if cycles == 0:
        return None
    names = block.get("poses")
    if not isinstance(names, list) or not names or any(n not in POSE_NAMES for n in names):
        raise PlanError(f"plan: iso9283.vap.poses: expected a list of names among {', '.join(POSE_NAMES)}")
    sides = block.get("approaches")
    if (
        not isinstance(sides, list)
        or len(sides) != len(names)
        or not all(
            isinstance(per, list) and [str(a)[1:] for a in per] == list(AXES) and all(str(a)[:1] in "+-" for a in per)
            for per in sides
        )
    ):
        raise PlanError(
            'plan: iso9283.vap.approaches: expected per pose the sides along x, y, z, e.g. ["-x", "+y", "-z"]'
        )
    where = "plan: iso9283.vap.approach_deg"
    per_pose = fields.sequence(block.get("approach_deg"), where, PlanError)
    flat = [q for i, sides in enumerate(per_pose) for q in fields.sequence(sides, f"{where}[{i}]", PlanError)]
    rows = fields.rows(flat, where, PlanError)
    if rows.shape != (len(names) * len(AXES), cell.chain.dof):
        raise PlanError(
            f"plan: iso9283.vap.approach_deg: expected {len(AXES)} joint vectors of "
            f"{cell.chain.dof} joints for each of {len(names)} poses"
        )
    approach = np.round(rows, 4).reshape(len(names), len(AXES), cell.chain.dof)
    return {
        "cycles": cycles,
        "poses": [POSE_NAMES.index(n) for n in names],
        "approaches": sides,
        "approach_deg": approach,
    }


def plan_steps(cell: Cell, plan_doc: dict, approached: bool = True) -> list[Step]:
    """The steps of a plan in a cell (`approached`: calib.doe.order); the whole plan is checked first
    (PlanError)."""
    poses, repeat = plan_arrays(plan_doc)
    if poses.shape[1] != cell.chain.dof:
        raise PlanError(f"plan: poses have {poses.shape[1]} joints, robot {cell.chain.name} has {cell.chain.dof}")
    # every pose measured from every station at every point on each pass, at most: a campaign whose table could not
    # be read back (calib.io.table: MAX_CELLS cells of its columns, those every table has at the least) is refused
    # before its steps are built (a fuzzed `repeat` of 10^6 built 5.5 GB of steps)
    rows = len(poses) * len(cell.stations) * len(cell.tool_points) * repeat
    limit = row_limit(len(("seq", "t_s", *IDS, *joint_columns(cell.chain.dof), *XYZ)))
    if rows > limit:
        raise PlanError(
            f"plan: repeat: {repeat} passes of {len(poses)} poses from {len(cell.stations)} stations at "
            f"{len(cell.tool_points)} points would measure up to {rows} rows, more than a measurement table holds "
            f"({limit} for {cell.chain.dof} joints)"
        )
    return list(campaign_steps(cell, poses, repeat, iso_block(plan_doc, cell, len(poses)), approached))
