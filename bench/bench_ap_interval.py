"""AP's confidence interval (calib.uncertainty_budget.norm_interval, issue 37): CPU time of one pose's interval with
its 5 % quantile ranked on the draws at the ends of T (_ratio_quantile) against every draw ranked (np.quantile of
_log_ratio over all FC_TRIALS draws, the form before issue 37, rebuilt here as the baseline), medians of interleaved
repeats, on a pose of a KR 270 acceptance test before compensation (1.2 mm off) and after (4 µm: an upper limit);
the two intervals equal to the bit."""

from __future__ import annotations

import time
from unittest import mock

import numpy as np
from scipy.spatial.transform import Rotation

from trackcal.calib import uncertainty_budget as ub
from trackcal.calib.uncertainty_budget import PoseSetting, norm_interval, pose_inputs

# a station, a tool orientation and the KR-270 tool's P1 as tests/calib/test_uncertainty_budget.py's scene: 30 cycles
# of 5 µm tracker noise, the station and point known to a few µm
R_STATION = Rotation.from_rotvec([0.3, -0.2, 2.5]).as_matrix()
T_STATION = np.array([-900.0, 3100.0, -700.0])
R_TOOL = Rotation.from_rotvec([0.1, 1.2, -0.4]).as_matrix()
COMMANDED = np.array([1500.0, 300.0, 1200.0]) + R_TOOL @ np.array([277.0, -47.0, -94.0])
STATION_U = np.array([0.004, 0.003, 0.005, 2e-6, 3e-6, 1.5e-6])
POINT_U = np.array([0.002, 0.003, 0.0025])


def every_draw_ranked(t: np.ndarray, lam: float, q: float, tail: int = 0) -> np.float64:
    """The baseline: the quantile of every draw's ratio."""
    return np.quantile(ub._log_ratio(t, lam), q)


def main() -> None:
    rng = np.random.default_rng(37)
    x = COMMANDED + rng.normal(0.0, 0.005, (30, 3))
    covs = np.broadcast_to(np.eye(3) * 0.005**2, (30, 3, 3)).copy()
    setting = PoseSetting(x @ R_STATION.T + T_STATION, R_STATION, STATION_U, R_TOOL, np.zeros(3), POINT_U, "bench")
    inputs = pose_inputs(x - x.mean(axis=0) + COMMANDED, covs, setting)
    for name, offset in (
        ("before compensation", np.array([0.9, -0.5, 0.7])),
        ("after", np.array([0.003, 0.0, 0.0025])),
    ):
        times: dict[str, list[float]] = {"ends": [], "every draw": []}
        got = {}
        for _ in range(5):
            for form in times:
                with mock.patch.object(
                    ub, "_ratio_quantile", every_draw_ranked if form == "every draw" else ub._ratio_quantile
                ):
                    t0 = time.process_time()
                    got[form] = norm_interval(offset, inputs)
                    times[form].append(time.process_time() - t0)
        t_new, t_old = (float(np.median(v)) for v in times.values())
        print(
            f"AP interval, {name}: {t_new:.3f} s CPU, every draw ranked {t_old:.3f} s ({t_old / t_new:.2f}x); "
            f"the same interval: {got['ends'] == got['every draw']}"
        )


if __name__ == "__main__":
    main()
