"""What a campaign identifies, decided here for plan (calib.doe.design), identify and the end of the run.

A campaign's identification (calib.identify.solver) estimates, jointly: the robot parameters (by default the
irreducible set of the chain, `campaign_params`), one 6-dof transform per tracker station (a translation and a
rotation perturbation in the station frame, x' = Exp(w) x + v) and the 3 coordinates of every reference point in
the last joint frame. A plan is only as good as the unknowns it was planned for: its criterion must see the same
ones (`Unknowns`), in the solver's order (robot, stations, points).

The paper plans with base and tool known (section 7.2): `known` names the groups held at their nominal values,
for reproducing its tables only; a campaign never knows them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trackcal.calib.errors import CalibError
from trackcal.calib.model.chain import Chain
from trackcal.calib.model.params import Param, irreducible_params

KNOWABLE = ("stations", "points")  # groups that may be held known
PAPER_KNOWN = KNOWABLE  # the paper plans with base (stations) and tool (points) known: section 7.2


class UnknownsError(CalibError):
    """A set of unknowns that cannot be: an unknown group name."""


@dataclass(frozen=True)
class Unknowns:
    """The layout of a campaign's unknowns: robot parameters, then 6 per estimated station (v then w), then 3
    per estimated reference point (x, y, z)."""

    params: tuple[Param, ...]
    n_stations: int  # stations whose transform is estimated (0: known)
    n_points: int  # reference points whose coordinates are estimated (0: known)

    @property
    def k(self) -> int:
        return len(self.params)

    @property
    def c_st(self) -> int:
        """First station column."""
        return self.k

    @property
    def c_pt(self) -> int:
        """First point column."""
        return self.k + 6 * self.n_stations

    @property
    def size(self) -> int:
        return self.c_pt + 3 * self.n_points

    def scale(self, length_scale_mm: float) -> np.ndarray:
        """(size,) mm per unit of each unknown: 1 for lengths, the lever arm for angles (so that angles count as
        the millimetres they move a point at that distance)."""
        robot = [1.0 if p.is_length else length_scale_mm for p in self.params]
        return np.array(
            robot
            + [1.0, 1.0, 1.0, length_scale_mm, length_scale_mm, length_scale_mm] * self.n_stations
            + [1.0] * (3 * self.n_points)
        )

    def names(self, station_ids: list[str], point_ids: list[str]) -> list[str]:
        """Names of the unknowns in order (as calib.identify.solver.Problem.unknown_names spells them)."""
        out = [p.name for p in self.params]
        for s in station_ids[: self.n_stations]:
            out += [f"station {s} {c}" for c in ("tx", "ty", "tz", "rx", "ry", "rz")]
        for p in point_ids[: self.n_points]:
            out += [f"point {p} {c}" for c in "xyz"]
        return out


def campaign_params(chain: Chain) -> list[Param]:
    """The robot parameters a campaign identifies by default: the chain's irreducible set (with stations and
    points free, the base's and the last link's parameters merge into them: calib.model.params)."""
    return irreducible_params(chain)[0]


def campaign_unknowns(params: list[Param], n_stations: int, n_points: int, known: tuple[str, ...] = ()) -> Unknowns:
    """The unknowns of a campaign with these robot parameters, stations and reference points; `known` holds
    groups at their nominal values (KNOWABLE: the paper's section 7.2 plans with stations and points known)."""
    wrong = sorted(set(known) - set(KNOWABLE))
    if wrong:
        raise UnknownsError(f"known: {', '.join(wrong)}; choose from {', '.join(KNOWABLE)}")
    return Unknowns(tuple(params), 0 if "stations" in known else n_stations, 0 if "points" in known else n_points)
