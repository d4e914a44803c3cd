"""mocks.servers.kuka.motion: what the mock KR C2 reports each interpolation cycle (issue 41: a cycle of a move
rounded the joints three times; it rounds them once a step and reads the same tuple after)."""

from __future__ import annotations

import random

from hypothesis import given, settings
from hypothesis import strategies as st

from trackcal.drivers.kuka.eki_codec import KIND_MOVE, Command
from trackcal.drivers.kuka.rsi_codec import KRC2_CYCLE_S
from trackcal.mocks.servers.kuka.motion import Motion

HOME = (0.0, -90.0, 90.0, 0.0, 90.0, 0.0)  # kuka_experimental KR_C2/ros_rsi.src HOME
angles = st.floats(-170.0, 170.0, allow_nan=False)  # within a KR C2's A1 range (+-185 deg)


def motion(overshoot_deg: float) -> Motion:
    return Motion(
        HOME,
        random.Random(1),
        joint_speed_deg_s=100.0,
        settle_s=0.3,
        cycle_s=KRC2_CYCLE_S,
        overshoot_deg=overshoot_deg,
        brake_deg_s2=200.0,
    )


def test_a_step_s_report_is_rounded_once_and_read_as_the_same_tuple():
    """Fails before issue 41: every read rounded the joints again into a new tuple, and there was no set_deg."""
    m = motion(0.0)
    m.begin(Command(1, KIND_MOVE, (10.0, -80.0, 85.0, 5.0, 80.0, -15.0), 30))
    m.step()
    assert m.joints_deg is m.joints_deg
    assert m.set_deg is m.joints_deg  # during a move the set point is where the arm is


@settings(max_examples=60, deadline=None)
@given(target=st.tuples(*[angles] * 6), overshoot=st.sampled_from([0.0, 0.02]), brake_at=st.integers(1, 200))
def test_every_cycle_reports_the_arm_and_its_set_point_to_4_decimals(target, overshoot, brake_at):
    """$AXIS_ACT and the set point as the controller writes them, 4 decimals (rsi_codec: AIPos/ASPos), at every
    cycle of a move, its braking, its dwell and the residual oscillation."""
    m = motion(overshoot)
    m.begin(Command(1, KIND_MOVE, target, 50))
    for n in range(400):
        if n == brake_at and m.mode == "moving":
            m.brake()
        m.step()
        assert m.joints_deg == tuple(round(v, 4) for v in m.q)
        assert m.set_deg == tuple(round(v, 4) for v in m.q_set)
