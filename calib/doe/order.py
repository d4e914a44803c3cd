"""The one campaign order: in which sequence a campaign measures its poses, for the engine and for the twin.

Ordering for few operator interventions: station by station (the operator moves the tracker once per
station), point by point within a station (the reflector is moved once per point), every visible pose
of the plan per point. Between passes over the poses the order alternates (each joint approaches from
both directions: backlash becomes visible), and the block's reference pose (the pose the station sees
the most points from, the first on ties) is revisited at the start and the end of every point block,
i.e. at the start, middle and end of each station block (drift checks: thermal drift and moved stations
become visible). Both revisits of a block are approached from the same pose (the block opens by measuring
the pose its closing revisit comes from): a joint's backlash then shifts them alike, so a difference between
them is a drift. Before, the opening revisit came from wherever the robot was, and on the twin a 0.05 mm backlash
alone raised a drift alarm (0.18 mm, "has station S1 moved?"). Pure: from who sees what, the sequence of visits;
no robot, no tracker, no clock.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Visit:
    """One measurement of the campaign: `pose` indexes the plan's poses; `drift` marks a reference revisit."""

    station: str
    point: str
    pose: int
    drift: bool = False


def campaign_order(
    n_poses: int,
    stations: Sequence[str],
    points: Sequence[str],
    seen: Mapping[tuple[str, str], np.ndarray],
    repeat: int = 1,
    approached: bool = True,
) -> list[Visit]:
    """The visits of a campaign of `n_poses` poses passed over `repeat` times, in campaign order.

    `seen[(station, point)]` is an (n_poses,) bool array: that station sees that point at that pose. A pose
    not seen is skipped, a point seen at no pose has no block, a station seeing nothing has no block.
    `approached`: each block opens with a measurement of the pose its closing revisit is approached from, so the
    two revisits it compares are approached alike (False: the order of sessions made before, which they walk).
    """
    order = list(range(n_poses))
    visits = []
    for sid in stations:
        vis = {pid: np.asarray(seen[(sid, pid)], dtype=bool) for pid in points}
        if not any(v.any() for v in vis.values()):
            continue
        ref = int(np.argmax(sum(v.astype(int) for v in vis.values())))
        for pid in points:
            v = vis[pid]
            passes = [i for k in range(repeat) for i in (order if k % 2 == 0 else order[::-1]) if v[i]]
            if not v[ref]:
                visits += [Visit(sid, pid, i) for i in passes]
                continue
            # the closing revisit is approached from the last other pose of the passes; the opening one is too, so
            # that both see every joint's backlash from the same side (an opening revisit reached from wherever the
            # robot was would differ from the closing one by the backlash, not by a drift)
            before = next((i for i in reversed(passes) if i != ref), None) if approached else None
            opening = [Visit(sid, pid, before)] if before is not None else []
            visits += [
                *opening,
                Visit(sid, pid, ref, True),
                *(Visit(sid, pid, i) for i in passes),
                Visit(sid, pid, ref, True),
            ]
    return visits


def iso9283_order(station: str, point: str, cycles: int, sequence: Sequence[int]) -> list[Visit]:
    """The visits of an ISO 9283 pose test: one point from one station, `cycles` cycles each visiting the poses in
    `sequence` (P1, P5, P4, P3, P2: ISO 9283:1998, 7.2), always in the same order so that every pose is approached
    from the same direction; no drift revisits (the test's own repeats are its drift data, clause 7.7)."""
    return [Visit(station, point, i) for _ in range(cycles) for i in sequence]
