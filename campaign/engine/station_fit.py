"""The residuals of each station block once it is measured (issue 22: the operator's page plots them).

A station block is the run of the plan's measurement steps taken from one tracker set-up. When its last step is
done, `StationFits` (a subscriber of the engine's documents, the last one) places the station on the block's
measurements with the nominal model held fixed, the fit calib's solver starts from (a Kabsch/Horn rigid fit of the
nominal reflector positions onto the measured ones: `calib.identify.solver._init_stations`, `calib.model.rigid.
kabsch`), and emits a `station_fit` document with every measurement's residual (measured minus the placed nominal
model, mm, in the station's frame): the session stores it like any document, so a page that reloads rebuilds the
plot from the session. Closed form and a few dozen points: microseconds beside a measurement.

What the residuals say: with the station placed, what is left is the nominal model's error at those poses (the
uncalibrated KR-270 of the paper misses by up to 1.31 mm, Table 9) plus the tracker's noise; a point far above the
others is a measurement to look at (wrong nest, reflector bumped) before the block is left behind.

A block with fewer than 3 measurements (its points skipped), or with collinear ones, does not place a station: its
document says why and carries no residuals. A run killed between a block's last step and its document makes the
document when the campaign is resumed (at its `start`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np

from trackcal.calib.identify.solver import residual_stats
from trackcal.calib.model.cell import Cell
from trackcal.calib.model.kinematics import Kinematics
from trackcal.calib.model.rigid import RigidError, kabsch
from trackcal.campaign.engine.documents import MeasurementDoc, StationFitDoc, StationResidual
from trackcal.campaign.engine.steps import Step, StepKind


@dataclass(frozen=True)
class Block:
    """The `index`-th station block of a plan: its station and its measurement steps (indices into the steps)."""

    index: int
    station: str
    steps: tuple[int, ...]


def station_blocks(steps: list[Step]) -> list[Block]:
    """The plan's station blocks in order: consecutive measurement steps from the same station."""
    runs: list[tuple[str, list[int]]] = []
    for i, s in enumerate(steps):
        if s.kind != StepKind.MEASURE:
            continue
        if not runs or runs[-1][0] != s.station:
            runs.append((s.station, []))
        runs[-1][1].append(i)
    return [Block(k, station, tuple(idx)) for k, (station, idx) in enumerate(runs)]


def fit_block(cell: Cell, block: Block, measured: dict[int, MeasurementDoc]) -> StationFitDoc:
    """The data of the block's `station_fit` document; `measured`: step -> the data of its measurement."""
    rows = [i for i in block.steps if i in measured and measured[i]["point"] in cell.tool_points]
    head = {"block": block.index, "station": block.station, "planned": len(block.steps), "measured": len(rows)}
    if len(rows) < 3:
        return StationFitDoc(
            **head, residuals=[], note=f"{len(rows)} measurement(s): at least 3 are needed to place the station"
        )
    data = [measured[i] for i in rows]
    q = np.radians(np.array([d["q_deg"] for d in data], dtype=float))
    tool = np.array([cell.tool_points[d["point"]] for d in data], dtype=float)
    nominal = Kinematics(cell.chain, []).points(q, tool)  # the base frame
    xyz = np.array([d["xyz_mm"] for d in data], dtype=float)  # the station's frame
    try:
        r, t = kabsch(nominal, xyz)
    except (RigidError, np.linalg.LinAlgError) as exc:  # collinear points; an SVD that does not converge
        return StationFitDoc(**head, residuals=[], note=str(exc))
    res = xyz - (nominal @ r.T + t)
    stats = residual_stats(res)
    return StationFitDoc(
        **head,
        rms_mm=round(stats["dist_rms_mm"], 4),
        max_mm=round(stats["dist_max_mm"], 4),
        position_mm=[round(float(v), 3) for v in -r.T @ t],  # the station's origin in the robot's base frame
        residuals=[
            StationResidual(step=i, pose=d["pose"], point=d["point"], d_mm=[round(float(v), 4) for v in e])
            for i, d, e in zip(rows, data, res, strict=True)
        ],
    )


class StationFits:
    """The subscriber: `emit` is the run's (RunContext.emit), so the document reaches the store and every other
    subscriber; it is the last subscriber, so every one of them has heard the document that ended the block
    first. `measured` (step, data) and `fitted` (block indices) are what the session already holds; `done`, its
    steps done (a block finished before a kill, its document not made yet, gets it at the next `start`)."""

    def __init__(
        self,
        cell: Cell,
        steps: list[Step],
        emit: Callable[..., None],
        measured: Iterable[tuple[int, MeasurementDoc]] = (),
        fitted: Iterable[int] = (),
        done: Iterable[int] = (),
    ) -> None:
        self.cell, self.emit = cell, emit
        self.blocks = station_blocks(steps)
        self.ending = {b.steps[-1]: b for b in self.blocks}
        self.measured = dict(measured)
        self.fitted = set(fitted)
        self.done = set(done)

    def __call__(self, doc) -> None:
        if doc.name == "measurement":
            self.measured[doc.step] = doc.data
        elif doc.name == "step_done" and doc.step in self.ending:
            self._fit(self.ending[doc.step], doc.t)
        elif doc.name == "start":
            for b in self.blocks:
                if b.steps[-1] in self.done:
                    self._fit(b, doc.t)

    def _fit(self, block: Block, t: float) -> None:
        if block.index in self.fitted:
            return
        self.fitted.add(block.index)
        self.emit("station_fit", fit_block(self.cell, block, self.measured), block.steps[-1], t)
