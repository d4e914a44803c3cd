"""What every driver client checks of the limits it is given: nothing waits forever (DESIGN.md's habits), so each
timeout (and each rate a wait is computed from) must be positive, and a settle wait's tolerance and window sane.

One place for the checks the emScon, KR C2, UR, meteo and PLC clients made each in their own words."""


def require_positive(**limits: float) -> None:
    """ValueError naming the first of `limits` that is not a positive number (zero, negative or NaN)."""
    for name, value in limits.items():
        if not value > 0:
            raise ValueError(f"{name} must be positive: nothing waits forever")


def require_settle_limits(tolerance_deg: float, window_s: float, timeout_s: float) -> None:
    """A settle wait (Robot.wait_settled): a positive tolerance and timeout, a window of zero or more seconds."""
    if not (tolerance_deg > 0 and window_s >= 0 and timeout_s > 0):
        raise ValueError("tolerance_deg and timeout_s must be positive, window_s non-negative")
