"""Whether a model's gain on held-out poses is real: a one-sided Wilcoxon signed-rank test on the per-pose
held-out errors, with the held-out RMS lower.

A cause joins the model only when it predicts poses it was not fitted on better than the model without it, and by
more than the folds' own scatter explains (issue 36: "any positive gain" let an encoder scale join on 0.2 um).
Both models are cross-validated on the same folds; for every pose, d = (sum of the squared held-out errors of its
rows without the cause) - (the same with it), summed over every fold that held it out (a pose at the edge of a
joint's range is held out twice: once in the partition, once by the edge fold that judges extrapolation,
`calib.diagnose.crossval.edge_rows`). H0: d is symmetric about 0; H1: the cause lowers poses' held-out errors, by
Wilcoxon's signed-rank test (Wilcoxon 1945, "Individual comparisons by ranking methods", Biometrics Bulletin 1(6);
exact null distribution up to EXACT_POSES poses without ties, else the normal approximation with the tie
correction and a continuity correction, Conover, "Practical Nonparametric Statistics", 3rd ed., section 5.7). A
rank test, not Student's paired t: held-out errors are heavy-tailed (a few poses at the edges of the ranges carry
most of the squared error) and a t test on them has little power (a backlash that cut the held-out RMS 8-fold
got p = 0.014). The mean is what the held-out RMS is made of, so the held-out RMS must fall too: a cause that
helps most poses a little and makes a few much worse (a cancellation breaking at the edge of a range) is refused.

The level is LEVEL = 1 %. Folds that share training rows make the per-pose differences slightly dependent and the
test somewhat liberal (Dietterich 1998, "Approximate statistical tests for comparing supervised classification
learning algorithms", Neural Computation 10(7)); 1 % rather than 5 % leaves room for it.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.special import ndtr  # the normal distribution function (scipy.stats: ~1 s to import)

LEVEL = 0.01  # one-sided
# the joint error map's order and ridge are chosen by cross-validation on the same poses (12 orders x 17 ridges), so
# its held-out gain is optimistic (Cawley & Talbot, "On over-fitting in model selection and subsequent selection
# bias in performance evaluation", JMLR 11, 2010): it is held to a level ten times stricter (issue 36: motor-side
# gear harmonics aliased by 20 poses passed at p = 0.002 and 0.003, and the map made fresh poses 11-20 % worse)
MAP_LEVEL = LEVEL / 10
MIN_POSES = 6  # fewer poses: no test (with 5, the smallest one-sided signed-rank p-value is 1/32; `attainable`)
EXACT_POSES = 50  # up to this many poses (and no ties) the null distribution is counted exactly


class HeldOut(NamedTuple):
    """Held-out errors of one model on one set of folds: per row the squared error (mm^2, summed over x, y, z and
    over every fold that held the row out) and how many times it was held out."""

    sq: np.ndarray  # (N,)
    count: np.ndarray  # (N,) int

    @property
    def rms_mm(self) -> float:
        """RMS of one coordinate over every held-out row (a row held out twice counts twice)."""
        return float(np.sqrt(np.sum(self.sq) / (3 * max(int(np.sum(self.count)), 1))))


def paired_pvalue(base: HeldOut, model: HeldOut, pose: list[str]) -> float:
    """One-sided p-value of H0 "the model predicts held-out poses no better than the base" (module docstring);
    1.0 when fewer than MIN_POSES poses differ."""
    labels, inv = np.unique(np.asarray(pose), return_inverse=True)
    held = np.bincount(inv, weights=base.count, minlength=len(labels)) > 0
    d = (
        np.bincount(inv, weights=base.sq, minlength=len(labels))
        - np.bincount(inv, weights=model.sq, minlength=len(labels))
    )[held]
    d = d[d != 0]  # Wilcoxon's rule: zero differences are dropped
    n = len(d)
    if n < MIN_POSES:
        return 1.0
    ranks = _midranks(np.abs(d))
    w_plus = float(np.sum(ranks[d > 0]))
    _, ties = np.unique(ranks, return_counts=True)
    if n <= EXACT_POSES and np.all(ties == 1):
        counts = _signed_rank_counts(n)  # counts[s]: subsets of the ranks 1..n summing to s
        return float(np.sum(counts[int(round(w_plus)) :]) / np.sum(counts))
    mean = n * (n + 1) / 4.0
    var = n * (n + 1) * (2 * n + 1) / 24.0 - float(np.sum(ties**3 - ties)) / 48.0
    return float(ndtr(-(w_plus - mean - 0.5) / np.sqrt(var)))


def _midranks(x: np.ndarray) -> np.ndarray:
    """Ranks 1..n of x, ties given their mean rank: a run of equal values in sorted order, ranks a + 1 .. b, takes
    (a + 1 + b) / 2, the mean of those integers exactly (a pass over the values equal to each distinct one was
    quadratic: 1 % of a diagnosis of the UR10's Series B, issue 41)."""
    order = np.argsort(x, kind="stable")
    xs = x[order]
    starts = np.flatnonzero(np.r_[True, xs[1:] != xs[:-1]])
    ends = np.r_[starts[1:], len(x)]
    ranks = np.empty(len(x))
    ranks[order] = np.repeat((starts + 1 + ends) / 2.0, ends - starts)
    return ranks


def _signed_rank_counts(n: int) -> np.ndarray:
    """How many subsets of {1..n} sum to each s = 0 .. n(n+1)/2 (the signed-rank statistic's null counts)."""
    counts = np.zeros(n * (n + 1) // 2 + 1)
    counts[0] = 1.0
    for k in range(1, n + 1):
        counts[k:] = counts[k:] + counts[:-k].copy()
    return counts


def attainable(pose: list[str], level: float = LEVEL) -> bool:
    """Whether the paired test can reach `level` on the poses `pose` at all: its smallest p-value, every one of the n
    poses better (one of the 2^n equally likely sign patterns), is 2^-n (6 poses: 1/64 > LEVEL; 7: 1/128 < LEVEL). A
    cause the F test and BIC admit where it cannot is untested, not absent."""
    n = len(set(pose))
    return n >= MIN_POSES and 2.0**-n < level


def significant(
    base: HeldOut | None, model: HeldOut | None, pose: list[str], level: float = LEVEL
) -> tuple[bool, float | None]:
    """(the model's held-out gain is significant at `level`, its p-value); (False, None) without both figures."""
    if base is None or model is None:
        return False, None
    p = paired_pvalue(base, model, pose)
    return bool(p < level and model.rms_mm < base.rms_mm), p
