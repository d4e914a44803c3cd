"""The noise floor's whole-array code (issue 41) against the row-by-row code it replaced, kept here as the reference:
the same approach directions, the same groups of comparable repeats in the same order, the same floor to 1e-12,
on the README's tables and on hypothesis-drawn ones; and no Python step per row."""

from __future__ import annotations

import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from trackcal.calib.diagnose.extensions import approach_signs
from trackcal.calib.diagnose.noise_floor import CLOSE_IN_TIME, MIN_FLOOR_DOF, comparable_repeats, noise_floor
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.io.table import MeasurementTable
from trackcal.campaign.jobs.simulate import SimulateOptions, simulate


def old_approach_signs(q: np.ndarray, tol: float = 1e-7) -> np.ndarray:
    out = np.zeros_like(q)
    state = np.zeros(q.shape[1])
    for r in range(1, len(q)):
        d = q[r] - q[r - 1]
        moved = np.abs(d) > tol
        state = np.where(moved, np.sign(d), state)
        out[r] = state
    return out


def old_comparable_repeats(table: MeasurementTable) -> list[np.ndarray]:
    signs = old_approach_signs(np.radians(table.q_deg))
    span = float(np.ptp(table.t_s)) if len(table) else 0.0
    groups: dict[tuple, list[int]] = {}
    for i, key in enumerate(zip(table.pose, table.station, table.point, map(tuple, signs), strict=True)):
        groups.setdefault(key, []).append(i)
    out = []
    for rows in groups.values():
        rows = sorted(rows, key=lambda r: table.t_s[r])
        cluster = [rows[0]]
        for r in rows[1:]:
            if table.t_s[r] - table.t_s[cluster[0]] <= CLOSE_IN_TIME * span:
                cluster.append(r)
                continue
            if len(cluster) > 1:
                out.append(np.array(cluster))
            cluster = [r]
        if len(cluster) > 1:
            out.append(np.array(cluster))
    return out


def old_floor_sigma(table: MeasurementTable) -> float | None:
    reps = old_comparable_repeats(table)
    n_dof = sum(len(g) - 1 for g in reps)
    if n_dof < MIN_FLOOR_DOF:
        return None
    ss = sum(float(np.sum((table.xyz[g] - table.xyz[g].mean(axis=0)) ** 2)) for g in reps)
    return float(np.sqrt(ss / (3 * n_dof)))


def assert_same(table: MeasurementTable) -> None:
    q = np.radians(table.q_deg)
    assert np.array_equal(approach_signs(q), old_approach_signs(q))
    new, old = comparable_repeats(table), old_comparable_repeats(table)
    assert [g.tolist() for g in new] == [g.tolist() for g in old]
    if not len(table):
        return
    floor, sigma = noise_floor(table, TrackerNoise()), old_floor_sigma(table)
    if sigma is None:
        assert floor.dof is None
    else:
        assert floor.sigma_mm == pytest.approx(sigma, rel=1e-12, abs=0.0)


# the README's `trackcal simulate` tables (its simulate section): plain, repeated, with a backlash, the UR10's
README_TABLES = [
    ("kr270", 30, 1, 1, {}),
    ("kr270", 30, 1, 3, {}),
    ("kr270", 40, 1, 1, {"backlash": 0.04}),
    ("ur10", 30, 2, 1, {}),
    ("kr270", 20, 3, 1, {"backlash": 0.05}),
]


@pytest.mark.parametrize(("cell", "poses", "seed", "repeat", "effects"), README_TABLES)
def test_readme_tables_give_the_same_floor_as_the_row_loop(cell, poses, seed, repeat, effects):
    table = simulate(SimulateOptions(cell, poses=poses, seed=seed, repeat=repeat, effects=effects))[2]
    assert_same(table)
    if repeat > 1:  # the repeated table's floor comes from its repeats: the groups were compared, not just empty
        assert comparable_repeats(table)


JOINTS = [np.array(v, dtype=float) for v in ([0, 0], [10, 10], [-10, 5], [10, -20], [0, 30])]


@st.composite
def tables(draw) -> MeasurementTable:
    n = draw(st.integers(0, 40))
    q = np.array([JOINTS[i] for i in draw(st.lists(st.integers(0, len(JOINTS) - 1), min_size=n, max_size=n))])
    steps = draw(st.lists(st.sampled_from([0.0, 0.5, 1.0, 3.0, 30.0]), min_size=n, max_size=n))
    pick = st.lists(st.sampled_from(["A", "B"]), min_size=n, max_size=n)
    xyz = draw(st.lists(st.floats(-1e3, 1e3), min_size=3 * n, max_size=3 * n))
    return MeasurementTable(
        np.arange(n), np.cumsum(steps), draw(pick), draw(pick), draw(pick), q.reshape(n, 2), np.array(xyz).reshape(n, 3)
    )


@settings(max_examples=300, deadline=None)
@given(tables())
def test_drawn_tables_give_the_same_floor_as_the_row_loop(table):
    assert_same(table)


@settings(max_examples=300, deadline=None)
@given(
    st.integers(0, 30).flatmap(
        lambda n: st.lists(
            st.lists(
                st.sampled_from([0.0, 5e-8, -5e-8, 1e-7, 2e-7, -3e-7, 0.25, -1.5, np.nan]), min_size=3, max_size=3
            ),
            min_size=n,
            max_size=n,
        )
    )
)
def test_drawn_joint_paths_give_the_same_approach_directions(steps):
    # moves at and around the 1e-7 rad tolerance, standing joints, a reading lost (NaN): the same array exactly
    q = np.cumsum(np.array(steps, dtype=float).reshape(-1, 3), axis=0)
    np.testing.assert_array_equal(approach_signs(q), old_approach_signs(q))


def test_no_python_step_per_row():
    # the cost of the check is whole-array work: the Python lines run do not grow with the rows (the row loop ran
    # several lines per row: over 100,000 on this table); a line per group of repeats returned, and here none are
    # comparable (a pose's four rows measure four points: four keys)
    n = 20_000
    rng = np.random.default_rng(0)
    q = np.repeat(rng.uniform(-90, 90, (n // 4, 6)), 4, axis=0)
    table = MeasurementTable(
        np.arange(n),
        np.arange(n, dtype=float),
        [f"Q{i // 4}" for i in range(n)],
        ["S"] * n,
        [f"P{i % 4}" for i in range(n)],
        q,
        rng.normal(0, 1, (n, 3)),
    )
    lines = 0

    def tracer(frame, event, arg):
        nonlocal lines
        lines += event == "line"
        return tracer

    sys.settrace(tracer)
    try:
        comparable_repeats(table)
    finally:
        sys.settrace(None)
    assert lines < 1_000
