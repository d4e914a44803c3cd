"""drivers.transport: the limits every driver client checks (nothing waits forever), in one place for the five.

A NaN timeout compares false with everything: `timeout_s <= 0` let it through (the meteo and PLC clients did), and a
read with a NaN deadline never ends; `not timeout_s > 0` refuses it."""

import math

import pytest

from trackcal.drivers.meteo.client import SerialMeteo
from trackcal.drivers.plc.client import ModbusCellIO
from trackcal.drivers.transport import require_positive, require_settle_limits

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


@pytest.mark.parametrize("tolerance_deg, window_s, timeout_s", [(0.0, 0.5, 10.0), (0.01, -0.1, 10.0),
                                                                (0.01, 0.5, 0.0), (math.nan, 0.5, 10.0)])  # fmt: skip
def test_a_settle_wait_needs_a_tolerance_a_window_and_a_timeout(tolerance_deg, window_s, timeout_s):
    with pytest.raises(ValueError, match="tolerance_deg and timeout_s must be positive, window_s non-negative"):
        require_settle_limits(tolerance_deg, window_s, timeout_s)
    require_settle_limits(0.01, 0.0, 10.0)
