"""What every robot client checks of a move before anything is sent: the target's arity, its joint limits, the cell
box, the speed override. Each refusal is a MotionRefused with its code (the session's error event records it)."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

from trackcal.drivers.errors import MotionRefused


def checked_limits(
    joint_limits_deg: Sequence[tuple[float, float]], axes: Sequence[str]
) -> tuple[tuple[float, float], ...]:
    """A client's joint limits as float (low, high) pairs, one per axis, or ValueError (a constructor's argument)."""
    limits = tuple((float(lo), float(hi)) for lo, hi in joint_limits_deg)
    if len(limits) != len(axes) or any(not lo < hi for lo, hi in limits):
        raise ValueError(f"joint_limits_deg needs {len(axes)} (low, high) pairs with low < high")
    return limits


def checked_target(
    target_deg: Sequence[float],
    axes: Sequence[str],
    limits_deg: Sequence[tuple[float, float]],
    cell_box_check: Callable[[tuple[float, ...]], str | None] | None,
    device: str,
) -> tuple[float, ...]:
    """The target as a tuple, or MotionRefused (the arity, the joint limits first, then the cell box)."""
    target = tuple(float(v) for v in target_deg)
    if len(target) != len(axes):
        raise MotionRefused(f"target needs {len(axes)} joint values, got {len(target)}", code="arity", device=device)
    for name, v, (lo, hi) in zip(axes, target, limits_deg, strict=True):
        if not math.isfinite(v) or not lo <= v <= hi:
            raise MotionRefused(
                f"{name}={v} deg outside the joint limits [{lo}, {hi}] deg", code="joint_limits", device=device
            )
    reason = None if cell_box_check is None else cell_box_check(target)
    if reason:
        raise MotionRefused(f"target {target} leaves the cell box: {reason}", code="cell_box", device=device)
    return target


def checked_speed(speed_override_pct: float, device: str) -> float:
    """The speed override (%) as a float, or MotionRefused unless it rounds to 1..100."""
    speed = float(speed_override_pct)
    if not (math.isfinite(speed) and 1 <= round(speed) <= 100):
        raise MotionRefused(f"speed override {speed_override_pct} % outside 1..100 %", code="speed", device=device)
    return speed
