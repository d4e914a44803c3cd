"""`simulate` on typed options: a measurement table of the digital twin (the one job that imports mocks), the
hidden effects a simulated campaign is given, and the twin's true parameters."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from trackcal.calib.diagnose.extensions import CAUSES
from trackcal.calib.doe.design import DesignError
from trackcal.calib.doe.poses import random_poses
from trackcal.calib.io.files import write_json
from trackcal.calib.io.table import MeasurementTable, write_table
from trackcal.calib.model.cell import Cell, load_cell
from trackcal.campaign.errors import InputError, OptionError
from trackcal.campaign.jobs.limits import check_memory, check_table_rows
from trackcal.mocks.twin import Twin, simulate_campaign


def parse_effects(items: list[str] | None) -> dict[str, float]:
    """Hidden effects NAME[:MAGNITUDE_MM] (the `effect` option, repeatable) as {cause: mm}; 0.05 mm by default."""
    out = {}
    for item in items or []:
        name, _, mag = item.partition(":")
        if name not in CAUSES:
            raise OptionError(
                "{0} {item}: unknown effect; choose from {causes}", "effect", item=item, causes=", ".join(CAUSES)
            )
        try:
            out[name] = float(mag) if mag else 0.05
        except ValueError:
            raise OptionError("{0} {item}: the magnitude must be a number of mm", "effect", item=item) from None
        if not out[name] > 0:
            raise OptionError("{0} {item}: the magnitude must be positive", "effect", item=item)
    return out


# Peak memory of `trackcal simulate` per pose, pass, station and reference point: 2.6 KiB per pose for the
# KR-270's 2 stations x 3 points (peak RSS 69.4 MB at 1000 poses, 92.7 MB at 10,000, one pass; 300 poses x 10
# passes cost less per pass, 1.5 KiB). The 4 candidate poses drawn per pose alone are 192 bytes.
SIMULATE_BYTES_PER_PAIR = 2600 / 6


def check_simulate_size(cell: Cell, opts: SimulateOptions) -> None:
    """Refuse a campaign the machine cannot hold, before drawing a pose."""
    pairs = max(1, len(cell.stations)) * len(cell.tool_points)
    rows = opts.poses * opts.repeat * pairs  # at most: a reflector a station cannot see is not measured
    if opts.repeat > 1 and opts.repeat >= opts.poses:  # the limit is named on the larger of the two counts
        check_memory(
            "repeat", opts.repeat, lambda k: opts.poses * k * pairs * SIMULATE_BYTES_PER_PAIR, "pass over the poses"
        )
        check_table_rows("repeat", opts.repeat, rows, cell.chain.dof, "passes")
    check_memory("poses", opts.poses, lambda n: n * opts.repeat * pairs * SIMULATE_BYTES_PER_PAIR, "pose")
    check_table_rows("poses", opts.poses, rows, cell.chain.dof, "poses")


@dataclass(frozen=True)
class SimulateOptions:
    """What `trackcal simulate` is asked."""

    cell: str  # cell name or path
    out: str | None = None  # the table to write; None: not written
    poses: int = 30
    seed: int = 1
    repeat: int = 1
    noise_free: bool = False
    effects: dict[str, float] = field(default_factory=dict)  # cause -> magnitude (mm), `parse_effects`
    truth: str | None = None  # the twin's truth (JSON, `write_truth`) to write; None: not written


def simulate(opts: SimulateOptions) -> tuple[Cell, Twin, MeasurementTable]:
    """A table of `opts.poses` random feasible poses measured by the twin of `opts.seed` (written to opts.out)."""
    cell = load_cell(opts.cell)
    if opts.poses < 1 or opts.repeat < 1:
        raise OptionError("{0} and {1} must be at least 1", "poses", "repeat")
    check_simulate_size(cell, opts)
    try:
        poses = np.degrees(random_poses(cell, opts.poses, np.random.default_rng(opts.seed)))
    except DesignError as exc:
        raise InputError(str(exc)) from None
    twin = Twin(cell, seed=opts.seed, effects=opts.effects)
    if opts.truth:
        write_json(opts.truth, twin.truth(), InputError)
    table = simulate_campaign(twin, poses, repeat=opts.repeat, noise_free=opts.noise_free)
    if opts.out:
        write_table(table, opts.out)
    return cell, twin, table


def write_truth(path: str | Path, cell: Cell, seed: int, effects: dict[str, float]) -> None:
    """The truth of the twin of `cell`, `seed` and hidden `effects` (mocks.twin.Twin.truth: what `simulate --truth`
    and `run --sim --truth` write), atomically; a file that cannot be written is an InputError."""
    write_json(path, Twin(cell, seed=seed, effects=effects).truth(), InputError)


def test_pose_miss_mm(cell: Cell, seed: int, figure: dict | None) -> float | None:
    """How far a model's TCP at the test pose (model.json's `test_pose`, calib.tcp_figure) is from where the twin of
    `seed` really has it (its truth file's centroid, the same station's frame): the figure the model states,
    checked against a truth the model did not compute. None without a test pose."""
    truth = Twin(cell, seed=seed).truth()["test_pose"]
    if truth is None or not figure or figure.get("station") not in truth["centroid_mm"]:
        return None
    return float(np.linalg.norm(np.subtract(figure["tcp_mm"], truth["centroid_mm"][figure["station"]])))


def twin_truth(cell: Cell, seed: int) -> dict[str, float]:
    """The twin's true parameter deviations in boundary units (mm, deg): those of its truth file."""
    return {name: p["value"] for name, p in Twin(cell, seed=seed).truth()["parameters"].items()}
