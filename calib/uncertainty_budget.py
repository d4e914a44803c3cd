"""The uncertainty budget of an ISO 9283 figure: every input with its standard uncertainty, its source and its
contribution, the combined standard uncertainty u_c, the coverage factor k and U (GUM, JCGM 100:2008), and, where the
figure is not linear in its inputs, the 95 % coverage interval by Monte-Carlo (GUM Supplement 1, JCGM 101:2008).

The figures of a pose are functions of its attained positions expressed in the robot base frame, x_j = R^T (y_j - t)
(y_j the tracker's measurement in its station's frame, R and t the calibration's estimate of that station) and of the
commanded position c = K_nom(q, p) (the nominal chain at the commanded joints, p the calibration's estimate of the
measured tool point). Each input below moves the offset o = x_bar - c by a vector delta = A z, z of unit variance
(normal, or rectangular on [-sqrt 3, sqrt 3]), A a 3 x m matrix the input's line carries:

- the tracker: each measurement's covariance Sigma_j from the instrument model (calib.identify.noise: the datasheet's
  MPE read as 2 sigma, Leica's "typical results are half of the MPE"; normal), averaged: Sigma_o = sum Sigma_j / n^2;
- the station estimate (model.json, its 95 % half-widths / 1.96 as standard uncertainties, its 6 components taken
  independent): a translation error v moves x by -R^T v, a rotation error w (the solver's update R' = exp([w]) R,
  t' = exp([w]) t + v) by R^T [y_bar]x w;
- the tool point estimate (model.json likewise): the commanded position moves by R_nom(q) dp;
- the reflector's centring in its nest (the tool file's `reflector.centring_um`, a maximum: rectangular per axis), for
  a reflector seated again between the calibration and the test;
- the temperature (the meteo record of the test: its half-range h, rectangular): the arm (steel, 11.5e-6/K) grows
  about its base, x alpha_steel dT, the tool (aluminium, 23e-6/K) about the flange, R_nom p alpha_al dT; the air along
  the beam differs from the tracker's sensor by as much, its refractive index by -0.93 ppm/K, the range by as much;
- the robot's repeatability as measured (a Type A evaluation, JCGM 100:2008, 4.2): the scatter of the x_j about their
  mean less the tracker's share, divided by n, the uncertainty of the barycentre of n cycles.

RP_l = l_bar + 3 S_l is not linear in the x_j: it is propagated by Monte-Carlo, M = MC_TRIALS trials with a fixed seed
(the same inputs give the same budget), the coverage interval the shortest 95 % one (JCGM 101:2008, 7.7.2).

AP_P = |o| is not linear near o = 0 (its GUM sensitivity o/|o| is not defined there), and there the measured |o| is
biased upward: |o_true + E| with E the error of the measured offset is a non-central chi (3 degrees of freedom),
E|o|^2 = |o_true|^2 + tr Sigma. The plug-in Monte-Carlo (the distribution of |o_measured + E|, JCGM 101:2008, 5.9)
adds the bias a second time: after compensation (a true AP of a few µm, the size of the noise) its interval's lower
end lay above the twin's true AP in 20 of 60 seeds (tests/campaign/jobs/test_iso9283_coverage.py). The interval of the
true AP is therefore a confidence interval by Neyman's construction (J. Neyman 1937, Phil. Trans. R. Soc. A 236, 333;
G. Casella, R. L. Berger, Statistical Inference, 2nd ed., 9.2.1 "inverting a test statistic"), its acceptance regions
ordered by the likelihood ratio of Feldman and Cousins (Phys. Rev. D 57 (1998) 3873, "unified approach"), which never
gives an empty interval and turns from an upper limit (lower end 0) to a two-sided interval by itself as |o| grows:
for each trial value theta of the true AP on a grid, the measured T = |theta u + E| (u the measured direction) is drawn
M = FC_TRIALS times from the inputs' distributions (the same draws of E for every theta, JCGM 101:2008, 7), each draw
ranked by R = f(T | theta) / f(T | theta_hat(T)), f the density of the norm of an isotropic normal vector of the
inputs' mean variance (the non-central chi of 3 degrees of freedom: only the ranking uses it; the region's 95 % is
counted in the drawn T), and theta is in the interval when the measured |o| ranks within the 95 % of its draws. Far
from 0 it is value -+ about 1.96 u_c, as before. AP's U is the larger distance from the value to the interval's
ends, the guard band of a decision (calib.decision_rule).

Measured on the twin after compensation (kr270, 60 seeds): 60 of 60 covered. It covers more than 95 % there because
the station's six components are taken independent (model.json gives their marginal half-widths only, not their
correlations) and the robot's Type A line is positive even for a robot that returns exactly: the budget's variance is
about 1.6 times the error's observed one (mean e^T Sigma^-1 e 1.95 against 3), a conservative statement.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trackcal.calib.errors import CalibError
from trackcal.calib.model.rigid import skew

COVERAGE = 2.0  # k = 2: about 95 % for a normal output (JCGM 100:2008, 6.2.1, 6.3.3)
PROBABILITY = 0.95
# JCGM 101:2008, 7.2.2: M should be large compared with 1/(1 - p), "e.g. at least 10^4 times greater": 10^4 / 0.05
MC_TRIALS = 200_000
MC_SEED = 9283
FC_TRIALS = 20_000  # draws of E per trial value of the true AP (their 5 % quantile of R: within 0.3 % of content)
FC_GRID = 400  # trial values of the true AP, over value -+ 6 sigma_max
# draws at each end of T ranked per trial value, about (the 5 % quantile reads the 1,001 lowest: _ratio_quantile),
# the ends' bounds taken from every FC_STEP-th draw; too few and every draw is ranked (the same quantile, 5 times the
# work): none of the 9,115 trial values of the ISO guide's compare (docs/guides/iso9283.md) with 1,100 or 1,200, 20 %
# less work than with 1,500 (issue 37)
FC_TAIL = 1_200
FC_STEP = 10
MC_CHUNK = 10_000  # trials per batch of RP's Monte-Carlo (30 cycles x 3 coordinates each: ~7 MB per batch)
# linear expansion coefficients at 20 degC, 1/K: carbon steel 11.5e-6 ... (structural steel 11-13e-6), aluminium
# 23e-6 (The Engineering ToolBox, "Coefficients of Linear Thermal Expansion",
# https://www.engineeringtoolbox.com/linear-expansion-coefficients-d_95.html; the brief's values)
ALPHA_STEEL = 11.5e-6
ALPHA_ALUMINIUM = 23e-6
# the air's refractivity by Edlen's simplified equation n - 1 = 7.86e-4 P / (273 + T) (as quoted in
# https://hackaday.io/project/1408/log/4229; P in kPa: 2.72e-4 at 101.325 kPa, 20 degC, the refractivity of standard
# air): d(n - 1)/dT = -7.86e-4 P / (273 + T)^2 = -0.93e-6 /K at 101.325 kPa, 20 degC
REFRACTION_PER_K = 7.86e-4 * 101.325 / 293.15**2
# a standard uncertainty from a model.json 95 % half-width (its t-quantile for the hundreds of degrees of freedom of a
# calibration: 1.96 to within 1 %)
CI95_TO_SIGMA = 1.0 / 1.96


class BudgetError(CalibError):
    """Inputs an uncertainty budget cannot be made of."""


@dataclass(frozen=True)
class Input:
    """One line of a budget: what moves the pose's offset o by A z (z of unit variance, `distribution`)."""

    name: str
    source: str
    distribution: str  # "normal" or "rectangular"
    u_text: str  # the input's standard uncertainty, as the source states it, with its unit
    a: np.ndarray  # (3, m)

    def cov(self) -> np.ndarray:
        return self.a @ self.a.T

    def draw(self, rng: np.random.Generator, m: int) -> np.ndarray:
        """m draws of the offset's error, (m, 3)."""
        k = self.a.shape[1]
        z = (
            rng.uniform(-np.sqrt(3.0), np.sqrt(3.0), (m, k))
            if self.distribution == "rectangular"
            else rng.standard_normal((m, k))
        )
        return z @ self.a.T


@dataclass(frozen=True)
class Line:
    """A budget's line as the report prints it: the input, its source and distribution, its standard uncertainty and
    its contribution |c_i| u(x_i) to the figure (mm)."""

    name: str
    source: str
    distribution: str
    u_text: str
    contribution_mm: float

    def to_doc(self) -> dict:
        return {
            "input": self.name,
            "source": self.source,
            "distribution": self.distribution,
            "standard_uncertainty": self.u_text,
            "contribution_mm": self.contribution_mm,
        }


@dataclass(frozen=True)
class Budget:
    """The budget of one figure: its lines, u_c = sqrt(sum contribution^2) (JCGM 100:2008, 5.1.2), k, U = k u_c and,
    by Monte-Carlo, the shortest 95 % coverage interval (None for a linear figure: value -+ U)."""

    figure: str
    value: float
    lines: list[Line]
    k: float = COVERAGE
    interval: tuple[float, float] | None = None
    method: str = "GUM law of propagation of uncertainty (JCGM 100:2008, 5.1.2)"

    @property
    def u_c(self) -> float:
        return float(np.sqrt(sum(line.contribution_mm**2 for line in self.lines)))

    @property
    def expanded(self) -> float:
        """U for a decision: k u_c, or for a Monte-Carlo figure the larger distance from the value to its interval."""
        if self.interval is None:
            return self.k * self.u_c
        lo, hi = self.interval
        return float(max(self.value - lo, hi - self.value))

    def to_doc(self) -> dict:
        return {
            "figure": self.figure,
            "value_mm": self.value,
            "lines": [line.to_doc() for line in self.lines],
            "u_c_mm": self.u_c,
            "k": self.k,
            "U_mm": self.k * self.u_c,
            "method": self.method,
            "interval95_mm": None if self.interval is None else list(self.interval),
            "U_decision_mm": self.expanded,
        }


def shortest_interval(samples: np.ndarray, p: float = PROBABILITY) -> tuple[float, float]:
    """The shortest interval holding a share p of the samples (JCGM 101:2008, 7.7.2: over the sorted values, the
    least y_(r + q) - y_(r), q = pM rounded to an integer, r = 1..M - q). Only the M - q lowest and the M - q highest
    values enter: those two ends are sorted (after a partition), not the whole sample."""
    y = np.asarray(samples, dtype=float)
    q = int(round(p * len(y)))
    if not 0 < q < len(y):
        raise BudgetError(f"{len(y)} Monte-Carlo trials cannot give a {p:.0%} coverage interval")
    r = len(y) - q
    part = np.partition(y, sorted({r, q}))
    low, high = np.sort(part[:r]), np.sort(part[q:])  # y_(1..M-q), y_(q+1..M)
    best = int(np.argmin(high - low))
    return float(low[best]), float(high[best])


def _sqrt_psd(c: np.ndarray) -> np.ndarray:
    """A with A A^T = c for a symmetric positive semi-definite c (negative eigenvalues from rounding set to 0)."""
    w, v = np.linalg.eigh(0.5 * (c + c.T))
    return v * np.sqrt(np.clip(w, 0.0, None))


def _um(v: float) -> str:
    return f"{v * 1000:.2f} µm"


@dataclass(frozen=True)
class PoseSetting:
    """What a pose's budget knows besides its attained positions: the station estimate and the measured tool point with
    their standard uncertainties, the commanded orientation of the last joint frame, the reflector and the
    temperature record."""

    y_station: np.ndarray  # (n, 3) mm: the measurements in the station's frame
    rotation: np.ndarray  # (3, 3) the station estimate, station <- base
    station_u: np.ndarray  # (6,) translation mm, rotation rad: standard uncertainties
    tool_rotation: np.ndarray  # (3, 3) R_nom(q): the last joint frame at the commanded joints
    tool_point: np.ndarray  # (3,) mm, in the last joint frame
    point_u: np.ndarray  # (3,) mm
    tracker: str  # the instrument, for the tracker line's source
    centring_mm: float | None = None  # the reflector's centring in its nest (a maximum), None: not stated
    temp_halfrange_k: float | None = None  # half the range of the temperatures recorded, None: not recorded


def pose_inputs(x: np.ndarray, covs: np.ndarray, s: PoseSetting) -> list[Input]:
    """The inputs of one pose's offset o = x_bar - c (module docstring), in the order the report lists them."""
    n = len(x)
    ybar = s.y_station.mean(axis=0)
    rt = s.rotation.T
    out = [
        Input(
            "tracker",
            f"{s.tracker}: datasheet MPE read as 2 sigma, mean of {n} measurements",
            "normal",
            f"{_um(float(np.sqrt(np.trace(covs.mean(axis=0)) / 3)))} per axis and measurement",
            _sqrt_psd(covs.sum(axis=0) / n**2),
        ),
        Input(
            "station estimate, translation",
            "model.json: the calibration's 95 % interval / 1.96",
            "normal",
            ", ".join(_um(v) for v in s.station_u[:3]),
            -rt * s.station_u[:3],
        ),
        Input(
            "station estimate, rotation",
            "model.json: the calibration's 95 % interval / 1.96",
            "normal",
            ", ".join(f'{np.degrees(v) * 3600:.2f}"' for v in s.station_u[3:]),
            rt @ skew(ybar) * s.station_u[3:],
        ),
        Input(
            "tool point estimate",
            "model.json: the calibration's 95 % interval / 1.96",
            "normal",
            ", ".join(_um(v) for v in s.point_u),
            s.tool_rotation * s.point_u,
        ),
    ]
    c = s.centring_mm
    out.append(
        Input(
            "reflector centring in its nest",
            "the tool file's reflector.centring_um (a maximum)"
            if c is not None
            else "not stated by the tool file (reflector.centring_um): left out",
            "rectangular",
            "-" if c is None else f"±{_um(c)} per axis",
            np.eye(3) * ((c or 0.0) / np.sqrt(3.0)),
        )
    )
    h = s.temp_halfrange_k
    hu = 0.0 if h is None else h / np.sqrt(3.0)  # a rectangular half-width h: u = h / sqrt 3 (JCGM 100:2008, 4.3.7)
    source = "not recorded: left out" if h is None else f"meteo record of the test: ±{h:.2f} K (half its range)"
    grow = ALPHA_STEEL * x.mean(axis=0) + ALPHA_ALUMINIUM * (s.tool_rotation @ s.tool_point)
    out.append(
        Input(
            "temperature: arm (steel) and tool (aluminium) expansion",
            source,
            "rectangular",
            f"{hu:.3f} K",
            (grow * hu)[:, None],
        )
    )
    beam = rt @ ybar * REFRACTION_PER_K  # the range scales by -0.93 ppm/K along the beam (its sign is immaterial)
    out.append(
        Input(
            "temperature: air along the beam (refraction)", source, "rectangular", f"{hu:.3f} K", (beam * hu)[:, None]
        )
    )
    scatter = np.cov(x.T, ddof=1) - covs.mean(axis=0) if n >= 2 else np.zeros((3, 3))
    robot = _sqrt_psd(scatter) / np.sqrt(n)
    out.append(
        Input(
            "robot repeatability (as measured)",
            f"Type A: scatter of the {n} cycles less the tracker's, / n",
            "normal",
            f"{_um(float(np.sqrt(max(np.trace(robot @ robot.T), 0.0) / 3)))} per axis",
            robot,
        )
    )
    return out


def joint_draws(inputs: list[Input], rng: np.random.Generator, m: int) -> np.ndarray:
    """m draws (m, 3) of the sum of the inputs' errors: the normal inputs' sum is normal with the sum of their
    covariances (drawn as one), the rectangular ones drawn each (their columns of no effect left out)."""
    normal = sum((i.cov() for i in inputs if i.distribution == "normal"), np.zeros((3, 3)))
    total = rng.standard_normal((m, 3)) @ _sqrt_psd(normal).T
    for i in inputs:
        if i.distribution == "rectangular" and np.abs(i.a).max() > 0:
            total += i.draw(rng, m)
    return total


_LOG_2 = np.log(2.0)


def _log_sinhc(t: np.ndarray, lam: np.ndarray | float) -> np.ndarray:
    """log(sinh(t lam) / lam), its limit log t at lam = 0 (t > 0); lam an array like t, or one value for every t.
    One value's log is taken as an array of one, by the same vectorised loop as an array's (a lone float's log may
    differ in the last bit). log1p(-exp(-2 z)) is -inf where z underflows to 0: those entries take log t instead."""
    z = np.maximum(t * lam, 1e-300)
    log_lam = np.log(np.maximum(np.atleast_1d(lam), 1e-300))
    with np.errstate(divide="ignore"):
        big = z + np.log1p(-np.exp(-2.0 * z)) - _LOG_2 - log_lam
    small = z < 1e-8
    return np.where(small, np.log(np.maximum(t, 1e-300)), big) if small.any() else big


def _mle_table(t: np.ndarray) -> np.ndarray:
    """The maximum-likelihood non-centrality lam of one draw t of a unit non-central chi of 3 degrees of freedom,
    f(t | lam) = sqrt(2/pi) (t / lam) sinh(t lam) exp(-(t^2 + lam^2) / 2): 0 for t <= sqrt 3 (the slope of log f at
    lam = 0 is lam (t^2/3 - 1)), else the root of t coth(t lam) - 1/lam - lam = 0 in (0, t), by bisection."""
    lo, hi = np.full_like(t, 1e-9), np.maximum(t, 1e-9)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        g = np.maximum(t, 1e-9) / np.tanh(np.maximum(t, 1e-9) * mid) - 1.0 / mid - mid
        lo, hi = np.where(g > 0, mid, lo), np.where(g > 0, hi, mid)
    return np.where(t > np.sqrt(3.0), 0.5 * (lo + hi), 0.0)


_T_TABLE = np.linspace(0.0, 10.0, 2001)
_LAM_TABLE = _mle_table(_T_TABLE)
# np.interp's slopes, as it forms them, and none after the last knot (where lam_hat is the knot's own value)
_SLOPES = np.append((_LAM_TABLE[1:] - _LAM_TABLE[:-1]) / (_T_TABLE[1:] - _T_TABLE[:-1]), 0.0)


def _lam_hat(t: np.ndarray) -> np.ndarray:
    """np.interp(t, _T_TABLE, _LAM_TABLE) for 0 <= t <= the table's end, bit for bit, without its binary search (the
    table is uniform: the interval is t's multiple of the step, corrected where the linspace's rounding puts t on the
    other side of a knot); np.interp's own expressions, slope (t - t_j) + lam_j, and lam_j on a knot."""
    last = len(_T_TABLE) - 1
    j = np.minimum((t * (last / _T_TABLE[-1])).astype(np.intp), last)
    j += ((j < last) & (_T_TABLE[np.minimum(j + 1, last)] <= t)).view(np.int8) - (_T_TABLE[j] > t).view(np.int8)
    t_j, lam_j = _T_TABLE[j], _LAM_TABLE[j]
    return np.where(t == t_j, lam_j, _SLOPES[j] * (t - t_j) + lam_j)


def _log_ratio(t: np.ndarray, lam: np.ndarray | float) -> np.ndarray:
    """log f(t | lam) - log f(t | lam_hat(t)) for the unit non-central chi of 3 degrees of freedom (t, lam in sigma;
    lam one value for every t, or an array like t); lam_hat beyond the table: the root of lam^2 - t lam + 1 (coth = 1
    there)."""
    far = np.sqrt(np.maximum(t * t - 4.0, 0.0))
    hat = np.where(t <= _T_TABLE[-1], _lam_hat(np.minimum(t, _T_TABLE[-1])), 0.5 * (t + far))
    return _log_sinhc(t, lam) - lam * lam / 2 - (_log_sinhc(t, hat) - hat * hat / 2)


# how far below the lower of its two sides _log_ratio may dip as a function of t (its table's interpolation): 2e-11
# measured over t in [0, 2000] and lam in [0, 1500] (tests/calib/test_uncertainty_budget.py), taken 50 times
RATIO_DIP = 1e-9


def _lerp(a: np.float64, b: np.float64, t: np.float64) -> np.float64:
    """np.quantile's interpolation between two order statistics a <= b at weight t, its expressions (numpy 2,
    numpy/lib/_function_base_impl.py, _lerp: from b when t >= 0.5), for one value."""
    diff = b - a
    return b - diff * (1 - t) if t >= 0.5 else a + diff * t


def _quantile_of_lowest(values: np.ndarray, n: int, q: float, floor: float) -> np.float64 | None:
    """np.quantile (its 'linear' method) of n values of which `values` are some and the others all at least `floor`,
    in every bit, from `values` alone: their order statistics at np.quantile's virtual index (n - 1) q and the next,
    interpolated as it does; None when the others may rank among the statistics read (the one above them not below
    `floor`)."""
    v = (n - 1) * np.float64(q)
    i = int(v)
    k = i + 2  # above both order statistics np.quantile interpolates between
    if k >= len(values):
        return None
    part = np.partition(values, (i, i + 1, k))
    if floor < part[k]:
        return None
    return _lerp(part[i], part[i + 1], v - i)


def _ratio_quantile(t: np.ndarray, lam: float, q: float, tail: int = FC_TAIL) -> np.float64:
    """np.quantile(_log_ratio(t, lam), q) in every bit, ranking only the draws at the ends of t (about `tail` at each,
    bounded by order statistics of every FC_STEP-th draw): the ratio rises with t up to its mode and falls after it (to
    RATIO_DIP), so a draw between the ends ranks at least as high as the lower of the two bounds. When that is above
    every order statistic the quantile reads, the quantile is read from the ends' ranks (_quantile_of_lowest); else
    every draw is ranked."""
    sample = t[::FC_STEP]
    m = max(tail // FC_STEP, 1)
    edge = np.partition(sample, (m - 1, len(sample) - m))
    low, high = edge[m - 1], edge[len(sample) - m]
    ends = (t <= low) | (t >= high)
    t_ends = t[ends]
    ranked = _log_ratio(t_ends, lam)
    bound = ranked[(t_ends == low) | (t_ends == high)].min()
    cut = _quantile_of_lowest(ranked, len(t), q, bound - RATIO_DIP)
    return np.quantile(_log_ratio(t, lam), q) if cut is None else cut


def norm_interval(
    offset: np.ndarray, inputs: list[Input], seed: int = MC_SEED, p: float = PROBABILITY
) -> tuple[float, float]:
    """The confidence interval (probability p) of |o_true| from the measured offset o and the inputs' errors E:
    Neyman's construction with Feldman and Cousins' ordering (module docstring)."""
    o = np.asarray(offset, dtype=float).reshape(3)
    t_obs = float(np.linalg.norm(o))
    cov = sum((i.cov() for i in inputs), np.zeros((3, 3)))
    sigma = float(np.sqrt(np.trace(cov) / 3.0))
    if sigma == 0.0:
        return t_obs, t_obs
    u = o / t_obs if t_obs > 0 else np.array([1.0, 0.0, 0.0])
    e = joint_draws(inputs, np.random.default_rng(seed), FC_TRIALS)
    ue, ee = e @ u, np.einsum("ij,ij->i", e, e)
    reach = 6.0 * float(np.sqrt(np.linalg.eigvalsh(cov).max()))
    thetas = np.linspace(max(0.0, t_obs - reach), t_obs + reach, FC_GRID)

    lams = thetas / sigma
    # the measured |o|'s rank at every trial value, in one pass: each the same bits as its own (an array's loop)
    observed = _log_ratio(np.full(FC_GRID, t_obs / sigma), lams)

    def score(k: int) -> float:
        """>= 0: the trial value k is in the acceptance region of its own ranking (Feldman and Cousins)."""
        th = thetas[k]
        t = np.multiply(ue, 2.0 * th)  # |th u + E|^2 = th^2 + 2 th u.E + E.E, in place
        t += th * th
        t += ee
        np.sqrt(np.maximum(t, 0.0, out=t), out=t)
        t /= sigma
        return observed[k] - _ratio_quantile(t, lams[k], 1.0 - p)

    # The interval is the lowest and the highest trial value accepted: each found by walking in from its end of the
    # grid, so the trial values between them (a third of the grid or more) are never ranked; the same ends as ranking
    # every value and taking the accepted ones' min and max, whatever the accepted set's shape.
    scores = []
    for k in range(FC_GRID):
        scores.append(score(k))
        if scores[-1] >= 0:
            break
    else:  # none accepted (the Monte-Carlo quantile can leave a measured value outside every region): the best
        best = thetas[int(np.argmax(scores))]
        return float(best), float(best)
    low = len(scores) - 1
    high = next((k for k in range(FC_GRID - 1, low, -1) if score(k) >= 0), low)
    return float(thetas[low]), float(thetas[high])


def ap_budget(offset: np.ndarray, inputs: list[Input], seed: int = MC_SEED) -> Budget:
    """AP_P = |o| (ISO 9283:1998, 7.2): each line's GUM contribution sqrt(e^T A A^T e), e = o/|o|, and the 95 %
    confidence interval of the true AP_P (`norm_interval`: the offset's error E drawn from the inputs, JCGM 101:2008;
    Neyman's construction with Feldman and Cousins' ordering, the module docstring)."""
    o = np.asarray(offset, dtype=float).reshape(3)
    value = float(np.linalg.norm(o))
    e = o / value if value > 0 else np.zeros(3)
    lines = [
        Line(i.name, i.source, i.distribution, i.u_text, float(np.sqrt(max(e @ i.cov() @ e, 0.0)))) for i in inputs
    ]
    return Budget(
        "AP_P",
        value,
        lines,
        interval=norm_interval(o, inputs, seed),
        method=f"Monte-Carlo (JCGM 101:2008), M = {FC_TRIALS} per trial value; 95 % confidence interval of "
        "the true AP by Neyman's construction, Feldman-Cousins ordering; lines by the GUM law of "
        "propagation (JCGM 100:2008, 5.1.2)",
    )


def _rp_of_lengths(ell: np.ndarray) -> np.ndarray:
    """RP_l = l_bar + 3 S_l of the distances l_j (..., n) of each cycle from the barycentre."""
    return ell.mean(axis=-1) + 3.0 * ell.std(axis=-1, ddof=1)


def repeatability(x: np.ndarray) -> np.ndarray:
    """RP_l = l_bar + 3 S_l (ISO 9283:1998, 7.2) of each of a stack of cycles' positions (..., n, 3)."""
    return _rp_of_lengths(np.linalg.norm(x - x.mean(axis=-2, keepdims=True), axis=-1))


def _noisy_repeatability(x: np.ndarray, chol: np.ndarray, z: np.ndarray) -> np.ndarray:
    """repeatability(x + chol z) of m draws z (m, n, 3) of each cycle's noise (chol (n, 3, 3)), with the cycles and the
    coordinates as the outer axes: numpy's reductions over the short axes of (m, n, 3) cost three times the arithmetic
    (issue 37). The same figures as the (m, n, 3) form to a few ulps of a coordinate (the noise's three products are
    summed in another order; tests/calib/test_uncertainty_budget.py)."""
    zt = np.ascontiguousarray(z.transpose(1, 2, 0))[:, None]  # (n, 1, 3, m)
    c = chol[:, :, :, None]  # (n, 3, 3, 1)
    d = x[:, :, None] + (c[:, :, 0] * zt[:, :, 0] + c[:, :, 1] * zt[:, :, 1] + c[:, :, 2] * zt[:, :, 2])
    e = d - d.mean(axis=0)  # (n, 3, m)
    ell = np.sqrt(e[:, 0] * e[:, 0] + e[:, 1] * e[:, 1] + e[:, 2] * e[:, 2])
    return _rp_of_lengths(np.ascontiguousarray(ell.T))


# what moves every cycle of a pose alike cancels in x_j - x_bar and so in RP (and in vAP, a difference of barycentres
# of the same pose; and, but for its scale, in a distance between two poses)
COMMON = ("station estimate", "tool point estimate", "reflector centring in its nest")


def rp_budget(x: np.ndarray, covs: np.ndarray, u_gum: float, tracker: str, seed: int = MC_SEED) -> Budget:
    """RP_l from the n cycles x (n, 3) with the tracker's covariances (n, 3, 3): its tracker line's GUM contribution
    `u_gum` (calib.iso9283.pose_repeatability's exact gradient), the shortest 95 % interval of RP_l over MC_TRIALS
    draws of the tracker's noise on every cycle; the inputs common to every cycle listed with no contribution, and the
    robot's scatter none: it is what RP measures."""
    x = np.asarray(x, dtype=float)
    n = len(x)
    chol = np.array([_sqrt_psd(c) for c in covs])  # (n, 3, 3)
    rng = np.random.default_rng(seed)
    draws = []
    for start in range(0, MC_TRIALS, MC_CHUNK):
        m = min(MC_CHUNK, MC_TRIALS - start)
        z = rng.standard_normal((m, n, 3))
        draws.append(_noisy_repeatability(x, chol, z))
    lines = [
        Line(
            "tracker",
            f"{tracker}: datasheet MPE read as 2 sigma, each of {n} measurements",
            "normal",
            f"{_um(float(np.sqrt(np.trace(covs.mean(axis=0)) / 3)))} per axis and measurement",
            u_gum,
        )
    ]
    lines += [Line(name, "common to every cycle: cancels in x_j - x_bar", "-", "-", 0.0) for name in COMMON]
    lines.append(Line("robot repeatability", "the measurand itself (not an input)", "-", "-", 0.0))
    return Budget(
        "RP_l",
        float(repeatability(x)),
        lines,
        interval=shortest_interval(np.concatenate(draws)),
        method=f"Monte-Carlo (JCGM 101:2008), M = {MC_TRIALS}, shortest 95 % interval; the tracker's "
        "line by the GUM law of propagation (JCGM 100:2008, 5.1.2)",
    )


def tracker_budget(figure: str, value: float, u95: float, tracker: str, common: str) -> Budget:
    """A figure whose only input that does not cancel is the tracker (vAP, RD, the orientation's): its U (k = 2)
    from calib.iso9283's exact gradient, the common inputs listed as `common` says."""
    lines = [Line("tracker", f"{tracker}: datasheet MPE read as 2 sigma", "normal", "-", u95 / COVERAGE)]
    lines += [Line(name, common, "-", "-", 0.0) for name in COMMON]
    return Budget(figure, value, lines)


def ad_budget(
    value: float, u95_tracker: float, distance_mm: float, temp_halfrange_k: float | None, tracker: str
) -> Budget:
    """AD_P = D_bar - D_c (ISO 9283:1998, 7.3), linear: the tracker (its exact gradient), the temperature (the arm's
    steel and the air's refraction scale a distance D by alpha dT and 0.93e-6 dT), the common inputs cancel (a rigid
    move of both poses, the same nest; the tool point's estimate moves both commanded positions alike at one tool
    orientation)."""
    h = temp_halfrange_k
    hu = 0.0 if h is None else h / np.sqrt(3.0)
    source = "not recorded: left out" if h is None else f"meteo record of the test: ±{h:.2f} K (half its range)"
    lines = [
        Line("tracker", f"{tracker}: datasheet MPE read as 2 sigma", "normal", "-", u95_tracker / COVERAGE),
        Line(
            "temperature: arm (steel) expansion", source, "rectangular", f"{hu:.3f} K", ALPHA_STEEL * distance_mm * hu
        ),
        Line(
            "temperature: air along the beam (refraction)",
            source,
            "rectangular",
            f"{hu:.3f} K",
            REFRACTION_PER_K * distance_mm * hu,
        ),
    ]
    lines += [Line(name, "common to both poses: cancels in their distance", "-", "-", 0.0) for name in COMMON]
    return Budget("AD_P", value, lines)
