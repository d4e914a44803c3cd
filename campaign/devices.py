"""The devices of a campaign: the simulated cell, or the real one from a hardware config."""

from __future__ import annotations

from calib.cell import Cell

from .runner import Live
from .store import SessionStore


def sim_live(cell: Cell, seed: int, store: SessionStore | None = None, effects: dict[str, float] | None = None,
             speed: float | None = None):  # fmt: skip
    """The digital twin's cell. On resume the world learns which measurements the session already holds,
    so that every measurement keeps its noise (a pure function of the seed and the step's identity).
    `speed`: simulated seconds per real second (None: as fast as the machine goes)."""
    from mocks.clock import VirtualClock
    from mocks.inproc import InprocCellIO, InprocRobot, InprocTracker, SimOperator
    from mocks.twin import Twin
    from mocks.world import World

    clock = VirtualClock(real_fraction=0.0 if not speed else 1.0 / speed)
    world = World(Twin(cell, seed=seed, effects=effects or {}), clock)
    if store is not None:
        world.restore_counts([(e.data["station"], e.data["point"], tuple(e.data["q_deg"]))
                              for e in store.events("measurement")])  # fmt: skip
    return world, Live(InprocTracker(world), InprocRobot(world), SimOperator(world), world.clock, InprocCellIO(world))
