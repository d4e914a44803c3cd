"""An independent campaign generator for the floor tests (issue 36): effects real cells have that no candidate of
diagnose has the form of, written from their physics here (not mocks/effects.py, not test_diagnose_hidden.py).

A true cell: the nominal robot of a cell with random deviations of every parameter of the complete model (lengths
~0.3 mm, angles ~0.02 deg: the paper's Table 8 orders of magnitude), its reference points and tracker stations
moved from their nominal places; the tracker noise of the AT901 model (calib/identify/noise.py). Each effect is
scaled so that what a geometric calibration cannot absorb is a drawn multiple (3x to 6x) of the tracker noise, as the
issue's campaigns were (75 um on a KR-270).

Effects (each a unit-scale shape, the magnitude set by that scaling):
- motor_gear: a transmission error of the motor-side gear stage: harmonics at the gear ratio N times the joint angle
  (N ~ 100-160 for robot reducers), aliased by poses scattered over the joint's range;
- sagging_nest: one reflector nest on a compliant stalk sags along gravity (base -z) by an amount proportional to
  the cosine of the stalk's elevation (a cantilever's tip deflection under its own weight is proportional to the
  bending moment at the root, which is the weight times the horizontal lever: cos of the elevation);
- station_scale: one station's distances scaled (air temperature or pressure wrong at that station: the refractive
  index of air changes by ~1 ppm per K, ~0.27 ppm per hPa; Edlen 1966), its other station right;
- wrist_coupling: the motor of axis 6 drives through axis 5 (KUKA wrists couple A4/A5/A6): A6 turns by a small
  ratio of A5's angle the controller does not know;
- warm_up: the links grow by a first-order warm-up g(t) = g0 (1 - exp(-t / tau)), tau a fraction of the campaign,
  about the robot base; poses measured after the campaign see the saturated growth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trackcal.calib.doe.poses import random_poses
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.identify.solver import Station, identify
from trackcal.calib.io.table import MeasurementTable
from trackcal.calib.model.cell import Cell
from trackcal.calib.model.kinematics import Kinematics
from trackcal.calib.model.params import complete_params, irreducible_params
from trackcal.calib.model.rigid import exp_so3

EFFECTS = ("motor_gear", "sagging_nest", "station_scale", "wrist_coupling", "warm_up")
NOISE_RMS_MM = 0.015  # AT901 model at 2-4 m: sqrt((5^2 + 2 * 16^2) / 3) um
SECONDS_PER_ROW = 20.0  # a tracker measurement with the robot settling


@dataclass
class Campaign:
    table: MeasurementTable  # measured (noisy)
    fresh: MeasurementTable  # fresh poses, their true reflector positions in the station frames (noise-free)
    params: list  # the irreducible parameters the diagnosis fits
    scale: float  # the effect's magnitude (unit shape times this)


class TrueCell:
    """A true cell drawn from `rng`: robot deviations, reference points and stations."""

    def __init__(self, cell: Cell, rng: np.random.Generator):
        self.cell, chain = cell, cell.chain
        self.params = complete_params(chain)
        self.dev = np.array(
            [rng.normal(0, 0.3) if p.is_length else np.radians(rng.normal(0, 0.02)) for p in self.params]
        )
        self.kin = Kinematics(chain, self.params)
        self.points = {k: v + rng.normal(0, 0.5, 3) for k, v in sorted(cell.tool_points.items())}
        self.stations = {}
        for sid, pl in sorted(cell.stations.items()):
            r = pl.rotation @ exp_so3(rng.normal(0, np.radians(0.5), 3))
            pos = pl.position + rng.normal(0, 20.0, 3)
            self.stations[sid] = Station(r.T, -r.T @ pos)


class Effect:
    """One effect's unit shape: joint errors dq(q, t), a displacement of the reflector in the base frame
    dp(q, point, t), a growth g(t) of the arm, and a scale of one station's distances."""

    def __init__(self, name: str, cell: TrueCell, rng: np.random.Generator, duration_s: float):
        self.name = name
        n = cell.cell.chain.dof
        self.station, self.sag_point, self.joints = None, None, ()
        if name == "motor_gear":
            self.joints = tuple(rng.choice(np.arange(1, min(n, 5)), 2, replace=False))  # A2..A5
            self.ratios = rng.integers(100, 161, 2)
            self.phases = rng.uniform(0, 2 * np.pi, 2)
        elif name == "sagging_nest":
            self.sag_point = sorted(cell.points)[rng.integers(0, len(cell.points))]
        elif name == "station_scale":
            self.station = sorted(cell.stations)[rng.integers(0, len(cell.stations))]
        elif name == "wrist_coupling":
            self.joints = (n - 2, n - 1)  # A5 leaks into A6
        elif name == "warm_up":
            self.tau = duration_s * rng.uniform(0.15, 0.4)
        elif name != "none":
            raise ValueError(name)
        self.cell = cell

    def dq(self, q: np.ndarray) -> np.ndarray:
        out = np.zeros_like(q)
        if self.name == "motor_gear":
            for j, ratio, ph in zip(self.joints, self.ratios, self.phases, strict=True):
                out[:, j] += np.sin(ratio * q[:, j] + ph)
        elif self.name == "wrist_coupling":
            a5, a6 = self.joints
            out[:, a6] += q[:, a5]
        return out

    def dp(self, q: np.ndarray, point: list[str]) -> np.ndarray:
        """(N, 3) displacement of the reflector in the robot base frame."""
        out = np.zeros((len(q), 3))
        if self.name == "sagging_nest":
            rot, _ = self.cell.kin.end_frames(q, self.cell.dev)
            stalk = rot[:, :, 2]  # the nest's stalk along the flange's z axis
            elevation = np.arcsin(np.clip(stalk[:, 2], -1.0, 1.0))
            mine = np.array([p == self.sag_point for p in point])
            out[mine, 2] = -np.cos(elevation[mine])
        return out

    def growth(self, t: np.ndarray) -> np.ndarray:
        return 1.0 - np.exp(-t / self.tau) if self.name == "warm_up" else np.zeros(len(t))

    def range_scale(self, station: list[str]) -> np.ndarray:
        return np.array([1.0 if s == self.station else 0.0 for s in station])


def _rows(cell: TrueCell, poses: np.ndarray, start_s: float = 0.0):
    """Campaign order: station by station, point by point, the poses in order; (pose ids, stations, points, q, t)."""
    pose, station, point, q = [], [], [], []
    for sid in cell.stations:
        for pid in cell.points:
            for i, qi in enumerate(poses):
                pose.append(f"Q{i + 1}")
                station.append(sid)
                point.append(pid)
                q.append(qi)
    t = start_s + np.arange(len(pose)) * SECONDS_PER_ROW
    return pose, station, point, np.array(q), t


def _measure(cell: TrueCell, effect: Effect, a: float, rows) -> np.ndarray:
    """True reflector positions in the station frames, the effect at scale `a`."""
    _, station, point, q, t = rows
    tool = np.array([cell.points[p] for p in point])
    p = cell.kin.points(q + a * effect.dq(q), tool, cell.dev) + a * effect.dp(q, point)
    o0 = cell.cell.chain.base[:3, 3]
    p = o0 + (1.0 + a * effect.growth(t))[:, None] * (p - o0)
    x = np.array([cell.stations[s].apply(pi[None])[0] for s, pi in zip(station, p, strict=True)])
    return x * (1.0 + a * effect.range_scale(station))[:, None]  # a station's distances scaled


def _table(rows, xyz: np.ndarray, source: str) -> MeasurementTable:
    pose, station, point, q, t = rows
    return MeasurementTable(np.arange(1, len(pose) + 1), t, pose, station, point, np.degrees(q), xyz, source=source)


def campaign(
    cell: Cell,
    name: str,
    seed: int,
    n_poses: int,
    n_fresh: int = 40,
    narrow_deg: float | None = None,
    outside: float = 0.0,
) -> Campaign:
    """A campaign of `n_poses` with the effect `name`, and `n_fresh` fresh poses measured after it. `narrow_deg`:
    every joint's calibration poses within a window of that width about a random centre (clipped to the limits);
    the fresh poses then reach up to `outside` (a fraction of the window) beyond it on each joint."""
    rng = np.random.default_rng(seed)
    true = TrueCell(cell, rng)
    limits = cell.chain.limits_array()
    limits = np.where(np.isfinite(limits), limits, np.array([-np.pi, np.pi]))
    if narrow_deg is None:
        poses = random_poses(cell, n_poses + n_fresh, rng)
        calib, fresh = poses[:n_poses], poses[n_poses:]
    else:
        width = np.radians(narrow_deg)
        centre = rng.uniform(limits[:, 0] + width, limits[:, 1] - width)
        calib = centre + rng.uniform(-0.5, 0.5, (n_poses, cell.chain.dof)) * width
        half = 0.5 * width * (1.0 + outside)
        fresh = centre + rng.uniform(-1.0, 1.0, (n_fresh, cell.chain.dof)) * half
    calib, fresh = np.round(calib, 6), np.round(fresh, 6)
    rows = _rows(true, calib)
    duration = rows[4][-1] + SECONDS_PER_ROW
    effect = Effect(name, true, rng, duration)
    later = _rows(true, fresh, start_s=duration + 600.0)  # measured after the campaign: a warm arm
    params = irreducible_params(cell.chain)[0]
    scale = 0.0
    if name != "none":
        # what the geometric model cannot absorb, on noise-free rows: linear in a small trial scale
        base = _measure(true, effect, 0.0, rows)
        trial = 1e-6
        probe = _measure(true, effect, trial, rows)

        def unabsorbed(x):
            res = identify(cell.chain, _table(rows, x, "twin"), cell.tool_points, params)
            return float(np.sqrt(np.mean(res.residuals**2)))

        got = max(unabsorbed(probe) - unabsorbed(base), 1e-300)
        scale = trial * rng.uniform(3.0, 6.0) * NOISE_RMS_MM / got
    xyz = _measure(true, effect, scale, rows)
    noise = TrackerNoise()
    for sid in true.stations:
        m = np.array([s == sid for s in rows[1]])
        xyz[m] += noise.sample(xyz[m], rng)
    return Campaign(
        _table(rows, xyz, f"independent twin {name} seed {seed}"),
        _table(later, _measure(true, effect, scale, later), "fresh poses"),
        params,
        scale,
    )
