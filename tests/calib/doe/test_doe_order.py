"""The one campaign order (calib/doe/order.py): what the engine's steps and the twin's tables both walk."""

import numpy as np
import pytest

from trackcal.calib.doe.order import Visit, campaign_order
from trackcal.calib.doe.poses import random_poses
from trackcal.campaign.engine.steps import StepKind, campaign_steps, check_plan, visibility
from trackcal.mocks.twin import Twin, simulate_campaign


def test_station_by_station_point_by_point_drift_revisits_and_alternating_passes():
    seen = {
        ("S1", "P1"): np.array([True, True, True, True]),
        ("S1", "P2"): np.array([False, True, True, False]),
        ("S2", "P1"): np.zeros(4, dtype=bool),  # S2 sees nothing: no block, no prompt
        ("S2", "P2"): np.zeros(4, dtype=bool),
    }
    got = [(v.station, v.point, v.pose, v.drift) for v in campaign_order(4, ["S1", "S2"], ["P1", "P2"], seen, 2)]
    # reference pose of S1: the one seeing the most points, the first on ties (poses 1 and 2 see both): 1. A block
    # opens on the pose its closing revisit is approached from: the last pose of its passes other than the reference
    # (P1: 0; P2: 2, its passes end on the reference itself, reached from 2)
    p1 = [("S1", "P1", 0, False), ("S1", "P1", 1, True)] + [("S1", "P1", i, False) for i in (0, 1, 2, 3, 3, 2, 1, 0)]
    p2 = [("S1", "P2", 2, False), ("S1", "P2", 1, True)] + [("S1", "P2", i, False) for i in (1, 2, 2, 1)]
    assert got == [*p1, ("S1", "P1", 1, True), *p2, ("S1", "P2", 1, True)]
    # the order of sessions made before (calib.doe.order: `approached`): no opening measurement
    legacy = [
        (v.station, v.point, v.pose, v.drift)
        for v in campaign_order(4, ["S1", "S2"], ["P1", "P2"], seen, 2, approached=False)
    ]
    assert legacy == [*p1[1:], ("S1", "P1", 1, True), *p2[1:], ("S1", "P2", 1, True)]


def test_no_drift_check_when_the_point_does_not_see_the_reference_pose():
    seen = {
        ("S1", "P1"): np.array([True, True, False]),
        ("S1", "P2"): np.array([False, True, True]),
        ("S1", "P3"): np.array([False, False, True]),
    }
    visits = campaign_order(3, ["S1"], ["P1", "P2", "P3"], seen)  # points seen per pose 1, 2, 2: the reference is 1
    assert [v for v in visits if v.point == "P3"] == [Visit("S1", "P3", 2)]


def test_engine_steps_and_twin_table_walk_the_same_order(kr270):
    poses = np.round(np.degrees(random_poses(kr270, 12, np.random.default_rng(3))), 4)
    poses = poses[[not check_plan(kr270, q[None])[0] for q in poses]]  # those inside the joint margins
    assert len(poses) >= 6
    steps = [s for s in campaign_steps(kr270, poses, 2) if s.kind == StepKind.MEASURE]
    order = campaign_order(len(poses), list(kr270.stations), sorted(kr270.tool_points), visibility(kr270, poses), 2)
    assert [(s.station, s.point, s.pose, s.drift) for s in steps] == [
        (v.station, v.point, f"Q{v.pose + 1}", v.drift) for v in order
    ]
    twin = Twin(kr270, seed=3)
    table = simulate_campaign(twin, poses, repeat=2)
    seen = {
        (s, p): np.array([twin.visible(q, p, s) for q in poses])
        for s in sorted(kr270.stations)
        for p in sorted(kr270.tool_points)
    }
    expected = campaign_order(len(poses), sorted(kr270.stations), sorted(kr270.tool_points), seen, 2)
    assert list(zip(table.station, table.point, table.pose, strict=True)) == [
        (v.station, v.point, f"Q{v.pose + 1}") for v in expected
    ]


@pytest.mark.parametrize("approached", [True, False])
def test_a_blocks_two_revisits_see_the_same_backlash(kr270, approached):
    """The twin with every joint's backlash (0.05 mm), noise-free, walked in campaign order: the opening and the
    closing revisit of each block are approached from the same pose, so they are the same point; in the order of
    the sessions made before (`approached=False`) the first block's opening revisit came from the robot's start and
    differed by the backlash (0.18 mm on the README's plan)."""
    poses = np.round(np.degrees(random_poses(kr270, 12, np.random.default_rng(3))), 4)
    poses = poses[[not check_plan(kr270, q[None])[0] for q in poses]][:6]
    twin = Twin(kr270, seed=3, effects={"backlash": 0.05})
    stations, points = sorted(kr270.stations), sorted(kr270.tool_points)
    seen = {(s, p): np.array([twin.visible(q, p, s) for q in poses]) for s in stations for p in points}
    revisits: dict[tuple[str, str], list[np.ndarray]] = {}
    for v in campaign_order(len(poses), stations, points, seen, 3, approached):
        twin.move_to(poses[v.pose])
        if v.drift:
            revisits.setdefault((v.station, v.point), []).append(twin.exact(poses[v.pose], v.point, v.station))
    assert len(revisits) >= 4 and all(len(r) == 2 for r in revisits.values())
    moved = [float(np.linalg.norm(b - a)) for a, b in revisits.values()]
    if approached:
        assert max(moved) < 1e-9
    else:  # the backlash is the 0.05 mm a geometric calibration cannot absorb; its shift at the TCP is larger
        assert moved[0] > 0.05
