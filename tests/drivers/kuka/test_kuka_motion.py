"""mocks.servers.kuka.motion: the mock KR C2's motion model, stepped cycle by cycle without sockets or threads."""

from __future__ import annotations

import math
import random

import pytest

from trackcal.drivers.kuka.eki_codec import ERR_STOPPED, KIND_MOVE, Command
from trackcal.drivers.kuka.rsi_codec import KRC2_CYCLE_S
from trackcal.mocks.servers.kuka.motion import RAISE_TIME_S, Motion, quintic, quintic_rate

HOME = (0.0, -90.0, 90.0, 0.0, 90.0, 0.0)  # kuka_experimental KR_C2/ros_rsi.src HOME
TARGET = (10.0, -80.0, 85.0, 5.0, 80.0, -15.0)


def motion(seed: int = 0, overshoot_deg: float = 0.02, brake_deg_s2: float = 200.0) -> Motion:
    return Motion(
        HOME,
        random.Random(seed),
        joint_speed_deg_s=100.0,
        settle_s=0.3,
        cycle_s=KRC2_CYCLE_S,
        overshoot_deg=overshoot_deg,
        brake_deg_s2=brake_deg_s2,
    )


def run_until_ended(m: Motion, limit: int = 10_000) -> tuple[int, tuple[Command, bool, int]]:
    for n in range(1, limit + 1):
        ended = m.step()
        if ended is not None:
            return n, ended
    raise AssertionError("the move never ended")


def test_the_quintic_profile_starts_and_ends_at_rest():
    # s(u) = 10u^3 - 15u^4 + 6u^5: s(0) = 0, s(1) = 1, zero speed at both ends, peak speed 30/16 = 1.875 at u = 1/2
    assert quintic(0.0) == 0.0 and quintic(1.0) == 1.0
    assert quintic_rate(0.0) == 0.0 and quintic_rate(1.0) == 0.0
    assert quintic_rate(0.5) == pytest.approx(1.875)


def test_a_move_lasts_its_ptp_time_then_the_dwell_and_ends_on_the_target():
    m = motion(overshoot_deg=0.0)
    cmd = Command(1, KIND_MOVE, TARGET, 50)
    m.begin(cmd)
    assert m.moving and m.command == cmd
    cycles, (ended, done, error) = run_until_ended(m)
    # the largest axis moves 15 deg at 50 % of 100 deg/s and of 100 / RAISE_TIME_S deg/s^2: the quintic's peak speed
    # is 1.875x the mean (T >= 1.875 * 15 / 50 = 0.5625 s) and its peak acceleration 10/sqrt(3) x span / T^2
    # (T >= sqrt(10/sqrt(3) * 15 / a)); the longer, rounded up to whole 12 ms cycles, then the 0.3 s dwell (25 cycles)
    a = 50.0 / RAISE_TIME_S
    t = max(1.875 * 15 / 50, math.sqrt(10 / math.sqrt(3) * 15 / a))
    assert cycles == math.ceil(t / KRC2_CYCLE_S - 1e-9) + 25
    assert (ended, done, error) == (cmd, True, 0)
    assert m.joints_deg == TARGET and m.still and m.command is None


@pytest.mark.parametrize("span", [0.5, 2.0, 15.0, 60.0])
def test_a_move_accelerates_within_the_axes_limit(span):
    """The KR C2 accelerates an axis to its rated speed in $RAISE_TIME (KR C2 Machine Data 2.1.47; the KRL sets
    $ACC_AXIS to the request's speed %), so no reported joint speeds up faster than rated speed / RAISE_TIME_S, nor runs
    faster than the rated speed; a short move is the longer for it (a 2 deg move at 100 % took 39 ms, 1.875 * 2 / 96,
    at 12,000 deg/s^2). Speeds and accelerations as differences of the 12 ms cycles' joints (the RSI positions)."""
    m = Motion(
        HOME,
        random.Random(0),
        joint_speed_deg_s=100.0,
        settle_s=0.3,
        cycle_s=KRC2_CYCLE_S,
        overshoot_deg=0.0,
        brake_deg_s2=200.0,
    )
    target = (HOME[0] + span, *HOME[1:])
    m.begin(Command(1, KIND_MOVE, target, 100))
    q = [m.q[0]]
    while m.mode == "moving":
        m.step()
        q.append(m.q[0])
    dt = KRC2_CYCLE_S
    speeds = [(b - a) / dt for a, b in zip(q, q[1:], strict=False)]
    accelerations = [(b - a) / dt for a, b in zip([0.0, *speeds], [*speeds, 0.0], strict=True)]
    assert max(abs(v) for v in speeds) <= 100.0 * (1 + 1e-9)
    # the quintic's peak acceleration, sampled every cycle, stays under the limit (a cycle's rounding up of T only
    # lowers it); 2 % for the differences taken over a cycle instead of the instant
    assert max(abs(x) for x in accelerations) <= 100.0 / RAISE_TIME_S * 1.02
    assert q[-1] == target[0]


def test_after_arrival_the_residual_oscillation_decays():
    m = motion(overshoot_deg=0.02)
    m.begin(Command(1, KIND_MOVE, TARGET, 100))
    run_until_ended(m)
    # the dwell is settle_s = 5 time constants: at most e^-5 of the overshoot (<= 0.02 deg) is left
    assert max(abs(a - b) for a, b in zip(m.q, TARGET, strict=True)) <= 0.02 * math.exp(-5) + 1e-12
    while not m.still:
        assert m.step() is None
    assert m.joints_deg == TARGET


def test_braking_stops_every_axis_together_within_the_braking_distance():
    m = motion(overshoot_deg=0.0, brake_deg_s2=50.0)
    cmd = Command(7, KIND_MOVE, TARGET, 100)
    m.begin(cmd)
    for _ in range(10):
        m.step()
    m.brake()
    assert m.moving
    _, ended = run_until_ended(m)
    assert ended == (cmd, False, ERR_STOPPED)
    [(q_stop, v_stop, q_rest)] = m.stops
    t_stop = max(abs(v) for v in v_stop) / 50.0 + KRC2_CYCLE_S
    for a, v, b in zip(q_stop, v_stop, q_rest, strict=True):
        # constant deceleration to rest in < v_max / a + one cycle: each axis travels v t / 2, plus 0.0001 deg
        # of the reported rounding
        assert abs(b - a) <= abs(v) * t_stop / 2 + 1e-4
    assert q_rest != pytest.approx(TARGET, abs=0.01) and not m.moving and m.still


def test_halt_stands_where_the_arm_is():
    m = motion()
    cmd = Command(3, KIND_MOVE, TARGET, 20)
    m.begin(cmd)
    for _ in range(20):
        m.step()
    here = m.joints_deg
    assert m.halt() == cmd
    assert m.halt() is None and m.still
    for _ in range(50):
        assert m.step() is None
    assert m.joints_deg == here


def test_same_seed_same_joints():
    def trajectory(seed: int) -> list[tuple[float, ...]]:
        m, out = motion(seed), []
        m.begin(Command(1, KIND_MOVE, TARGET, 100))
        for _ in range(200):
            m.step()
            out.append(m.joints_deg)
        return out

    assert trajectory(5) == trajectory(5)
    assert trajectory(5) != trajectory(6)  # the overshoot's amplitude is drawn from the seed
