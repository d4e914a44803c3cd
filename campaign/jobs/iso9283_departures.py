"""The departures of a test from the conditions ISO 9283:1998 sets (clause 6, numbers as calib.iso9283_clauses
checked them), each one line for the report's box: a velocity not the standard's (6.7), the load not stated or
none (6.6), no warm-up (6.2), fewer than 30 cycles (6.9), a cube smaller than the largest the robot reaches (6.8)."""

from __future__ import annotations

from trackcal.calib.iso9283 import CYCLES
from trackcal.calib.iso9283_clauses import clause

STANDARD_VELOCITIES = (100.0, 50.0, 10.0)  # 6.7: 100 %, 50 % and 10 % of the rated velocity
SIDE_SLACK_MM = 1.0  # a cube within this of the largest is the largest (the search bisects to a few mm)


def departures(
    iso: dict, speed: float, cycles: int, conditions: dict[str, str], no_load: str, unloaded: str
) -> list[str]:
    """The departures of one test (the plan's `iso9283` block, the test's velocity, its cycles, its conditions)."""
    out = []
    planned = [float(v) for v in iso.get("velocities") or []]
    if not speed:
        out.append(
            f"no test velocity planned: {conditions.get('speed', '-')} ({clause('velocities')} asks 100 %, "
            "50 % and 10 % of the rated velocity)"
        )
    elif sorted(planned, reverse=True) != list(STANDARD_VELOCITIES):
        out.append(
            f"test velocities {', '.join(f'{v:g}' for v in planned)} % of the rated, not the standard's "
            f"100, 50 and 10 % ({clause('velocities')})"
        )
    load = conditions.get("load", no_load)
    if load == no_load:
        out.append(f"load not stated ({clause('load')}: the test at 100 % of the rated load)")
    elif load.strip().lower() == unloaded:
        out.append(f"tested unloaded ({clause('load')}: the test at 100 % of the rated load)")
    if not int(iso.get("warm_up_cycles") or 0):
        out.append(f"no warm-up before the test ({clause('warm-up')})")
    if cycles < CYCLES:
        out.append(f"{cycles} cycles, fewer than the {CYCLES} of {clause('cycles')}")
    side, largest = iso.get("cube_side_mm"), iso.get("largest_side_mm")
    if side is not None and largest is not None and side < largest - SIDE_SLACK_MM:
        out.append(
            f"cube side {side:.1f} mm, smaller than the largest the robot reaches about its centre "
            f"({largest:.1f} mm; {clause('poses')})"
        )
    return out
