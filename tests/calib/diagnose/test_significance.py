"""The paired held-out test's reach (calib.diagnose.significance): on n poses its smallest p-value is 2^-n."""

import numpy as np
import pytest

from trackcal.calib.diagnose.significance import LEVEL, MAP_LEVEL, HeldOut, attainable, paired_pvalue


def poses(n: int) -> list[str]:
    """n poses of 3 rows each (a pose seen by three reflectors)."""
    return [f"Q{i}" for i in range(n) for _ in range(3)]


@pytest.mark.parametrize("n", [6, 7, 9, 10])
def test_attainable_is_whether_every_pose_better_reaches_the_level(n):
    # every pose better by distinct amounts: the one sign pattern of 2^n as extreme, p = 2^-n (6 poses: 1/64 above
    # LEVEL = 1 %, 7: 1/128 below; MAP_LEVEL = 0.1 %: 9 poses 1/512 above, 10 poses 1/1024 below)
    base = HeldOut(np.ones(3 * n), np.ones(3 * n, dtype=int))
    better = HeldOut(1.0 - 0.01 * np.repeat(np.arange(1, n + 1), 3), np.ones(3 * n, dtype=int))
    smallest = paired_pvalue(base, better, poses(n))
    assert smallest == pytest.approx(2.0**-n)
    assert attainable(poses(n)) == (smallest < LEVEL) == (n >= 7)
    assert attainable(poses(n), MAP_LEVEL) == (smallest < MAP_LEVEL) == (n >= 10)


def test_too_few_poses_for_any_test_are_not_attainable():
    # fewer than MIN_POSES = 6 poses: no test at all (paired_pvalue answers 1.0), whatever the level
    assert not attainable(poses(5), level=1.0)
