"""Joint identification of robot parameters, tracker stations and reference points (paper eq. 13).

Unknowns: the deviations of the chosen robot parameters, one 6-dof transform per tracker station
(station <- robot base, x_s = R_s p + t_s) and the position of every reference point in the last joint
frame. Stations start from a closed-form Kabsch fit on nominal predictions; then Levenberg-Marquardt on
the analytic Jacobian of `calib.model.kinematics` solves the whole non-linear problem at once (the paper's
two-step alternation, eqs. 17-22, is kept in bench/ as a baseline).

Weighting: i.i.d. by default, or a `TrackerNoise` model (eqs. 23-24). Uncertainty: eq. (27) with the
variance factor estimated from the residuals, Student-t 95 % intervals.

`fixed` holds groups of unknowns at their given values: ("robot", "points") re-estimates only the stations,
the shop-floor check of a calibrated model after the tracker was set up again (validation on a series
measured from another station).
"""

from __future__ import annotations

import copy
from concurrent.futures import Executor
from dataclasses import dataclass, field
from functools import cached_property
from typing import NamedTuple

import numpy as np

from trackcal.calib.errors import CalibError
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.identify.student import t_quantile
from trackcal.calib.io.table import MeasurementTable, label_codes
from trackcal.calib.model.chain import Chain
from trackcal.calib.model.extension import Extension, JointFeatures
from trackcal.calib.model.kinematics import Kinematics, row_runs
from trackcal.calib.model.params import Param
from trackcal.calib.model.rigid import RigidError, exp_so3, kabsch, skew

CHUNK_ROWS = 4096  # rows per chunk of the normal equations: ~1 MB of Jacobian, cache-sized
CHUNK_BYTES = 2**23  # and at most 8 MB of a chunk's Jacobian blocks (rows x 3 x columns float64): a problem of many
# columns (the joint error map's ~700) takes fewer rows at once (issue 41: 4,096 of its rows were 78 MB)
# The covariance's R factor comes from the Cholesky factor of the normal equations at the solution when the
# column-scaled Jacobian's condition number is at most this (R then carries rounding of about eps * cond^2 = 2e-12
# relative at most, where the R of a QR of the Jacobian carries eps * cond); above it, from that QR (issue 41)
CHOLESKY_COND = 100.0
# joint-feature columns (each a joint's lever times a feature: the joint error map's harmonics) from which the normal
# equations form their block from the rows' levers (`JointFeatures.gram`), not from their Jacobian columns
LEVER_GRAM_MIN = 64


class IdentificationError(CalibError):
    """A set-up that cannot be identified; the message says what is missing."""


@dataclass
class Station:
    rotation: np.ndarray  # R_s: station <- robot base
    translation: np.ndarray  # t_s, mm

    def apply(self, p: np.ndarray) -> np.ndarray:
        return p @ self.rotation.T + self.translation


@dataclass
class Identification:
    chain: Chain
    params: list[Param]
    dev: np.ndarray  # deviations from nominal (mm, rad), ordered as params
    stations: dict[str, Station]
    points: dict[str, np.ndarray]
    cov: np.ndarray  # covariance of [dev, ext, station perturbations (v, w) x S, points x P]
    station_ids: list[str]
    point_ids: list[str]
    residuals: np.ndarray  # (N, 3) measured - predicted, mm, station frames
    variance_factor: float  # s^2 (a-posteriori), 1 if the noise model holds
    dof: int
    iterations: int
    noise: TrackerNoise | None
    extension: Extension | None = None
    ext: np.ndarray = field(default_factory=lambda: np.zeros(0))  # extension parameters (internal units)
    converged: bool = True  # the solver's stopping test was met (scipy OptimizeResult's `success`)
    message: str = ""  # why the solver stopped
    # R of the whitened Jacobian at the solution, free columns (R^T R = J^T J; None: not kept): what judges the
    # parameters' determination afterwards without forming the Jacobian again (calib.identify.determined)
    r_factor: np.ndarray | None = None

    @property
    def _c_st(self) -> int:
        return len(self.params) + len(self.ext)

    @property
    def t95(self) -> float:
        return t_quantile(self.dof, 0.975)  # Student t quantile (calib.identify.student: scipy's costs start-up)

    def std(self) -> np.ndarray:
        return np.sqrt(np.diag(self.cov))

    def param_ci95(self) -> np.ndarray:
        return self.t95 * self.std()[: len(self.params)]

    def ext_ci95(self) -> np.ndarray:
        return self.t95 * self.std()[len(self.params) : self._c_st]

    def station_ci95(self, sid: str) -> np.ndarray:
        k = self._c_st + 6 * self.station_ids.index(sid)
        return self.t95 * self.std()[k : k + 6]

    def point_ci95(self, pid: str) -> np.ndarray:
        k = self._c_st + 6 * len(self.station_ids) + 3 * self.point_ids.index(pid)
        return self.t95 * self.std()[k : k + 3]

    @property
    def sigma_mm(self) -> float:
        """A-posteriori standard deviation of one coordinate (i.i.d. weighting) or the variance-factor root."""
        return float(np.sqrt(self.variance_factor))

    def param_cov(self) -> np.ndarray:
        k = len(self.params)
        return self.cov[:k, :k]


def _init_stations(kin, poses, tool_rows, xyz, st_idx, station_ids, source) -> list[Station]:
    """Kabsch fits of every station on the nominal predictions; `poses` = (q of the distinct poses, pose of
    each row)."""
    p_nom = kin.points(poses[0], tool_rows, rows=poses[1])
    out = []
    for s, sid in enumerate(station_ids):
        rows = np.flatnonzero(st_idx == s)
        if len(rows) < 3:
            raise IdentificationError(
                f"{source}: station {sid!r} has {len(rows)} measurement(s); at least 3 non-collinear "
                "points are needed to place a station"
            )
        try:
            r, t = kabsch(p_nom[rows], xyz[rows])
        except RigidError as exc:
            raise IdentificationError(f"{source}: station {sid!r}: {exc}") from None
        out.append(Station(r, t))
    return out


def _selector(rows: np.ndarray) -> np.ndarray | slice:
    """What selects `rows` from per-row arrays: the slice they make when they follow each other (a view, where an
    index copies: the joint error map's features are tens of MB; issue 26), else the rows themselves."""
    if len(rows) and bool(np.all(np.diff(rows) == 1)):
        return slice(int(rows[0]), int(rows[-1]) + 1)
    return rows


def _whitened(w: np.ndarray, r: np.ndarray) -> np.ndarray:
    """w @ r row by row: the whitening w (n, 3, 3) of r (n, 3, ...)."""
    return np.einsum("nij,nj...->ni...", w, r)


def _rotated(m: np.ndarray, cols: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """m @ cols row by row, rows first (n, 3, c), from columns given coordinate first (3, c, n); m (3, 3) the same
    for every row (then one product for all the rows, where a product per row cost ~80 ns each) or (n, 3, 3)."""
    if m.ndim == 2:
        prod = (m @ cols.reshape(3, -1)).reshape(cols.shape).transpose(2, 0, 1)
        if out is None:
            return np.ascontiguousarray(prod)
        out[...] = prod
        return out
    return np.matmul(m, np.ascontiguousarray(cols.transpose(2, 0, 1)), out=out)  # BLAS takes contiguous rows


def unique_rows(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(first row of each distinct row, index of each row's among them) of a 2-D array, in the order of
    np.unique(a, axis=0, return_index=True, return_inverse=True), the same arrays: one lexsort of the columns
    (stable, like np.unique's mergesort of the rows as records, which took 2-3x as long: issue 41) of the runs of
    equal rows that follow each other (a pose's rows: a sixth of a campaign's rows to sort)."""
    runs, of_row = row_runs(a)
    b = a[runs]
    order = np.lexsort(b.T[::-1])  # by the first column, then the next, ...; a run before a later equal one
    starts, rank = row_runs(b[order])
    inverse = np.empty(len(b), dtype=np.intp)
    inverse[order] = rank
    return runs[order[starts]], inverse[of_row]


def _distinct_poses(
    q: np.ndarray, feats: JointFeatures | None, angles: tuple[np.ndarray, np.ndarray] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """(first row of each distinct pose, pose of every row): rows with equal joint angles and, with joint-offset
    features (N, n, e), equal features, in np.unique's order of the key [q, features]. `angles`: unique_rows(q) if
    already computed (`Rows.angle_poses`).

    The features are usually a function of the angles (a joint error map: hundreds of columns): then the groups of
    the angles alone are those of the whole key and in the same order (the key sorts by the angles first), and the
    sort of a key thousands of columns wide is skipped (issue 26: 5 s of a diagnosis of the UR10's Series B). When
    they are not (backlash follows the direction of motion), the whole key is sorted as before."""
    first, of_row = unique_rows(q) if angles is None else angles
    if feats is not None and len(first) < len(q):  # every row its own pose by its angles: so by the whole key
        flat = feats.values  # equal rows of the block form are equal rows of the dense features
        # compared a piece of rows at a time (issue 41: the whole N x e copy was the peak of a 20k-row diagnosis)
        pieces = range(0, len(q), CHUNK_ROWS)
        if not all(np.array_equal(flat[a : a + CHUNK_ROWS], flat[first[of_row[a : a + CHUNK_ROWS]]]) for a in pieces):
            key = np.hstack([q, feats.dense().reshape(len(q), -1)])  # the dense key's order, as before
            first, of_row = unique_rows(key)
    return first, of_row


@dataclass
class State:
    dev: np.ndarray  # robot parameter deviations (mm, rad)
    stations: list[Station]
    points: np.ndarray  # (P, 3) in the last joint frame
    ext: np.ndarray = field(default_factory=lambda: np.zeros(0))  # model extension parameters


class _Chunk(NamedTuple):
    """Rows of one chunk of the normal equations, ordered by (station, point), with what every pass reuses."""

    rows: np.ndarray  # table rows
    order: np.ndarray | None  # position of each among the rows the chunk was made from (None: the same order)
    poses: np.ndarray  # the distinct poses of those rows (in row order when no two rows share one)
    of_row: np.ndarray | None  # index into poses of each row (None: a pose per row, in order)
    pairs: list[tuple[slice, int, int]]  # rows of one (station, point), and their indices
    take: np.ndarray | slice  # selects the rows from per-row arrays: `rows`, or the slice they make
    stations: list[tuple[slice, int]]  # rows of one station, and its index
    xyz: np.ndarray  # (n, 3) their measurements
    w: np.ndarray | None  # (n, 3, 3) their whitening


class Rows:
    """A table's rows as a Problem lays them out, whatever its unknowns: the station and point ids and each row's,
    the joint angles (rad), the distinct poses, the whitening, the chunks of the normal equations and the stations'
    start (Kabsch fits on the nominal robot). Problems of one table, tool points, noise and joint-offset features
    share them (`Identification.rows`: the nominal robot's "before" fit and the fit, issue 41: the second set-up
    cost 0.1 s at 100k rows). The table is checked at once; the rest is computed when first asked for (in the order a
    Problem asks, so its errors come in the same order)."""

    def __init__(self, chain: Chain, table: MeasurementTable, tool_points, noise, feats: JointFeatures | None):
        source = table.source
        if table.xyz is None:
            raise IdentificationError(f"{source}: the table has no x_mm, y_mm, z_mm columns to identify from")
        if table.n_joints != chain.dof:
            raise IdentificationError(
                f"{source}: the table has {table.n_joints} joint columns, robot {chain.name} has {chain.dof}"
            )
        self.pt_idx, self.point_ids = label_codes(table.point)  # ids in order of first appearance
        for i, pid in enumerate(self.point_ids):  # so the first unknown is the one of the first row
            if pid not in tool_points:
                raise IdentificationError(
                    f"{source}: row {int(np.argmax(self.pt_idx == i)) + 2}: column point: unknown point id {pid!r} "
                    f"(the tool defines {', '.join(sorted(tool_points))})"
                )
        self.chain, self.table, self.tool_points, self.noise, self.feats = chain, table, tool_points, noise, feats
        self.st_idx, self.station_ids = label_codes(table.station)
        # each station's rows: a slice when they follow each other (a view, not a copy)
        self.station_rows = [_selector(np.flatnonzero(self.st_idx == i)) for i in range(len(self.station_ids))]
        self.q = np.radians(table.q_deg)
        self.xyz = table.xyz
        self._chunks: dict[int, list[_Chunk]] = {}

    def of(self, chain: Chain, table: MeasurementTable, tool_points, noise) -> bool:
        """Were these rows laid out for this table (the same objects, an equal noise model), whatever the features?"""
        mine, theirs = (self.chain, self.table, self.tool_points), (chain, table, tool_points)
        return all(a is b for a, b in zip(mine, theirs, strict=True)) and self.noise == noise

    def fits(self, chain: Chain, table: MeasurementTable, tool_points, noise, feats: JointFeatures | None) -> bool:
        """Were these rows laid out for this set-up (the same objects, an equal noise model)?"""
        return self.of(chain, table, tool_points, noise) and self.feats is feats

    def with_features(self, feats: JointFeatures | None) -> Rows:
        """These rows for other joint-offset features: what the table alone gives (ids, indices, angles, measurements,
        whitening, the angles' distinct poses) shared, the distinct poses, the stations' start and the chunks made
        again (a diagnosis's candidates, each with its own features, made it all again: 1 ms a fit of Series B's
        1495 rows, issue 41)."""
        out = copy.copy(self)
        out.feats, out._chunks = feats, {}
        for name in ("poses", "stations"):  # cached_property values of these features (kept in the instance dict)
            out.__dict__.pop(name, None)
        return out

    @cached_property
    def angle_poses(self) -> tuple[np.ndarray, np.ndarray]:
        """unique_rows of the joint angles: the distinct poses of the angles alone (whatever the features)."""
        return unique_rows(self.q)

    @cached_property
    def poses(self) -> tuple[np.ndarray, np.ndarray]:
        """(first row of each distinct pose, pose of every row): rows share poses (several points, several
        stations), so the chain is walked once per distinct pose (and joint-offset features, which make the
        extended joint angles of a row)."""
        return _distinct_poses(self.q, self.feats, self.angle_poses)

    @cached_property
    def w(self) -> np.ndarray | None:
        return None if self.noise is None else self.noise.whitening(self.xyz)

    def chunks(self, size: int = CHUNK_ROWS) -> list[_Chunk]:
        """Chunks of at most `size` rows, pose by pose, for the normal equations: memory stays bounded whatever the
        table size (made once per size)."""
        if size not in self._chunks:
            order = np.argsort(self.poses[1], kind="stable")
            parts = np.array_split(order, max(1, -(-len(self.q) // size)))
            self._chunks[size] = [self.chunk(rows) for rows in parts]
        return self._chunks[size]

    def chunk(self, rows: np.ndarray) -> _Chunk:
        n_pt = len(self.point_ids)
        group = self.st_idx[rows] * n_pt + self.pt_idx[rows]
        order = np.argsort(group, kind="stable")
        rows, group = rows[order], group[order]
        row_pose = self.poses[1]
        poses, of_row = np.unique(row_pose[rows], return_inverse=True)
        of_row = of_row.ravel()
        if len(poses) == len(rows):  # no two rows share a pose: the chain walked for the rows in their order
            poses, of_row = row_pose[rows], np.arange(len(rows))
        starts = np.flatnonzero(np.r_[True, group[1:] != group[:-1]])
        ends = np.r_[starts[1:], len(rows)]
        pairs, stations = [], []
        for a, b in zip(starts, ends, strict=True):
            s, p = divmod(int(group[a]), n_pt)
            pairs.append((slice(a, b), s, p))
            if stations and stations[-1][1] == s:
                stations[-1] = (slice(stations[-1][0].start, b), s)
            else:
                stations.append((slice(a, b), s))
        take = _selector(rows)
        return _Chunk(
            rows,
            None if np.array_equal(order, np.arange(len(order))) else order,
            poses,
            None if np.array_equal(of_row, np.arange(len(of_row))) else of_row,
            pairs,
            take,
            stations,
            self.xyz[take],
            None if self.w is None else self.w[take],
        )

    @cached_property
    def points(self) -> np.ndarray:
        """(P, 3) the tool points, in the order of point_ids."""
        return np.array([np.asarray(self.tool_points[p], dtype=float) for p in self.point_ids])

    @cached_property
    def stations(self) -> list[Station]:
        """The stations' start: Kabsch fits on the nominal robot's predictions (whatever the unknowns)."""
        first, row_pose = self.poses
        return _init_stations(
            Kinematics(self.chain, []),
            (self.q[first], row_pose),
            self.points[self.pt_idx],
            self.xyz,
            self.st_idx,
            self.station_ids,
            self.table.source,
        )


class Problem:
    """The least-squares problem of eq. (13) for one table: residuals, Jacobian, retraction.

    Unknowns, in order: robot deviations (k), model-extension parameters (e), per station a translation
    and a rotation perturbation (v, w) in the station frame (x' = Exp(w) x + v), per reference point its
    3 coordinates. `fixed` removes groups from the unknowns: "robot" (deviations and extension parameters,
    held at dev0 / ext0) and "points" (held at tool_points); `n_cols` counts the free unknowns, and the
    Jacobian and steps have only their columns. `rows`: the table's layout from a Problem of the same table,
    tool points and noise (Rows.of; any other is not used), its distinct poses too when its joint-offset features are
    the same objects (else `Rows.with_features`).
    """

    def __init__(
        self,
        chain,
        table,
        tool_points,
        params,
        noise=None,
        dev0=None,
        extension: Extension | None = None,
        ext0=None,
        fixed: tuple[str, ...] = (),
        rows: Rows | None = None,
    ):
        feats = None if extension is None else extension.joint_features
        if rows is None or not rows.of(chain, table, tool_points, noise):
            rows = Rows(chain, table, tool_points, noise, feats)
        elif rows.feats is not feats:
            rows = rows.with_features(feats)
        self.rows, source = rows, table.source
        self.chain, self.params, self.noise, self.source = chain, list(params), noise, source
        self.station_ids, self.point_ids = rows.station_ids, rows.point_ids
        self.st_idx, self.pt_idx, self.station_rows = rows.st_idx, rows.pt_idx, rows.station_rows
        self.q, self.xyz = rows.q, rows.xyz
        self.ext = extension
        self.n_rows, self.k = len(table), len(self.params)
        self.e = 0 if extension is None else extension.size
        growth = None if extension is None else extension.growth
        self._grows = None if growth is None else np.flatnonzero(np.any(growth != 0, axis=0))  # parameters that grow
        self.n_st, self.n_pt = len(self.station_ids), len(self.point_ids)
        self.c_st = self.k + self.e  # first station column
        self.n_all = self.c_st + 6 * self.n_st + 3 * self.n_pt
        unknown = set(fixed) - {"robot", "points"}
        if unknown:
            raise IdentificationError(f"fixed: {', '.join(sorted(unknown))}; choose from robot, points")
        self.free = np.ones(self.n_all, dtype=bool)
        if "robot" in fixed:
            self.free[: self.c_st] = False
        if "points" in fixed:
            self.free[self.c_st + 6 * self.n_st :] = False
        self.n_cols = int(self.free.sum())
        if 3 * self.n_rows <= self.n_cols:
            raise IdentificationError(
                f"{source}: {self.n_rows} measurements give {3 * self.n_rows} equations for {self.n_cols} "
                "unknowns; measure more poses"
            )
        self.kin = Kinematics(chain, self.params)
        self.pose_first, self.row_pose = rows.poses
        self.w = rows.w
        # the columns of the rows of one (station, point) among all unknowns, and the block of the normal matrix
        # they make (np.ix_)
        c_pt = self.c_st + 6 * self.n_st
        self.columns = {}
        for s in range(self.n_st):
            for p in range(self.n_pt):
                cols = np.r_[np.arange(self.c_st), self.c_st + 6 * s + np.arange(6), c_pt + 3 * p + np.arange(3)]
                self.columns[s, p] = cols, np.ix_(cols, cols)
        self.chunks = rows.chunks(max(1, min(CHUNK_ROWS, CHUNK_BYTES // (24 * (self.c_st + 9)))))
        self._q_at: tuple[bytes, np.ndarray] | None = None  # (extension values, joint angles with their offsets)
        self._dev0 = np.zeros(self.k) if dev0 is None else np.array(dev0, dtype=float)
        self._ext0 = np.zeros(self.e) if ext0 is None else np.array(ext0, dtype=float)

    @cached_property
    def initial(self) -> State:
        """The solver's start: dev0, ext0, the tool points and the stations' Kabsch fits on the nominal robot (their
        errors: a station of fewer than three rows, collinear points). Formed when first asked for: a caller that
        starts elsewhere assigns its own (a diagnosis's whole-table fits, warm-started: their Kabsch fits were 1 % of
        a diagnosis of the UR10's Series B, issue 41)."""
        return State(self._dev0, list(self.rows.stations), self.rows.points.copy(), self._ext0)

    def set_chunks(self, chunks: list[np.ndarray]) -> None:
        """Split the rows into these chunks for the normal equations (any partition of the rows)."""
        self.chunks = [self.rows.chunk(rows) for rows in chunks]

    @cached_property
    def _every_row(self) -> _Chunk:
        return self.rows.chunk(np.arange(self.n_rows))

    def _whiten(self, r: np.ndarray) -> np.ndarray:
        return r if self.w is None else _whitened(self.w, r)

    def _q(self, s: State) -> np.ndarray:
        """The rows' joint angles with the extension's offsets at s (rad), kept for the last extension values asked:
        a state's Jacobian rows are formed a chunk or a piece of rows at a time, and each formed every row's offsets
        (issue 41: N^2 / piece work in the joint map's folds, the same values each time)."""
        if self.ext is None or self.ext.joint_features is None:
            return self.q
        key = s.ext.tobytes()
        if self._q_at is None or self._q_at[0] != key:
            self._q_at = (key, self.q + self.ext.joint_offsets(s.ext))
        return self._q_at[1]

    def _growth(self, s: State) -> np.ndarray | None:
        return None if self.ext is None else self.ext.growth_of(s.ext)

    def predicted(self, s: State) -> np.ndarray:
        shared = len(self.pose_first) < self.n_rows  # else the chain is walked for the rows in order (no gathers)
        pb = model_points(
            self.kin,
            self.q,
            s.points[self.pt_idx],
            s.dev,
            self.ext,
            s.ext,
            (self.pose_first, self.row_pose) if shared else None,
        )
        for st, rows in zip(s.stations, self.station_rows, strict=True):  # station by station: no per-row rotations
            pb[rows] = st.apply(pb[rows])
        scale = None if self.ext is None else self.ext.range_of(s.ext)
        return pb if scale is None else (1.0 + scale)[:, None] * pb

    def residual(self, s: State) -> np.ndarray:
        """Whitened residuals (measured - predicted), flattened (3N,)."""
        return self._whiten(self.xyz - self.predicted(s)).ravel()

    def _blocks(
        self, s: State, ch: _Chunk, skip: slice | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Whitened residuals (n, 3) of the chunk's rows, the non-zero blocks of their Jacobian (n, 3, m): the columns
        of the robot and extension, of the row's station (v, w) and of its point, in that order; and the rows'
        whitened levers (n, 3, joints), the derivatives by the joint angles the joint features' columns multiply
        (None without joint features). The joint features' columns `skip` (of the extension's) are left zero: their
        sums come from the levers (`_lever_parts`)."""
        rows, take, k, c = ch.rows, ch.take, self.k, self.c_st
        jac = self.kin.jacobian(
            self._q(s)[self.pose_first[ch.poses]], s.points[self.pt_idx[take]], s.dev, rows=ch.of_row
        )
        p, d_params, d_point = jac.p, jac.d_params_t, jac.d_point_t  # derivatives coordinate first (3, ., n)
        # the station frame, then the whitening: one matrix m per row for both (a chunk of one station: unwhitened,
        # the station's rotation for every row; whitened, w times it in one (3n, 3) by (3, 3) product, where a
        # product per row cost ~100 ns each)
        if len(ch.stations) == 1:
            st = s.stations[ch.stations[0][1]]
            rs, ts = st.rotation, st.translation
        else:
            rs, ts = np.empty((len(rows), 3, 3)), np.empty((len(rows), 3))
            for sl, i in ch.stations:
                rs[sl], ts[sl] = s.stations[i].rotation, s.stations[i].translation
        w = ch.w
        m = rs if w is None else ((w.reshape(-1, 3) @ rs).reshape(w.shape) if rs.ndim == 2 else w @ rs)
        jc = np.empty((len(rows), 3, c + 9))
        g = self._growth(s)
        joint = self.ext is not None and self.ext.joint_features is not None
        m_dq = None
        if g is not None:  # p = pivot + (1 + g) (p_rigid - pivot), g = growth @ theta: exact derivatives
            grow = 1.0 + g[take]
            rel = p - self.ext.pivot
            # the columns of the parameters that grow the arm only (issue 41: every column of the extension was formed,
            # with the joint error map 650 zero ones: 0.12 s of a diagnosis of the UR10's Series B, line profile)
            grown = (m @ rel[:, :, None]) * self.ext.growth[take][:, self._grows][:, None, :]
            p = self.ext.pivot + grow[:, None] * rel
            d_params, d_point = grow * d_params, grow * d_point
        if joint:
            m_dq = _rotated(m, jac.d_q_t if g is None else grow * jac.d_q_t)
            feats = self.ext.joint_features
            if skip is None:
                feats.take(take).lever_columns(m_dq, jc[:, :, k:c])
            else:
                jc[:, :, k + skip.start : k + skip.stop] = 0.0
                for part in (slice(0, skip.start), slice(skip.stop, self.e)):
                    feats.columns(part).take(take).lever_columns(m_dq, jc[:, :, k + part.start : k + part.stop])
        else:
            jc[:, :, k:c] = 0.0
        if g is not None:
            jc[:, :, k + self._grows] += grown
        if self.ext is not None and self.ext.displacement is not None:  # p + D theta (base frame): D's columns
            dp = self.ext.displacement[take]
            p = p + np.einsum("rke,e->rk", dp, s.ext)
            jc[:, :, k:c] += m @ dp
        xs = (p @ rs.T if rs.ndim == 2 else (rs @ p[:, :, None])[:, :, 0]) + ts
        _rotated(m, d_params, out=jc[:, :, :k])
        _rotated(m, d_point, out=jc[:, :, c + 6 :])
        if w is None:
            jc[:, :, c : c + 3] = np.eye(3)
            skew(-xs, out=jc[:, :, c + 3 : c + 6])  # -[x]x: the derivative by the rotation perturbation w
        else:
            jc[:, :, c : c + 3] = w
            np.matmul(w, skew(-xs), out=jc[:, :, c + 3 : c + 6])
        if self.ext is not None and self.ext.range_scale is not None:  # (1 + S theta) x: every column scaled, S's
            sc = self.ext.range_scale[take]
            jc *= (1.0 + sc @ s.ext)[:, None, None]
            jc[:, :, k:c] += (xs if w is None else (w @ xs[:, :, None])[:, :, 0])[:, :, None] * sc[:, None, :]
            xs = (1.0 + sc @ s.ext)[:, None] * xs
        r = ch.xyz - xs
        if w is not None:
            r = _whitened(w, r)
        return r, jc, m_dq

    def _dense(self, ch: _Chunk, jc: np.ndarray) -> np.ndarray:
        """The chunk's Jacobian rows (3n, n_cols) in its own row order, from their non-zero blocks."""
        if len(ch.pairs) == 1 and jc.shape[2] == self.n_all:  # one station, one point: the blocks are every column
            jm = jc
            return (jm if self.n_cols == self.n_all else jm[:, :, self.free]).reshape(-1, self.n_cols)
        jm = np.zeros((len(ch.rows), 3, self.n_all))
        for sl, s, p in ch.pairs:
            jm[sl][:, :, self.columns[s, p][0]] = jc[sl]
        return (jm if self.n_cols == self.n_all else jm[:, :, self.free]).reshape(-1, self.n_cols)

    def residual_and_jacobian(self, s: State, rows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Whitened residuals and the Jacobian of the *prediction* (so a GN step is J d = r), of every row or
        of the given `rows` (their residuals and Jacobian rows, in that order)."""
        ch = self._every_row if rows is None else self.rows.chunk(np.asarray(rows))
        rb, jc, _ = self._blocks(s, ch)
        if ch.order is None:
            return rb.ravel(), self._dense(ch, jc)
        r, jm = np.empty_like(rb), np.empty((len(ch.rows), 3, self.n_cols))
        r[ch.order], jm[ch.order] = rb, self._dense(ch, jc).reshape(-1, 3, self.n_cols)
        return r.ravel(), jm.reshape(-1, self.n_cols)

    def normal_equations(self, s: State, executor: Executor | None = None) -> tuple[np.ndarray, np.ndarray, float]:
        """(J^T J, J^T r, r.r) of the whitened problem, accumulated over row chunks from the Jacobian's
        non-zero blocks: the rows of one (station, point) pair touch only the robot's, that station's and that
        point's columns (the whole Jacobian is never held). A problem of many joint-feature columns (`_lever_gram`:
        the joint error map's ~650) forms their block from the rows' levers, its chunks in `executor` when given
        (threads: their products release the GIL), summed in chunk order. Otherwise one whose robot and extension
        columns outnumber the stations' and points' eight times sums each chunk's rows at once: one product, where a
        product and a scatter of a ~700 x 700 block per pair cost more than the few zeros skipped."""
        if self._lever_gram is not None:
            sums = (0.0, 0.0, 0.0)
            for part in (map if executor is None else executor.map)(
                lambda ch: self._lever_parts(s, ch)[:3], self.chunks
            ):
                sums = tuple(a + b for a, b in zip(sums, part, strict=True))
            return self._assembled(*sums)
        if self.c_st > 8 * (6 * self.n_st + 3 * self.n_pt):
            info, grad, cost = np.zeros((self.n_cols, self.n_cols)), np.zeros(self.n_cols), 0.0
            for ch in self.chunks:
                r, jc, _ = self._blocks(s, ch)
                jd = self._dense(ch, jc)
                info += jd.T @ jd
                grad += jd.T @ r.ravel()
                cost += float(np.vdot(r, r))
            return info, grad, cost
        info, grad, cost = np.zeros((self.n_all, self.n_all)), np.zeros(self.n_all), 0.0
        for ch in self.chunks:
            r, jc, _ = self._blocks(s, ch)
            for sl, st, pt in ch.pairs:
                cols, block = self.columns[st, pt]
                jg, rg = jc[sl].reshape(-1, jc.shape[2]), r[sl].ravel()
                info[block] += jg.T @ jg
                grad[cols] += jg.T @ rg
            cost += float(np.vdot(r, r))
        return info[np.ix_(self.free, self.free)], grad[self.free], cost

    def normal_rows(self, s: State, rows: np.ndarray, keep: np.ndarray) -> tuple[np.ndarray, ...]:
        """(J^T J, J^T r, r, J[:, keep]) of the given rows: their normal equations, with their whitened residual (3 n,)
        and their Jacobian's columns `keep` (none of the lever-gram columns: not formed), rows in the order given (a
        fold's part of the normal equations)."""
        if self._lever_gram is None:
            r, jd = self.residual_and_jacobian(s, rows)
            return jd.T @ jd, jd.T @ r, r, jd[:, keep]
        cols = self._lever_gram[0]
        if np.any((keep >= cols.start) & (keep < cols.stop)):
            raise IdentificationError("normal_rows: the lever-gram columns' Jacobian is not formed")
        ch = self.rows.chunk(np.asarray(rows))
        *sums, rb, jd = self._lever_parts(s, ch)
        gram, rhs, _ = self._assembled(*sums)
        if ch.order is None:
            return gram, rhs, rb.ravel(), jd[:, keep]
        r, jk = np.empty_like(rb), np.empty((len(ch.rows), 3, len(keep)))
        r[ch.order], jk[ch.order] = rb, jd[:, keep].reshape(len(ch.rows), 3, -1)
        return gram, rhs, r.ravel(), jk.reshape(-1, len(keep))

    @cached_property
    def _lever_gram(self) -> tuple[slice, JointFeatures, np.ndarray] | None:
        """(the longest run of one cause's extension columns that are each a joint's lever times a feature alone, as
        columns of the free unknowns; their features; the other columns) when it holds at least LEVER_GRAM_MIN (the
        joint error map's harmonics), else None. Its block of the normal equations is then formed from each row's lever
        (`JointFeatures.gram`: N e^2 multiply-adds where its Jacobian columns take 3 N e^2, issue 41: the map's Gram
        matrices were a fifth of a diagnosis of the UR10's Series B) and its Jacobian columns are not formed. Not for an
        extension that scales the range (every column then carries it) nor one whose robot unknowns are fixed."""
        ext = self.ext
        if ext is None or ext.joint_features is None or ext.range_scale is not None or not self.free[: self.c_st].all():
            return None
        alone = np.ones(self.e, dtype=bool)  # neither growing the arm nor moving the reflector
        if self._grows is not None:
            alone[self._grows] = False
        if ext.displacement is not None:
            alone &= ~np.any(ext.displacement != 0, axis=(0, 1))
        run, start = slice(0, 0), 0
        for _, names in ext.parts():  # runs within one cause's parameters (a base's few are other columns)
            edges = start + np.flatnonzero(np.diff(np.r_[False, alone[start : start + len(names)], False].astype(int)))
            for a, b in zip(edges[::2], edges[1::2], strict=True):
                run = slice(int(a), int(b)) if b - a > run.stop - run.start else run
            start += len(names)
        if run.stop - run.start < LEVER_GRAM_MIN:
            return None
        cols = slice(self.k + run.start, self.k + run.stop)
        return cols, ext.joint_features.columns(run), np.r_[0 : cols.start, cols.stop : self.n_cols]

    def _lever_parts(self, s: State, ch: _Chunk) -> tuple[np.ndarray, ...]:
        """A chunk's sums for `_assembled`, M = [J_o r]^T [J_o r], X = [J_o r]^T C and C^T C (J_o the Jacobian's
        other columns, C the lever-gram columns, r the residual; C^T C from the levers a chunk at a time: the whole
        table's at once took 1.5x as long), with the rows' whitened residuals (n, 3) and Jacobian rows (3 n, n_cols)."""
        cols, feats, other = self._lever_gram
        r, jc, lever = self._blocks(s, ch, skip=slice(cols.start - self.k, cols.stop - self.k))
        jd = self._dense(ch, jc)
        jor = np.concatenate([jd[:, other], r.reshape(-1, 1)], axis=1)
        feats = feats.take(ch.take)
        return jor.T @ jor, feats.cross(lever, jor.reshape(len(ch.rows), 3, -1)), feats.gram(lever), r, jd

    def _assembled(self, m: np.ndarray, x: np.ndarray, gcc: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """(J^T J, J^T r, r.r) from `_lever_parts`' sums."""
        cols, _, other = self._lever_gram
        gram, rhs = np.empty((self.n_cols, self.n_cols)), np.empty(self.n_cols)
        gram[np.ix_(other, other)] = m[:-1, :-1]
        gram[other, cols], gram[cols, other], gram[cols, cols] = x[:-1], x[:-1].T, gcc
        rhs[other], rhs[cols] = m[:-1, -1], x[-1]
        return gram, rhs, float(m[-1, -1])

    def r_factor(self, s: State) -> np.ndarray:
        """R (n_cols, n_cols) of J = QR, accumulated over row chunks (TSQR): J and R share their singular
        values and right singular vectors, and R^T R = J^T J."""
        r_acc = np.zeros((0, self.n_cols))
        for ch in self.chunks:
            r_acc = np.linalg.qr(np.vstack([r_acc, self._dense(ch, self._blocks(s, ch)[1])]), mode="r")
        return r_acc

    def retract(self, s: State, delta: np.ndarray) -> State:
        """The state moved by a step `delta` in the free unknowns."""
        k, c = self.k, self.c_st
        if self.n_cols < self.n_all:
            full = np.zeros(self.n_all)
            full[self.free] = delta
            delta = full
        stations = []
        for i, st in enumerate(s.stations):
            v, om = delta[c + 6 * i : c + 6 * i + 3], delta[c + 6 * i + 3 : c + 6 * i + 6]
            e = exp_so3(om)
            stations.append(Station(e @ st.rotation, e @ st.translation + v))
        points = s.points + delta[c + 6 * self.n_st :].reshape(self.n_pt, 3)
        return State(s.dev + delta[:k], stations, points, s.ext + delta[k:c])

    def unknown_names(self) -> list[str]:
        names = [p.name for p in self.params] + ([] if self.ext is None else list(self.ext.names))
        for s in self.station_ids:
            names += [f"station {s} {c}" for c in ("tx", "ty", "tz", "rx", "ry", "rz")]
        for p in self.point_ids:
            names += [f"point {p} {c}" for c in "xyz"]
        return [n for n, f in zip(names, self.free, strict=True) if f]


@dataclass
class Solution:
    """Where the solver stopped (after scipy's OptimizeResult: success, message, nit); the solver never holds the
    whole Jacobian (`Problem.residual_and_jacobian` forms it at `state` when a caller needs it)."""

    state: State
    nit: int
    converged: bool
    message: str
    # (J^T J, J^T r, r.r) at `state` to first order in the last step when the solver stopped on a step it took without
    # forming them there (J^T J kept, r - J d), else None: they differ from those formed at `state` by the model's
    # curvature times that small step (test_identify: a step from them moves by < 1e-7 of the noise)
    normal: tuple[np.ndarray, np.ndarray, float] | None = None


def solve(problem: Problem, state: State, max_iter: int = 100) -> Solution:
    """Levenberg-Marquardt on column-scaled normal equations from `state`.

    The normal equations are accumulated once per Jacobian (`Problem.normal_equations`, by row chunks, pose
    by pose) and reused for every damping step tried at that point; the pass that forms them also gives the
    cost that judges the step which led there."""
    info, g, cost = problem.normal_equations(state)
    dof = max(3 * problem.n_rows - problem.n_cols, 1)
    # rounding floor of the residual vector: coordinates carry ~1e-16 relative error each
    floor = 1e-15 * float(np.linalg.norm(problem._whiten(problem.xyz)))
    lam, iterations = 1e-8, 1
    # after a taken step the next trial point is evaluated with its normal equations (steps are nearly always
    # taken: geometric calibration is close to linear), after a refused one by its residuals alone, and so is the
    # trial after a step taken only once damped more: on a valley the undamped step overshoots every time (the
    # damping then alternates, one refused trial per iteration), and forming normal equations that are thrown
    # away doubled the cost of such fits (issue 26: cyclic_error with encoder_scale on the UR10's Series B, 25
    # iterations). The iterates are the same either way.
    fused, refused = True, False
    prev = 0.0  # size of the last step taken almost undamped (0: none)
    converged, message = False, f"stopped after {max_iter} iterations without meeting the step test"
    eye = np.eye(problem.n_cols)
    scale = info_s = gs = None
    for _ in range(max_iter):
        if info_s is None:
            scale = np.sqrt(np.diag(info))  # the column norms of J
            scale[scale == 0] = 1.0
            # normal equations of the column-scaled problem: its condition number is modest (tens to
            # thousands for calibration set-ups), and any step error is corrected by the next iteration
            # because residuals and Jacobian are exact; identifiability is judged by the SVD afterwards
            info_s, gs = info / np.outer(scale, scale), g / scale
        ds = np.linalg.solve(info_s + lam * eye, gs)
        jd2 = float(ds @ info_s @ ds)  # |J_s ds|^2
        step, tol = np.sqrt(jd2), 1e-9 * np.sqrt(cost / dof) + floor
        # Converged when an (almost undamped) step would move the fit by < 1e-9 of the noise level, so
        # parameters move by ~1e-9 of their standard deviation, or by less than the rounding floor. Gauss-Newton
        # converges linearly near the minimum: with the rate rho = step / previous step, the steps still to
        # come after this one add up to rho / (1 - rho) * step, and when that is below the same tolerance the
        # step is taken as the last one (MINPACK's lm likewise stops on the step it takes, xtol).
        rate = step / prev if prev > 0 else 1.0
        if lam <= 1e-6 and (step <= tol or (rate <= 0.5 and rate / (1.0 - rate) * step <= tol)):
            d = ds / scale
            state = problem.retract(state, d)
            iterations += 1
            converged, message = True, "the undamped step, or all steps after it, below the noise and rounding floor"
            moved = (info, g - info @ d, cost - 2.0 * float(g @ d) + jd2)  # r - J d: the normal equations there
            return Solution(state, iterations, converged, message, moved)
        cand = problem.retract(state, ds / scale)
        if fused:  # one pass gives the trial cost and, if the step is taken, the next normal equations
            info_new, g_new, cost_new = problem.normal_equations(cand)
        else:
            r_new = problem.residual(cand)
            cost_new = float(r_new @ r_new)
        # Near the minimum the decrease a step predicts falls below the rounding noise of the cost
        # (residuals of ~0.01 mm from coordinates of ~5000 mm): such a step is taken on trust, since
        # a comparison of costs can no longer judge it.
        predicted = 2.0 * float(gs @ ds) - jd2
        if cost_new <= cost or predicted <= 1e-10 * cost:
            state = cand
            info, g, cost = (info_new, g_new, cost_new) if fused else problem.normal_equations(state)
            info_s = None
            iterations += 1
            prev = step if lam <= 1e-6 else 0.0
            lam = max(lam / 10.0, 1e-12)
            fused = fused or not refused
            refused = False
        else:
            refused = True
            lam *= 10.0
            fused = False
            if lam > 1e8:
                message = "the damping exceeded 1e8: no step decreases the cost"
                break
    return Solution(state, iterations, converged, message)


def identify(
    chain: Chain,
    table: MeasurementTable,
    tool_points: dict[str, np.ndarray],
    params: list[Param],
    noise: TrackerNoise | None = None,
    dev0: np.ndarray | None = None,
    max_iter: int = 100,
    extension: Extension | None = None,
    ext0: np.ndarray | None = None,
    fixed: tuple[str, ...] = (),
    covariance: bool = True,
    rows: Rows | None = None,
) -> Identification:
    """Identify `params` (deviations from nominal), the extension's parameters, every station and every
    reference point; `fixed` ("robot", "points") holds those at dev0 / ext0 / tool_points (their rows and
    columns of the covariance are zero). Without `covariance` (a fit whose residuals alone are used: the nominal
    robot's "before" fit) the covariance is NaN, there is no R factor and the set-up's identifiability is not
    checked: the pass over the rows and the factorisation that give them are saved (issue 41). `rows`: the table's
    layout when another fit of it made it (Problem)."""
    problem = Problem(chain, table, tool_points, params, noise, dev0, extension, ext0, fixed, rows)
    sol = solve(problem, problem.initial, max_iter)
    state = sol.state
    residuals = problem.xyz - problem.predicted(state)
    r = problem._whiten(residuals).ravel()
    dof = 3 * problem.n_rows - problem.n_cols
    s2 = float(r @ r) / dof
    cov, rf = np.full((problem.n_all, problem.n_all), np.nan), None
    if covariance:
        cov, rf = _covariance(problem, state, s2)
    return identification_of(problem, state, residuals, cov, s2, dof, sol.nit, sol.converged, sol.message, rf)


def identification_of(
    problem: Problem,
    state: State,
    residuals: np.ndarray,
    cov: np.ndarray,
    variance_factor: float,
    dof: int,
    iterations: int,
    converged: bool,
    message: str,
    r_factor: np.ndarray | None = None,
) -> Identification:
    """The Identification of `problem` at `state`: its chain, parameters, stations, points, noise model and extension
    with the fit's figures (identify's, and the joint error map's penalised fit)."""
    return Identification(
        chain=problem.chain,
        params=list(problem.params),
        dev=state.dev,
        stations=dict(zip(problem.station_ids, state.stations, strict=True)),
        points={p: state.points[i] for i, p in enumerate(problem.point_ids)},
        cov=cov,
        station_ids=problem.station_ids,
        point_ids=problem.point_ids,
        residuals=residuals,
        variance_factor=variance_factor,
        dof=dof,
        iterations=iterations,
        noise=problem.noise,
        extension=problem.ext,
        ext=state.ext,
        converged=converged,
        message=message,
        r_factor=r_factor,
    )


def cholesky_r(normal: np.ndarray) -> np.ndarray | None:
    """R with R^T R = normal (J^T J), from the Cholesky factor of the column-scaled normal matrix; None when the
    scaled Jacobian's condition number exceeds CHOLESKY_COND (or the factorisation fails): the normal equations
    have then lost more to rounding than the 1e-12 this R is held to (a QR of J keeps it)."""
    scale = np.sqrt(np.diag(normal))
    scale[scale == 0] = 1.0
    try:
        lower = np.linalg.cholesky(normal / np.outer(scale, scale))
    except np.linalg.LinAlgError:
        return None
    sv = np.linalg.svd(lower, compute_uv=False)  # the scaled Jacobian's singular values
    return lower.T * scale if sv[-1] * CHOLESKY_COND >= sv[0] else None


def _covariance(problem: Problem, state: State, s2: float) -> tuple[np.ndarray, np.ndarray]:
    """(covariance of every unknown at `state`, eq. 27 with the variance factor s2; R of the whitened Jacobian), or
    IdentificationError naming the unknowns the measurements cannot separate. R is the Cholesky factor's of the
    normal equations at `state` when they are well conditioned (cholesky_r: half the work of a QR of the Jacobian),
    else the QR's."""
    rf = cholesky_r(problem.normal_equations(state)[0])
    if rf is None:
        rf = problem.r_factor(state)
    scale = np.linalg.norm(rf, axis=0)  # = the column norms of J
    scale[scale == 0] = 1.0
    _, sv, vt = np.linalg.svd(rf / scale)
    if sv[-1] < 1e-9 * sv[0]:
        null = np.abs(vt[-1])
        names = problem.unknown_names()
        worst = [names[i] for i in np.argsort(null)[::-1][:4] if null[i] > 0.1]
        raise IdentificationError(
            f"{problem.source}: unidentifiable set-up: the measurements cannot separate {', '.join(worst)} "
            "(add poses, reference points or stations, or identify fewer parameters)"
        )
    cov = np.zeros((problem.n_all, problem.n_all))
    cov[np.ix_(problem.free, problem.free)] = s2 * ((vt.T / sv**2) @ vt) / np.outer(scale, scale)
    return cov, rf


def model_points(
    kin: Kinematics,
    q: np.ndarray,
    tool: np.ndarray,
    dev: np.ndarray,
    ext: Extension | None,
    theta: np.ndarray,
    poses: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """Reflector positions (N, 3) in the robot base frame, geometric model plus extension. `poses` (first
    row of each distinct pose, pose of each row) lets rows that share a pose share its forward kinematics."""
    off = None if ext is None else ext.joint_offsets(theta)
    if off is not None:
        q = q + off
    first, rows = poses if poses is not None else (np.arange(len(q)), None)
    pb = kin.points(q[first], tool, dev, rows=rows)
    g = None if ext is None else ext.growth_of(theta)
    if g is not None:  # thermal: every length grows about the pivot
        pb = ext.pivot + (1.0 + g)[:, None] * (pb - ext.pivot)
    d = None if ext is None else ext.displacement_of(theta)
    return pb if d is None else pb + d


def predict_points(
    result_chain: Chain,
    params: list[Param],
    dev: np.ndarray,
    stations: dict[str, Station],
    points: dict[str, np.ndarray],
    table: MeasurementTable,
    ext: Extension | None = None,
    theta: np.ndarray | None = None,
) -> np.ndarray:
    """Predicted reflector positions (N, 3) in each row's station frame."""
    for i, (sid, pid) in enumerate(zip(table.station, table.point, strict=True)):
        if sid not in stations:
            raise IdentificationError(
                f"{table.source}: row {i + 2}: column station: unknown station {sid!r} (the "
                f"model has {', '.join(stations)}; a tracker set up elsewhere: trackcal locate)"
            )
        if pid not in points:
            raise IdentificationError(f"{table.source}: row {i + 2}: column point: unknown point {pid!r}")
    tool = np.array([points[p] for p in table.point])
    pb = model_points(Kinematics(result_chain, params), np.radians(table.q_deg), tool, dev, ext, theta)
    rs = np.array([stations[s].rotation for s in table.station])
    ts = np.array([stations[s].translation for s in table.station])
    xs = np.einsum("nij,nj->ni", rs, pb) + ts
    scale = None if ext is None else ext.range_of(theta)
    return xs if scale is None else (1.0 + scale)[:, None] * xs


def residual_stats(residuals: np.ndarray) -> dict[str, float]:
    """Table 9: coordinate-based (every x, y, z) and distance-based (3-D norm) residuals, max and RMS."""
    coord = np.abs(residuals).ravel()
    dist = np.linalg.norm(residuals, axis=1)
    return {
        "coord_max_mm": float(coord.max()),
        "coord_rms_mm": float(np.sqrt(np.mean(coord**2))),
        "dist_max_mm": float(dist.max()),
        "dist_rms_mm": float(np.sqrt(np.mean(dist**2))),
    }


def significance(
    chain: Chain, params: list[Param], dev: np.ndarray, q0: np.ndarray, tcp: np.ndarray
) -> list[tuple[str, float]]:
    """Section 7.3: TCP position error at the test pose q0 (rad) when one parameter is reset to nominal."""
    kin = Kinematics(chain, params)
    ref = kin.points(q0[None], tcp, dev)[0]
    out = []
    for i, p in enumerate(params):
        d = dev.copy()
        d[i] = 0.0
        out.append((p.name, float(np.linalg.norm(kin.points(q0[None], tcp, d)[0] - ref))))
    return out
