"""drivers.transport: the limits every driver client checks (nothing waits forever), in one place for the five.

A NaN timeout compares false with everything: `timeout_s <= 0` let it through (the meteo and PLC clients did), and a
read with a NaN deadline never ends; `not timeout_s > 0` refuses it."""

import math
import socket
import time

import pytest
from hypothesis import given
from hypothesis import strategies as st

from trackcal.drivers.errors import ConnectionLost, DeviceTimeout
from trackcal.drivers.meteo.client import SerialMeteo
from trackcal.drivers.plc.client import ModbusCellIO
from trackcal.drivers.transport import SettleWindow, receive, require_positive, require_settle_limits, time_left

NOT_POSITIVE = [0.0, -1.0, math.nan]


@pytest.mark.parametrize("value", NOT_POSITIVE)
def test_a_limit_that_is_not_positive_is_refused_by_its_name(value):
    with pytest.raises(ValueError, match="^io_timeout_s must be positive: nothing waits forever$"):
        require_positive(connect_timeout_s=1.0, io_timeout_s=value)
    require_positive(connect_timeout_s=1e-3, io_timeout_s=60.0)


@pytest.mark.parametrize("value", NOT_POSITIVE)
def test_the_meteo_and_plc_clients_refuse_a_timeout_that_is_not_positive(value):
    with pytest.raises(ValueError, match="timeout_s must be positive"):
        SerialMeteo("/dev/nonexistent-meteo", timeout_s=value)
    with pytest.raises(ValueError, match="timeout_s must be positive"):
        ModbusCellIO("127.0.0.1", timeout_s=value)


@pytest.mark.parametrize(
    "tolerance_deg, window_s, timeout_s",
    [(0.0, 0.5, 10.0), (0.01, -0.1, 10.0), (0.01, 0.5, 0.0), (math.nan, 0.5, 10.0)],
)
def test_a_settle_wait_needs_a_tolerance_a_window_and_a_timeout(tolerance_deg, window_s, timeout_s):
    with pytest.raises(ValueError, match="tolerance_deg and timeout_s must be positive, window_s non-negative"):
        require_settle_limits(tolerance_deg, window_s, timeout_s)
    require_settle_limits(0.01, 0.0, 10.0)


# ------------------------------------------------------------------ the shared waits: time_left and receive
# the KR C2's RSI cycle (12 ms, KUKA RSI 2.3 manual, IPOC) and ABB's EGM cycle (4 ms, Application manual EGM)
CYCLES_S = st.sampled_from([0.012, 0.004])


def _frames_after_anchor(window_s: float, cycle_s: float) -> int:
    """Frames after the window's first one until window_s of controller time has passed (counted, not divided)."""
    m = 0
    while m * cycle_s < window_s - 1e-9:
        m += 1
    return m


@given(CYCLES_S, st.floats(1e-3, 2.0), st.integers(0, 60), st.integers(0, 10**6))
def test_a_settle_window_ends_the_window_after_the_last_move(cycle_s, window_s, moving, start):
    """Joints that move by twice the tolerance for `moving` frames and then stand settle at the frame window_s of
    controller time after the first standing frame, and frames_wanted said so beforehand. (A window of 0 s settles
    on the first frame: test below.)"""
    tol = 0.01
    window = SettleWindow(tol, window_s, 1e6, cycle_s, start, "robot")
    stand = start + moving  # the first frame of the standing joints
    assert window.frames_wanted(start) == _frames_after_anchor(window_s, cycle_s) + 1  # before any frame
    seq = start
    while not window.settled(seq, (2 * tol * min(seq - start, moving), 1.0)):
        seq += 1
    assert seq == stand + _frames_after_anchor(window_s, cycle_s)


@given(CYCLES_S, st.floats(0.05, 3.0), st.integers(0, 10**6))
def test_a_settle_window_that_never_settles_times_out_on_controller_time(cycle_s, timeout_s, start):
    window = SettleWindow(0.01, 10.0, timeout_s, cycle_s, start, "robot")
    seq = start
    with pytest.raises(DeviceTimeout, match="of controller time"):
        while True:
            window.settled(seq, (0.05 * (seq - start),))
            seq += 1
    n = 1  # frames fed when the timeout fell: the first count whose controller time exceeds timeout_s
    while n * cycle_s <= timeout_s:
        n += 1
    assert seq - start + 1 == n


def test_a_settle_window_of_no_time_settles_on_the_first_frame():
    assert SettleWindow(0.01, 0.0, 10.0, 0.012, 7, "robot").settled(7, (1.0, 2.0))


def test_a_settle_window_restarts_when_frames_were_skipped():
    window = SettleWindow(0.01, 0.048, 10.0, 0.012, 0, "robot")  # a window of four RSI cycles
    assert not any(window.settled(seq, (0.0,)) for seq in range(3))
    window.restart()
    assert window.frames_wanted(100) == 5  # the first frame again, then four cycles
    assert [window.settled(seq, (0.0,)) for seq in range(100, 105)] == [False] * 4 + [True]


def test_time_left_is_the_seconds_before_the_deadline_and_the_clients_error_after_it():
    def expired():
        return DeviceTimeout("no answer within 5 s while testing", device="dev")

    assert 0 < time_left(time.monotonic() + 60.0, expired) <= 60.0
    with pytest.raises(DeviceTimeout, match="^dev: no answer within 5 s while testing$"):
        time_left(time.monotonic() - 1e-6, expired)


@pytest.fixture
def pair():
    a, b = socket.socketpair()
    yield a, b
    a.close()
    b.close()


def _receive(sock, timeout_s, dropped):
    return receive(
        sock,
        4096,
        timeout_s,
        device="dev",
        failed="receive failed while testing",
        closed="the peer closed the connection while testing",
        drop=lambda: dropped.append(1),
    )


def test_receive_gives_the_bytes_that_came_or_none_when_none_came_in_time(pair):
    a, b = pair
    dropped = []
    b.sendall(b"hello")
    assert _receive(a, 1.0, dropped) == b"hello"
    assert _receive(a, 0.01, dropped) is None  # nothing sent: the read times out
    b.sendall(b"late")
    assert _receive(a, 0.0, dropped) is None and _receive(a, -1.0, dropped) is None  # no time left: not read
    assert _receive(a, 1.0, dropped) == b"late" and not dropped


def test_receive_drops_the_connection_when_the_peer_closes_it_or_the_read_fails(pair):
    a, b = pair
    dropped = []
    b.close()
    with pytest.raises(ConnectionLost, match="^dev: the peer closed the connection while testing$"):
        _receive(a, 1.0, dropped)
    assert dropped == [1]
    a.close()  # a read on a closed socket fails (EBADF)
    with pytest.raises(ConnectionLost, match="^dev: receive failed while testing: "):
        _receive(a, 1.0, dropped)
    assert dropped == [1, 1]
