"""The digital twin: the "true" robot, its tracker stations and an AT901-like tracker.

One deterministic world for the whole project: the true chain is the nominal one plus hidden deviations
(any parameter of the complete model), the true reference points and station placements differ from
the nominal ones, and every measurement's noise is a pure function of (seed, identity of the step), so
a campaign resumed after a crash sees exactly the numbers an uninterrupted one sees.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field

import numpy as np

from calib.cell import Cell
from calib.identify import Station
from calib.kinematics import Kinematics
from calib.noise import TrackerNoise
from calib.params import complete_params, param_by_name
from calib.rigid import exp_so3

# Paper Table 8: the KR-270's identified deviations (mm, deg), the default hidden truth of the twin.
PAPER_TABLE8 = {
    "px1": -0.353, "py1": 0.426, "phix1": 0.015, "dq2": -0.007, "px2": 0.458, "phix2": 0.022,
    "phiz2": -0.023, "dq3": -0.023, "px3": -0.214, "pz3": -0.508, "phiz3": -0.011, "dq4": 0.001,
    "py4": -0.167, "pz4": -0.018, "phiz4": 0.025, "dq5": -0.011, "pz5": 0.016, "phiz5": -0.008,
}  # fmt: skip


def stable_seed(seed: int, key: str) -> np.random.Generator:
    """A generator that depends only on the seed and the step's identity string."""
    digest = hashlib.blake2b(key.encode(), digest_size=8).digest()
    return np.random.default_rng([int(seed), int.from_bytes(digest, "little")])


@dataclass
class Twin:
    cell: Cell
    seed: int = 0
    deviations: dict[str, float] | None = None  # name -> mm | deg; default PAPER_TABLE8 for the KR-270
    noise: TrackerNoise = field(default_factory=TrackerNoise)
    point_offset_mm: float = 0.5  # std of the true points around the tool drawing
    station_error_mm: float = 20.0  # std of the true station positions around the cell's nominal ones

    def __post_init__(self) -> None:
        chain = self.cell.chain
        self.params = complete_params(chain)
        self.kin = Kinematics(chain, self.params)
        devs = self.deviations
        if devs is None:
            devs = PAPER_TABLE8 if self.cell.chain.name == "kr270" else {}
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

    def point_in_base(self, q_deg: np.ndarray, point: str) -> np.ndarray:
        return self.kin.points(np.radians(np.atleast_2d(q_deg)), self.true_points[point], self.true_dev)[0]

    def exact(self, q_deg: np.ndarray, point: str, station: str) -> np.ndarray:
        """Noise-free reflector position in the station frame."""
        return self.true_stations[station].apply(self.point_in_base(q_deg, point))

    def measure(self, q_deg: np.ndarray, point: str, station: str, key: str) -> np.ndarray:
        """One tracker measurement; the noise depends only on (seed, key)."""
        x = self.exact(q_deg, point, station)
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
