"""ISO 9283:1998 pose characteristics from attained positions, with their uncertainty from the instrument.

ISO 9283:1998, *Manipulating industrial robots -- Performance criteria and related test methods*, clause 7. A test
commands the same pose `n` times (30 cycles, clause 6.9) and measures the attained positions x_j (j = 1..n) of the
reference point; c is the commanded position. Every figure below is the standard's formula, cited by clause
(calib.iso9283_clauses: the numbers checked against the standard's contents):

- 7.2 pose accuracy:         AP_P = |x_bar - c|,  AP_x = x_bar - c_x (each coordinate),  x_bar = (1/n) sum x_j;
                              orientation AP_a = a_bar - a_c (b, c alike)
- 7.2 pose repeatability:    RP_l = l_bar + 3 S_l,  l_j = |x_j - x_bar|,  l_bar = (1/n) sum l_j,
                              S_l = sqrt(sum (l_j - l_bar)^2 / (n - 1));  orientation RP_a = 3 S_a
- 7.2 multi-directional pose accuracy variation: vAP_P = max over approach directions h, k of |x_bar_h - x_bar_k|
- 7.3 distance accuracy:     AD_P = D_bar - D_c,  D_j = |x1_j - x2_j|,  D_c = |c1 - c2|
       distance repeatability: RD = 3 sqrt(sum (D_j - D_bar)^2 / (n - 1))
- 7.6 drift:                 dAP = |AP_(t=1) - AP_(t=T)|,  dRP = |RP_(t=1) - RP_(t=T)|

Uncertainty: each attained position is a tracker measurement with covariance Sigma_j (the instrument model,
calib.identify.noise); a figure f(x_1..x_n) then carries the instrument's standard uncertainty
u(f)^2 = sum_j g_j^T Sigma_j g_j with g_j = df/dx_j, the GUM's law of propagation (JCGM 100:2008, 5.1.2), from the
exact gradients below (tests compare them with finite differences), the expanded uncertainty U = 2 u (k = 2, about
95 %). This is the tracker's line of a figure's budget: calib.uncertainty_budget adds the calibration's station and
tool point, the reflector, the temperature and the robot's repeatability (for AP_P and AD_P), and propagates AP_P and
RP_l by Monte-Carlo; `iso9283 compare` states the budget's U (campaign.jobs.iso9283_budget).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from trackcal.calib.errors import CalibError
from trackcal.calib.iso9283_clauses import clause
from trackcal.calib.model.rigid import RigidError, kabsch, skew
from trackcal.calib.uncertainty_budget import Budget

CYCLES = 30  # ISO 9283:1998, 6.9: pose accuracy and repeatability are tested over 30 cycles
COVERAGE = 2.0  # expanded uncertainty U = k u with k = 2 (JCGM 100:2008, 6.2)


DISTANCE_POSES = (1, 3)  # AD and RD over P2-P4, a diagonal of the measuring plane (trackcal's choice of pair)


class IsoError(CalibError):
    """Attained positions an ISO 9283 figure cannot be computed from."""


@dataclass(frozen=True)
class Figure:
    """One ISO 9283 figure in mm (or deg), its expanded uncertainty from the instrument (k = 2) and its clause."""

    value: float
    u95: float
    clause: str

    def to_doc(self) -> dict:
        return {"value_mm": self.value, "u95_mm": self.u95, "clause": self.clause}

    def to_doc_deg(self) -> dict:
        """An orientation figure's document (degrees); a number that does not exist is null (strict JSON)."""

        def num(v):
            return float(v) if np.isfinite(v) else None

        return {"value_deg": num(self.value), "u95_deg": num(self.u95), "clause": self.clause}


def _points(x, name: str, min_rows: int = 1) -> np.ndarray:
    a = np.asarray(x, dtype=float)
    if a.ndim != 2 or a.shape[1] != 3 or a.shape[0] < min_rows or not np.isfinite(a).all():
        raise IsoError(f"{name}: expected at least {min_rows} finite positions (n x 3), got shape {a.shape}")
    return a


def _covs(cov, n: int) -> np.ndarray | None:
    if cov is None:
        return None
    c = np.asarray(cov, dtype=float)
    if c.shape == (3, 3):
        c = np.broadcast_to(c, (n, 3, 3))
    if c.shape != (n, 3, 3) or not np.isfinite(c).all():
        raise IsoError(f"covariances: expected (3, 3) or ({n}, 3, 3), got {c.shape}")
    return c


def _u95(grad: np.ndarray, cov: np.ndarray | None) -> float:
    """U = k sqrt(sum_j g_j^T Sigma_j g_j): the law of propagation for independent measurements."""
    if cov is None:
        return float("nan")
    return COVERAGE * float(np.sqrt(np.einsum("ni,nij,nj->", grad, cov, grad)))


def _norm_grad(d: np.ndarray) -> np.ndarray:
    """d|d|/dd, zero where |d| = 0 (the figure's gradient is not defined there; its one-sided slope is 1)."""
    r = np.linalg.norm(d, axis=-1, keepdims=True)
    return np.divide(d, r, out=np.zeros_like(d), where=r > 0)


def pose_accuracy(attained, commanded, cov=None) -> tuple[Figure, np.ndarray]:
    """AP_P (7.2) and the per-coordinate offsets AP_x, AP_y, AP_z = x_bar - c."""
    x = _points(attained, "attained positions")
    c = np.asarray(commanded, dtype=float).reshape(3)
    n = len(x)
    offset = x.mean(axis=0) - c
    grad = np.broadcast_to(_norm_grad(offset) / n, (n, 3))
    return Figure(float(np.linalg.norm(offset)), _u95(grad, _covs(cov, n)), clause("AP")), offset


def _repeatability_parts(x: np.ndarray):
    n = len(x)
    d = x - x.mean(axis=0)
    ell = np.linalg.norm(d, axis=1)
    lbar = ell.mean()
    s = float(np.sqrt(((ell - lbar) ** 2).sum() / (n - 1)))
    return d, ell, lbar, s


def pose_repeatability(attained, cov=None) -> tuple[Figure, float, float]:
    """RP_l = l_bar + 3 S_l (7.2); also l_bar and S_l."""
    x = _points(attained, "attained positions", min_rows=2)
    n = len(x)
    d, ell, lbar, s = _repeatability_parts(x)
    # dl_j/dx_i = u_j (delta_ij - 1/n) with u_j = d_j / l_j, so d l_bar/dx_i = (u_i - u_mean) / n
    u = _norm_grad(d)
    g_lbar = (u - u.mean(axis=0)) / n
    # d S_l / dx_i = 1/((n-1) S) sum_j (l_j - l_bar) dl_j/dx_i  (the l_bar term vanishes: sum_j (l_j - l_bar) = 0)
    #             = 1/((n-1) S) [ (l_i - l_bar) u_i - (1/n) sum_j (l_j - l_bar) u_j ]
    w = (ell - lbar)[:, None] * u
    g_s = (w - w.mean(axis=0)) / ((n - 1) * s) if s > 0 else np.zeros_like(x)
    grad = g_lbar + 3.0 * g_s
    return Figure(float(lbar + 3.0 * s), _u95(grad, _covs(cov, n)), clause("RP")), float(lbar), s


def orientation_accuracy(attained_deg, commanded_deg) -> np.ndarray:
    """AP_a, AP_b, AP_c = mean attained angle - commanded angle (7.2), in degrees; angles are unwrapped about
    the commanded one first (a cluster straddling +-180 deg averages to its centre, not to 0)."""
    a = _points(attained_deg, "attained orientations")
    c = np.asarray(commanded_deg, dtype=float).reshape(3)
    wrapped = (a - c + 180.0) % 360.0 - 180.0
    return wrapped.mean(axis=0)


def orientation_repeatability(attained_deg) -> np.ndarray:
    """RP_a, RP_b, RP_c = 3 S_a (7.2: the standard writes +-3 S_a), in degrees."""
    a = _points(attained_deg, "attained orientations", min_rows=2)
    ref = a[0]
    wrapped = (a - ref + 180.0) % 360.0 - 180.0
    return 3.0 * wrapped.std(axis=0, ddof=1)


def log_so3(r: np.ndarray) -> np.ndarray:
    """The rotation vector w (rad) of a rotation matrix, exp_so3(w) = r, for rotations below a half turn."""
    c = np.clip((np.trace(r) - 1.0) / 2.0, -1.0, 1.0)
    theta = float(np.arccos(c))
    v = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]]) / 2.0
    return v if theta < 1e-8 else v * theta / np.sin(theta)


def attained_orientations(tool_points, attained, commanded_rot, covs=None) -> tuple[np.ndarray, np.ndarray | None]:
    """Per cycle the attained orientation's deviation from the commanded one, from the tool's reference points.

    tool_points (k, 3): the points in the last joint frame (k >= 3, not collinear); attained (n, k, 3): their attained
    positions per cycle (base frame); commanded_rot (3, 3): the commanded orientation of the last joint frame. Each
    cycle's attained orientation R_j is the least-squares rigid fit of the tool points onto the attained positions
    (calib.model.rigid.kabsch), and its deviation w_j = log(R_j R_c^T) is a rotation vector about the base axes: for
    the small deviations of a robot, its components are the differences a_j - a_c, b_j - b_c, c_j - c_c of rotation
    angles about the base x, y and z axes, the orientation ISO 9283:1998, 7.2 compares. Returns w (n, 3) in rad and,
    with the positions' covariances (n, k, 3, 3), each w_j's covariance (n, 3, 3) by the fit linearised: a rotation
    omega moves point k by omega x r_k (r_k about the points' centroid), so omega = G sum_k A_k^T dx_k with
    A_k = -[r_k]x and G = (sum_k A_k^T A_k)^-1, and cov omega = G (sum_k A_k^T Sigma_k A_k) G."""
    src = np.asarray(tool_points, dtype=float)
    x = np.asarray(attained, dtype=float)
    if src.ndim != 2 or src.shape[0] < 3 or x.shape[1:] != src.shape or x.ndim != 3 or not np.isfinite(x).all():
        raise IsoError(
            f"orientation: expected n x {len(src)} x 3 attained positions of >= 3 tool points, got {x.shape}"
        )
    rc = np.asarray(commanded_rot, dtype=float)
    w, cov_w = np.zeros((len(x), 3)), np.zeros((len(x), 3, 3))
    try:
        for j, xj in enumerate(x):
            r, _ = kabsch(src, xj)
            w[j] = log_so3(r @ rc.T)
            if covs is not None:
                a = -np.array([skew(v) for v in xj - xj.mean(axis=0)])  # (k, 3, 3)
                g = np.linalg.inv(np.einsum("kji,kjl->il", a, a))
                cov_w[j] = g @ np.einsum("kji,kjl,klm->im", a, np.asarray(covs[j], float), a) @ g
    except RigidError as exc:
        raise IsoError(f"orientation: {exc}") from exc
    return w, (cov_w if covs is not None else None)


def orientation_figures(w: np.ndarray, cov_w: np.ndarray | None = None) -> dict[str, Figure]:
    """AP_a, AP_b, AP_c (7.2: mean attained angle less the commanded, the mean of w) and RP_a, RP_b, RP_c
    (7.2: 3 S_a) in degrees from the per-cycle deviations w (n, 3) rad, each with the instrument's expanded
    uncertainty from the deviations' covariances (n, 3, 3): u(AP_a)^2 = sum_j var(a_j) / n^2 and, with
    dS_a/da_j = (a_j - a_bar) / ((n - 1) S_a), u(RP_a)^2 = 9 sum_j (dS_a/da_j)^2 var(a_j)."""
    n = len(w)
    deg = np.degrees(w)
    ap = orientation_accuracy(deg, np.zeros(3))
    rp = orientation_repeatability(deg) if n >= 2 else np.full(3, np.nan)
    out = {}
    for k, axis in enumerate("abc"):
        u_ap = u_rp = float("nan")
        if cov_w is not None:
            var = np.degrees(np.degrees(cov_w[:, k, k]))  # rad^2 -> deg^2
            u_ap = COVERAGE * float(np.sqrt(var.sum())) / n
            s = rp[k] / 3.0
            if n >= 2 and s > 0:
                g = (deg[:, k] - deg[:, k].mean()) / ((n - 1) * s)
                u_rp = COVERAGE * 3.0 * float(np.sqrt((g**2 * var).sum()))
        out[f"AP_{axis}"] = Figure(float(ap[k]), u_ap, clause("AP"))
        out[f"RP_{axis}"] = Figure(float(rp[k]), u_rp, clause("RP"))
    return out


def multidirectional_variation(clusters: Sequence, covs: Sequence | None = None) -> Figure:
    """vAP_P (7.2): the largest distance between the barycentres of the clusters attained from different
    approach directions (three, parallel to the base axes, in the standard)."""
    xs = [_points(c, f"approach {k + 1}") for k, c in enumerate(clusters)]
    if len(xs) < 2:
        raise IsoError("multi-directional variation needs the attained positions of at least two approaches")
    bars = [x.mean(axis=0) for x in xs]
    best, pair = -1.0, (0, 1)
    for h in range(len(xs)):
        for k in range(h + 1, len(xs)):
            dist = float(np.linalg.norm(bars[h] - bars[k]))
            if dist > best:
                best, pair = dist, (h, k)
    u = float("nan")
    if covs is not None:
        h, k = pair
        g = _norm_grad(bars[h] - bars[k])
        var = sum(
            _u95(np.broadcast_to(sign * g / len(xs[i]), xs[i].shape), _covs(covs[i], len(xs[i]))) ** 2
            for i, sign in ((h, 1.0), (k, -1.0))
        )
        u = float(np.sqrt(var))
    return Figure(best, u, clause("vAP"))


def distance_accuracy(attained1, attained2, commanded1, commanded2, cov1=None, cov2=None) -> tuple[Figure, Figure]:
    """AD_P = D_bar - D_c and RD = 3 S_D (7.3), D_j = |x1_j - x2_j| over the n cycles."""
    x1 = _points(attained1, "attained positions of the first pose", min_rows=2)
    x2 = _points(attained2, "attained positions of the second pose", min_rows=2)
    if len(x1) != len(x2):
        raise IsoError(f"distance: the two poses have {len(x1)} and {len(x2)} cycles; one pair per cycle is needed")
    n = len(x1)
    diff = x1 - x2
    dj = np.linalg.norm(diff, axis=1)
    dc = float(np.linalg.norm(np.asarray(commanded1, float) - np.asarray(commanded2, float)))
    dbar = dj.mean()
    s = float(np.sqrt(((dj - dbar) ** 2).sum() / (n - 1)))
    u = _norm_grad(diff)
    c1, c2 = _covs(cov1, n), _covs(cov2, n)
    both = None if c1 is None or c2 is None else c1 + c2  # dD_j/dx1_j = u_j = -dD_j/dx2_j
    ad = Figure(float(dbar - dc), _u95(u / n, both), clause("AD"))
    g_s = ((dj - dbar)[:, None] * u) / ((n - 1) * s) if s > 0 else np.zeros_like(u)
    rd = Figure(3.0 * s, _u95(3.0 * g_s, both), clause("RD"))
    return ad, rd


def drift(first: Figure, last: Figure) -> Figure:
    """dAP or dRP (7.6): |figure at the first test - figure at the last|, their uncertainties added in quadrature."""
    return Figure(abs(first.value - last.value), float(np.hypot(first.u95, last.u95)), clause("drift"))


@dataclass
class PoseFigures:
    name: str
    n: int
    ap: Figure
    offset_mm: np.ndarray
    rp: Figure
    l_bar_mm: float
    s_l_mm: float
    orientation: dict[str, Figure] = field(default_factory=dict)  # AP_a..c, RP_a..c in deg, with >= 3 tool points
    budgets: dict[str, Budget] = field(default_factory=dict)  # "AP_P", "RP_l": calib.uncertainty_budget


@dataclass
class IsoFigures:
    """The figures of one session's test, the attained and commanded positions (base frame) and its conditions."""

    session: str
    compensated: bool
    poses: list[PoseFigures]
    ad: Figure | None
    rd: Figure | None
    attained_mm: list[np.ndarray]  # (cycles, 3) per pose
    commanded_mm: np.ndarray  # (5, 3)
    conditions: dict[str, str]
    notes: list[str] = field(default_factory=list)
    # multi-directional test (7.2): per pose name, vAP_P and the attained positions (base frame) from each side
    vap: dict[str, Figure] = field(default_factory=dict)
    vap_attained_mm: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    ad_budget: Budget | None = None  # AD_P's (calib.uncertainty_budget)
    other_budgets: dict[str, Budget] = field(default_factory=dict)  # "RD", "vAP_P P1", ...: the tracker's line alone
    velocity_pct: float = 0.0  # the test velocity (6.7), % of the rated; 0: none planned (the session's setting)
    departures: list[str] = field(default_factory=list)  # from the standard's test conditions, one line each

    @property
    def label(self) -> str:
        """The test's targets and, where planned, its velocity: "nominal", "compensated, 50 %"."""
        kind = "compensated" if self.compensated else "nominal"
        return f"{kind}, {self.velocity_pct:g} %" if self.velocity_pct else kind

    def to_doc(self) -> dict:
        def fig(f: Figure | None):
            return None if f is None else f.to_doc()

        return {
            "session": self.session,
            "compensated": self.compensated,
            "poses": [
                {
                    "pose": p.name,
                    "cycles": p.n,
                    "AP_P": fig(p.ap),
                    "AP_xyz_mm": p.offset_mm.tolist(),
                    "RP_l": fig(p.rp),
                    "l_bar_mm": p.l_bar_mm,
                    "S_l_mm": p.s_l_mm,
                    **{k: f.to_doc_deg() for k, f in p.orientation.items()},
                    "budget": {k: b.to_doc() for k, b in p.budgets.items()},
                }
                for p in self.poses
            ],
            "AD_P": fig(self.ad),
            "RD": fig(self.rd),
            "distance_poses": [f"P{i + 1}" for i in DISTANCE_POSES],
            "vAP_P": [
                {
                    "pose": name,
                    **f.to_doc(),
                    "cycles": {side: len(x) for side, x in self.vap_attained_mm.get(name, {}).items()},
                }
                for name, f in self.vap.items()
            ],
            "AD_P_budget": None if self.ad_budget is None else self.ad_budget.to_doc(),
            "other_budgets": {k: b.to_doc() for k, b in self.other_budgets.items()},
            "conditions": self.conditions,
            "notes": self.notes,
            "departures": self.departures,
        } | ({"velocity_pct": self.velocity_pct} if self.velocity_pct else {})
