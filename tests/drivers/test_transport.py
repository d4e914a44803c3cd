"""drivers.transport: the limits every driver client checks (nothing waits forever), in one place for the five.

A NaN timeout compares false with everything: `timeout_s <= 0` let it through (the meteo and PLC clients did), and a
read with a NaN deadline never ends; `not timeout_s > 0` refuses it."""

import math
import socket
import time

import pytest

from trackcal.drivers.errors import ConnectionLost, DeviceTimeout
from trackcal.drivers.meteo.client import SerialMeteo
from trackcal.drivers.plc.client import ModbusCellIO
from trackcal.drivers.transport import receive, require_positive, require_settle_limits, time_left

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
