"""The digital twin: the "true" robot, its tracker stations and an AT901-like tracker.

One deterministic world for the whole project: the true chain is the nominal one plus hidden deviations
(any parameter of the complete model; by default the paper's Table 8 for the KR-270 and, for any other robot, every
irreducible parameter drawn from the seed, `drawn_deviations`), the true reference points and station placements
differ from the nominal ones, optional hidden non-geometric effects (`mocks.effects`) act on the real joint angles,
the arm's size or a station, and every measurement's noise is a pure function of (seed, identity of
the step), so a campaign resumed after a crash sees exactly the numbers an uninterrupted one sees.

The twin is a small stateful world: `move_to` tells it where the robot was commanded (the direction each
joint last moved in matters for backlash), `measure` takes the time since the campaign start (thermal
drift: every length grows, tool included, about the pivot `thermal_pivot`; station shift).
`simulate_campaign` is the table a campaign of given poses would record on it, in the campaign order; `Twin.truth`
is what it really is, for `simulate --truth` and `run --sim --truth`.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from operator import sub

import numpy as np

from trackcal.calib.diagnose.extensions import LOAD_COLUMN
from trackcal.calib.doe.order import campaign_order
from trackcal.calib.doe.poses import random_poses
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.identify.solver import Problem, Station
from trackcal.calib.io.table import MeasurementTable
from trackcal.calib.model.cell import Cell
from trackcal.calib.model.chain import Chain
from trackcal.calib.model.kinematics import Kinematics
from trackcal.calib.model.params import complete_params, irreducible_params, param_by_name
from trackcal.calib.model.rigid import exp_so3
from trackcal.mocks.effects import Effects, unit_effect

# Paper Table 8: the KR-270's identified deviations (mm, deg), the default hidden truth of the twin.
PAPER_TABLE8 = {
    "px1": -0.353,
    "py1": 0.426,
    "phix1": 0.015,
    "dq2": -0.007,
    "px2": 0.458,
    "phix2": 0.022,
    "phiz2": -0.023,
    "dq3": -0.023,
    "px3": -0.214,
    "pz3": -0.508,
    "phiz3": -0.011,
    "dq4": 0.001,
    "py4": -0.167,
    "pz4": -0.018,
    "phiz4": 0.025,
    "dq5": -0.011,
    "pz5": 0.016,
    "phiz5": -0.008,
}

REFERENCE_POSES = 40


def stable_seed(seed: int, key: str) -> np.random.Generator:
    """A generator that depends only on the seed and the step's identity string."""
    digest = hashlib.blake2b(key.encode(), digest_size=8).digest()
    return np.random.default_rng([int(seed), int.from_bytes(digest, "little")])


# Every other robot's hidden truth: each irreducible parameter's deviation drawn from N(0, sigma), seeded. The
# magnitudes are those of an uncalibrated industrial robot: its absolute positioning error is about 1 mm while its
# repeatability is far smaller (ISO 9283 RP on the data sheets: KR 270 0.06 mm, UR10 0.1 mm, IRB 120 0.01 mm), i.e.
# a few tenths of a millimetre per link and a few hundredths of a degree per joint; the paper's Table 8 (above) has
# an RMS of 0.33 mm over its 7 lengths and of 0.016 deg over its 11 angles, the same range.
DEVIATION_SIGMA_MM = 0.3
DEVIATION_SIGMA_DEG = 0.02


def drawn_deviations(chain: Chain, seed: int) -> dict[str, float]:
    """The deviations (mm, deg) of every irreducible parameter of `chain`, drawn from N(0, DEVIATION_SIGMA_MM) for
    lengths and N(0, DEVIATION_SIGMA_DEG) for angles; a pure function of (seed, chain name)."""
    rng = stable_seed(seed, f"twin/deviations/{chain.name}")
    return {
        p.name: float(rng.normal(0.0, DEVIATION_SIGMA_MM if p.is_length else DEVIATION_SIGMA_DEG))
        for p in irreducible_params(chain)[0]
    }


@dataclass
class Twin:
    cell: Cell
    seed: int = 0
    deviations: dict[str, float] | None = None  # name -> mm | deg; default PAPER_TABLE8 for the KR-270, else drawn
    # (drawn_deviations); {} for the nominal robot
    noise: TrackerNoise | None = None  # None: the cell's instrument (calib.model.instruments; default the AT901)
    point_offset_mm: float = 0.5  # std of the true points around the tool drawing
    station_error_mm: float = 20.0  # std of the true station positions around the cell's nominal ones
    effects: dict[str, float] = field(default_factory=dict)  # hidden effect -> magnitude (mm, see effects.py)
    thermal_pivot: str = "base"  # what thermal growth keeps fixed (effects.THERMAL_PIVOTS)

    def __post_init__(self) -> None:
        if self.noise is None:
            self.noise = TrackerNoise.of(self.cell.tracker)
        chain = self.cell.chain
        self.params = complete_params(chain)
        self.kin = Kinematics(chain, self.params)
        devs = self.deviations
        if devs is None:
            devs = PAPER_TABLE8 if chain.name == "kr270" else drawn_deviations(chain, self.seed)
        self.true_dev = np.zeros(len(self.params))
        for name, v in devs.items():
            p = param_by_name(chain, name)
            self.true_dev[self.params.index(p)] = v if p.is_length else np.radians(v)
        rng = stable_seed(self.seed, "twin/setup")
        self.true_points = {
            pid: p + rng.normal(0.0, self.point_offset_mm, 3) for pid, p in sorted(self.cell.tool_points.items())
        }
        self.true_stations: dict[str, Station] = {}
        for sid, pl in sorted(self.cell.stations.items()):
            r = pl.rotation @ exp_so3(rng.normal(0.0, np.radians(0.5), 3))
            pos = pl.position + rng.normal(0.0, self.station_error_mm, 3)
            self.true_stations[sid] = Station(rotation=r.T, translation=-r.T @ pos)
        self.hidden = Effects()
        self._last_q: list[float] | None = None
        self.approach = np.zeros(chain.dof)
        for name, magnitude in sorted(self.effects.items()):
            self._add_effect(name, magnitude)

    # ------------------------------------------------------------------ robot state
    def move_to(self, q_deg) -> None:
        """The robot was commanded to q_deg (reported angles); joints that moved more than 1e-7 deg set their
        approach sign. A controller calls it every cycle of a move (issue 41): the six differences are plain
        floats, and the approach array is made anew only when a sign changes."""
        q = list(map(float, q_deg))
        last, self._last_q = self._last_q, q
        if last is None:
            return
        approach = self.approach.tolist()
        steps = map(sub, q, last)
        moved = [1.0 if d > 1e-7 else -1.0 if d < -1e-7 else a for d, a in zip(steps, approach, strict=True)]
        if moved != approach:
            self.approach = np.array(moved)

    # ------------------------------------------------------------------ measurements
    def point_in_base(self, q_deg: np.ndarray, point: str, t_s: float = 0.0) -> np.ndarray:
        q = np.radians(np.atleast_2d(np.asarray(q_deg, dtype=float)))
        q_true = q + self.hidden.joint_errors(q, self.approach[None], t_s)
        r, o = self.kin.end_frames(q_true, self.true_dev)
        return self.hidden.grown(o[0] + r[0] @ self.true_points[point], t_s) + self.hidden.sag(point)

    def exact(self, q_deg: np.ndarray, point: str, station: str, t_s: float = 0.0) -> np.ndarray:
        """Noise-free reflector position in the station frame (robot state as set by `move_to`)."""
        x = self.true_stations[station].apply(self.point_in_base(q_deg, point, t_s))
        shift = self.hidden.station_shift(station, t_s)
        x = x if shift is None else shift[0] @ x + shift[1]
        return x * (1.0 + self.hidden.range_scale.get(station, 0.0))  # its air data wrong: its distances scaled

    def measure(self, q_deg: np.ndarray, point: str, station: str, key: str, t_s: float = 0.0) -> np.ndarray:
        """One tracker measurement; the noise depends only on (seed, key)."""
        x = self.exact(q_deg, point, station, t_s)
        return x + self.noise.sample(x[None], stable_seed(self.seed, f"noise/{key}"))[0]

    def visible(self, q_deg: np.ndarray, point: str, station: str) -> bool:
        """The reflector faces the station within the acceptance cone."""
        q = np.radians(np.atleast_2d(q_deg))
        r, _ = self.kin.end_frames(q, self.true_dev)
        p = self.point_in_base(q_deg, point)
        st = self.true_stations[station]
        tracker = -st.rotation.T @ st.translation
        d = tracker - p
        cosang = float(r[0] @ self.cell.tool_normals[point] @ d / np.linalg.norm(d))
        return cosang >= np.cos(np.radians(self.cell.acceptance_deg))

    def _exact_rows(self, table) -> np.ndarray:
        """Noise-free positions of the rows of a campaign table, replaying its motions from a fresh state."""
        self._last_q, self.approach = None, np.zeros(self.cell.chain.dof)
        out = []
        for q, pt, st, t in zip(table.q_deg, table.point, table.station, table.t_s, strict=True):
            self.move_to(q)
            out.append(self.exact(q, pt, st, t))
        return np.array(out)

    # ------------------------------------------------------------------ the truth
    def test_pose_points(self) -> dict[str, dict[str, np.ndarray]] | None:
        """{station: {point: true reflector position}} at the cell's test pose in each station's frame, at the
        neutral context the models' test-pose figure has (no approach history, the campaign's start); None
        without a test pose."""
        if self.cell.test_pose is None:
            return None
        saved = self.approach
        self.approach = np.zeros(self.cell.chain.dof)
        q = np.degrees(self.cell.test_pose)
        try:
            return {
                sid: {pid: self.exact(q, pid, sid) for pid in sorted(self.true_points)}
                for sid in sorted(self.true_stations)
            }
        finally:
            self.approach = saved

    def truth(self) -> dict:
        """What the twin really is, in boundary units (mm, deg), laid out as model.json lays out a model: the
        parameter deviations (the irreducible set and any other deviating parameter), the stations (station <-
        base), the reference points (last joint frame), the hidden effects and the true reflector positions and
        their centroid at the cell's test pose in each station's frame."""
        kept = set(irreducible_params(self.cell.chain)[0])
        pars = {}
        for p, v in zip(self.params, self.true_dev, strict=True):
            if p in kept or v != 0.0:
                pars[p.name] = {
                    "value": float(v) if p.is_length else float(np.degrees(v)),
                    "unit": "mm" if p.is_length else "deg",
                    "nominal": float(self.cell.chain.joints[p.joint].translation[p.axis]) if p.kind == "p" else 0.0,
                }
        if self.deviations is not None:
            source = "given"
        elif self.cell.chain.name == "kr270":
            source = "paper Table 8"
        else:
            source = (
                f"drawn: N(0, {DEVIATION_SIGMA_MM} mm) per length, N(0, {DEVIATION_SIGMA_DEG} deg) per angle, "
                f"seed {self.seed}"
            )
        at_test = self.test_pose_points()
        test = (
            None
            if at_test is None
            else {
                "joints_deg": np.degrees(self.cell.test_pose).tolist(),
                "points_mm": {sid: {pid: x.tolist() for pid, x in pts.items()} for sid, pts in at_test.items()},
                "centroid_mm": {sid: np.mean(list(pts.values()), axis=0).tolist() for sid, pts in at_test.items()},
            }
        )
        return {
            "format": "trackcal-twin-truth/1",
            "cell": self.cell.name,
            "robot": self.cell.chain.name,
            "seed": int(self.seed),
            "deviations": source,
            "parameters": pars,
            "stations": {
                sid: {"rotation": st.rotation.tolist(), "translation_mm": st.translation.tolist()}
                for sid, st in sorted(self.true_stations.items())
            },
            "tool_points": {pid: {"xyz_mm": x.tolist()} for pid, x in sorted(self.true_points.items())},
            "effects": {"magnitudes_mm": dict(sorted(self.effects.items())), "parameters": self.hidden.to_doc()},
            "test_pose": test,
        }

    # ------------------------------------------------------------------ hidden effects
    def _add_effect(self, name: str, magnitude_mm: float) -> None:
        """Scale the effect so that what a geometric calibration cannot absorb has RMS `magnitude_mm`."""
        rng = stable_seed(self.seed, f"effect/{name}")
        poses = np.degrees(random_poses(self.cell, REFERENCE_POSES, stable_seed(self.seed, "twin/reference")))
        saved, self.hidden = self.hidden, Effects()
        base = simulate_campaign(self, poses, noise_free=True)
        first = sorted(self.true_stations)[0]  # a station shift happens halfway through this station's block
        t_mid = float(np.median(base.t_s[np.array(base.station) == first]))
        unit = unit_effect(
            name,
            self.cell.chain,
            rng,
            sorted(self.true_stations),
            t_mid,
            self.thermal_pivot,
            tuple(sorted(self.true_points)),
        )
        self.hidden = unit
        shifted = self._exact_rows(base)
        self.hidden = saved
        self._last_q, self.approach = None, np.zeros(self.cell.chain.dof)
        d = (shifted - base.xyz).ravel()
        problem = Problem(self.cell.chain, base, self.cell.tool_points, irreducible_params(self.cell.chain)[0])
        _, jm = problem.residual_and_jacobian(problem.initial)
        resid = d - jm @ np.linalg.lstsq(jm, d, rcond=None)[0]
        rms = float(np.sqrt(np.mean(resid**2)))
        if rms <= 0:
            raise ValueError(f"effect {name} is invisible to this cell's reference campaign")
        scaled = unit.scaled(magnitude_mm / rms)
        merged = self.hidden
        for key in ("compliance", "backlash", "encoder_scale"):
            if getattr(scaled, key) is not None:
                setattr(merged, key, getattr(scaled, key))
        if scaled.mass_chain is not None:
            merged.mass_chain = scaled.mass_chain
        merged.cyclic += scaled.cyclic
        if scaled.thermal_per_s:
            merged.thermal_per_s, merged.thermal_pivot = scaled.thermal_per_s, scaled.thermal_pivot
        merged.shift = scaled.shift or merged.shift
        if scaled.warmup_inf:
            merged.warmup_inf, merged.warmup_tau_s = scaled.warmup_inf, scaled.warmup_tau_s
            merged.warmup_pivot = scaled.warmup_pivot
        if scaled.payload_compliance is not None:
            merged.payload_compliance, merged.payload_chain = scaled.payload_compliance, scaled.payload_chain
            merged.payload = scaled.payload
        merged.coupling = scaled.coupling if scaled.coupling is not None else merged.coupling
        merged.range_scale.update(scaled.range_scale)
        merged.nest_sag.update(scaled.nest_sag)


def simulate_campaign(
    twin: Twin,
    poses_deg: np.ndarray,
    repeat: int = 1,
    stations: list[str] | None = None,
    points: list[str] | None = None,
    noise_free: bool = False,
    seconds_per_measurement: float = 20.0,
) -> MeasurementTable:
    """Measure every pose (repeated `repeat` times) with every point from every station that sees it.

    Rows come in the campaign order of `calib.doe.order` (the order `trackcal run` measures in): station by
    station, point by point, the block's reference pose revisited at its start and end, passes alternating
    direction; which reflector a station sees is the twin's own (true) visibility. Joint values are rounded
    to the controller's 0.0001 deg. The twin's robot state follows the motions (backlash), time advances per
    measurement (thermal drift). The noise of pass k is keyed by k, that of a drift check by its number.
    """
    stations = stations or sorted(twin.true_stations)
    points = points or sorted(twin.true_points)
    poses = np.round(np.asarray(poses_deg, dtype=float), 4)
    seen = {(s, pt): np.array([twin.visible(q, pt, s) for q in poses], dtype=bool) for s in stations for pt in points}
    visits: dict[tuple[str, str, int, bool], int] = {}
    rows = []
    for v in campaign_order(len(poses), stations, points, seen, repeat):
        q = poses[v.pose]
        k = visits.get((v.station, v.point, v.pose, v.drift), 0)
        visits[(v.station, v.point, v.pose, v.drift)] = k + 1
        twin.move_to(q)
        t = len(rows) * seconds_per_measurement
        key = f"{v.station}/{v.point}/pose{v.pose}/{'drift' if v.drift else 'rep'}{k}"
        x = twin.exact(q, v.point, v.station, t) if noise_free else twin.measure(q, v.point, v.station, key, t)
        rows.append((f"Q{v.pose + 1}", v.station, v.point, q, x, t))
    n = len(rows)
    t_rows = np.array([r[5] for r in rows], dtype=float)
    extra = {} if twin.hidden.payload is None else {LOAD_COLUMN: [f"{m:g}" for m in twin.hidden.load_at(t_rows)]}
    return MeasurementTable(
        seq=np.arange(1, n + 1),
        t_s=np.array([r[5] for r in rows], dtype=float),
        pose=[r[0] for r in rows],
        station=[r[1] for r in rows],
        point=[r[2] for r in rows],
        q_deg=np.array([r[3] for r in rows]).reshape(n, poses.shape[1]),
        xyz=np.array([r[4] for r in rows]).reshape(n, 3),
        extra=extra,  # the payload mounted at each row, when the campaign changes it
        source="twin",
    )
