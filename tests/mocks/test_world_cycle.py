"""mocks.cell.World.robot_at and mocks.twin.Twin.move_to, called at every cycle of a controller's move (issue 41:
their numpy on six values cost more than the rest of the world's cycle). The plain-float forms keep the numbers:
the rounding is np.round's to the bit, the approach signs np.where's."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from trackcal.mocks.cell import World
from trackcal.mocks.twin import Twin

joint = st.floats(-400.0, 400.0, allow_nan=False)  # beyond any axis range: +-350 deg on a KR C2's A4/A6
# steps from 0 (a joint standing) through the 1e-7 deg threshold to large moves, either way
step = st.sampled_from([0.0, 5e-8, -5e-8, 1e-7, 1.5e-7, -1.5e-7]) | st.floats(-5.0, 5.0, allow_nan=False)


@pytest.fixture(scope="module")
def twin(kr270):
    return Twin(kr270, seed=3)


@settings(max_examples=200, deadline=None)
@given(q=st.tuples(*[joint | st.sampled_from([-0.0, 0.0, -4e-5, 5e-5, -5e-5, 1.5e-4, -2.5e-4, 2.5e-4])] * 6))
def test_the_world_keeps_the_joints_as_np_round_rounds_them(twin, q):
    world = World(twin)
    world.robot_at(q)
    assert world.q_deg.tobytes() == np.round(np.asarray(q, dtype=float), 4).tobytes()  # sign of zero included


@settings(max_examples=200, deadline=None)
@given(start=st.tuples(*[joint] * 6), steps=st.lists(st.tuples(*[step] * 6), min_size=1, max_size=12))
def test_the_approach_is_the_sign_of_each_joint_s_last_move_over_1e_7_deg(twin, start, steps):
    """The reference is the twin's formula before issue 41: np.where(|d| > 1e-7, sign(d), approach)."""
    twin._last_q, twin.approach = None, np.zeros(6)
    q = np.array(start)
    twin.move_to(q)
    expected = np.zeros(6)
    for d in steps:
        nxt = q + np.array(d)
        twin.move_to(nxt)
        diff = nxt - q
        expected = np.where(np.abs(diff) > 1e-7, np.sign(diff), expected)
        q = nxt
        assert twin.approach.tobytes() == expected.tobytes()


def test_a_move_that_keeps_its_directions_keeps_the_approach_array(twin):
    """Fails before issue 41: every call made a new approach array (np.where), every cycle of every move."""
    twin._last_q, twin.approach = None, np.zeros(6)
    twin.move_to((0.0, -90.0, 90.0, 0.0, 90.0, 0.0))
    twin.move_to((1.0, -89.0, 89.0, 0.0, 91.0, 0.0))
    approach = twin.approach
    twin.move_to((2.0, -88.0, 88.0, 0.0, 92.0, 0.0))
    assert twin.approach is approach
    assert twin.approach.tolist() == [1.0, 1.0, -1.0, 0.0, 1.0, 0.0]
