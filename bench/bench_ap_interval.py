"""The ISO 9283 budgets' Monte-Carlo (calib.uncertainty_budget, issue 37), medians of interleaved repeats of CPU time,
each against the form before rebuilt here as its baseline, the results equal to the bit:

- AP's confidence interval (norm_interval) on a pose of a KR 270 acceptance test before compensation (1.2 mm off)
  and after (4 µm: an upper limit): its 5 % cut read from the ranked ends' order statistics (_quantile_of_lowest)
  against np.quantile over the ends padded with +inf (the form before), and against every draw ranked (the first
  form);
- RP's budget (rp_budget) of a pose of 4 cycles (the docs' example) and of 30 (the standard's): its Monte-Carlo with
  the cycles and coordinates as outer axes and its interval from the two sorted ends, against repeatability of x plus
  np.einsum of the noise and the whole sample sorted (the form before)."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable
from unittest import mock

import numpy as np
from scipy.spatial.transform import Rotation

from trackcal.calib import uncertainty_budget as ub
from trackcal.calib.uncertainty_budget import PoseSetting, norm_interval, pose_inputs, rp_budget

# a station, a tool orientation and the KR-270 tool's P1 as tests/calib/test_uncertainty_budget.py's scene: 30 cycles
# of 5 µm tracker noise, the station and point known to a few µm
R_STATION = Rotation.from_rotvec([0.3, -0.2, 2.5]).as_matrix()
T_STATION = np.array([-900.0, 3100.0, -700.0])
R_TOOL = Rotation.from_rotvec([0.1, 1.2, -0.4]).as_matrix()
COMMANDED = np.array([1500.0, 300.0, 1200.0]) + R_TOOL @ np.array([277.0, -47.0, -94.0])
STATION_U = np.array([0.004, 0.003, 0.005, 2e-6, 3e-6, 1.5e-6])
POINT_U = np.array([0.002, 0.003, 0.0025])
REPEATS = 5


def every_draw_ranked(t: np.ndarray, lam: float, q: float, tail: int = 0) -> np.float64:
    """The first form: the quantile of every draw's ratio."""
    return np.quantile(ub._log_ratio(t, lam), q)


def ends_padded(t: np.ndarray, lam: float, q: float, tail: int = ub.FC_TAIL) -> np.float64:
    """_ratio_quantile before issue 37: the ends ranked, the draws between put at +inf, np.quantile over all n."""
    n = len(t)
    sample = t[:: ub.FC_STEP]
    m = max(tail // ub.FC_STEP, 1)
    edge = np.partition(sample, (m - 1, len(sample) - m))
    low, high = edge[m - 1], edge[len(sample) - m]
    ends = (t <= low) | (t >= high)
    t_ends = t[ends]
    ranked = ub._log_ratio(t_ends, lam)
    k = int((n - 1) * q) + 2
    bound = ranked[(t_ends == low) | (t_ends == high)].min()
    if k >= len(ranked) or bound - ub.RATIO_DIP < np.partition(ranked, k)[k]:
        return np.quantile(ub._log_ratio(t, lam), q)
    ratio = np.full(n, np.inf)
    ratio[ends] = ranked
    return np.quantile(ratio, q)


def einsum_form(x: np.ndarray, chol: np.ndarray, z: np.ndarray) -> np.ndarray:
    """RP's Monte-Carlo before issue 37."""
    return ub.repeatability(x + np.einsum("nij,mnj->mni", chol, z))


def full_sort(samples: np.ndarray, p: float = ub.PROBABILITY) -> tuple[float, float]:
    """shortest_interval before issue 37: the whole sample sorted."""
    y = np.sort(np.asarray(samples, dtype=float))
    q = int(round(p * len(y)))
    r = int(np.argmin(y[q:] - y[: len(y) - q]))
    return float(y[r]), float(y[r + q])


def interleaved(forms: dict[str, dict[str, object]], run: Callable[[], object]) -> tuple[dict[str, float], dict]:
    """Median CPU seconds of `run` under each form's patches of calib.uncertainty_budget, the forms interleaved; and
    what each gave."""
    times: dict[str, list[float]] = {name: [] for name in forms}
    got = {}
    for _ in range(REPEATS):
        for name, patches in forms.items():
            with mock.patch.multiple(ub, **patches) if patches else contextlib.nullcontext():
                t0 = time.process_time()
                got[name] = run()
                times[name].append(time.process_time() - t0)
    return {name: float(np.median(v)) for name, v in times.items()}, got


def main() -> None:
    rng = np.random.default_rng(37)
    x = COMMANDED + rng.normal(0.0, 0.005, (30, 3))
    covs = np.broadcast_to(np.eye(3) * 0.005**2, (30, 3, 3)).copy()
    setting = PoseSetting(x @ R_STATION.T + T_STATION, R_STATION, STATION_U, R_TOOL, np.zeros(3), POINT_U, "bench")
    inputs = pose_inputs(x - x.mean(axis=0) + COMMANDED, covs, setting)
    forms = {
        "ends": {},
        "ends, +inf padded": {"_ratio_quantile": ends_padded},
        "every draw": {"_ratio_quantile": every_draw_ranked},
    }
    for name, offset in (
        ("before compensation", np.array([0.9, -0.5, 0.7])),
        ("after", np.array([0.003, 0.0, 0.0025])),
    ):
        t, got = interleaved(forms, lambda offset=offset: norm_interval(offset, inputs))
        new, padded, every = t.values()
        print(
            f"AP interval, {name}: {new:.3f} s CPU; +inf padded {padded:.3f} s ({padded / new:.2f}x), every draw "
            f"ranked {every:.3f} s ({every / new:.2f}x); the same interval: {len(set(got.values())) == 1}"
        )
    forms = {"outer axes": {}, "einsum": {"_noisy_repeatability": einsum_form, "shortest_interval": full_sort}}
    for n in (4, 30):
        # the robot's scatter of the docs' example, about 20 µm, and its tracker noise
        xs, cs = COMMANDED + rng.normal(0.0, 0.02, (n, 3)), covs[:n]
        t, got = interleaved(forms, lambda xs=xs, cs=cs: rp_budget(xs, cs, 0.005, "bench").to_doc())
        new, old = t.values()
        # the noise's three products summed in another order: the interval's ends agree to a few ulps of a coordinate
        ends = [
            abs(a - b) for a, b in zip(got["outer axes"]["interval95_mm"], got["einsum"]["interval95_mm"], strict=True)
        ]
        print(
            f"RP budget, {n} cycles: {new:.3f} s CPU, einsum form {old:.3f} s ({old / new:.2f}x); the interval's "
            f"ends differ by {max(ends):.1e} mm"
        )


if __name__ == "__main__":
    main()
