import numpy as np
import pytest

from calib.cell import load_cell
from calib.doe import design_for_cell, random_feasible_poses
from calib.params import irreducible_params
from calib.poses import random_poses
from campaign.engine.runner import Live
from campaign.session.session import measured_keys
from mocks.cell import World
from mocks.inproc import InprocCellIO, InprocRobot, InprocTracker, SimOperator
from mocks.synth import simulate_campaign
from mocks.twin import Twin


@pytest.fixture(scope="session")
def kr270():
    return load_cell("kr270")


def kr270_campaign(cell, seed: int, n_poses: int = 30, noise_free: bool = False, **twin_kw):
    """A paper-like campaign: random feasible poses, 3 points, 2 stations, AT901-like noise (twin defaults)."""
    twin = Twin(cell, seed=seed, **twin_kw)
    poses = np.degrees(random_poses(cell, n_poses, np.random.default_rng(seed)))
    return twin, simulate_campaign(twin, poses, noise_free=noise_free)


def truth_of(twin, params):
    return np.array([twin.true_dev[twin.params.index(p)] for p in params])


@pytest.fixture(scope="session")
def kr270_params(kr270):
    return irreducible_params(kr270.chain)[0]


def feasible_plan(cell, n_poses: int, seed: int, repeat: int) -> dict:
    """A campaign plan (plan.json form) of n random poses satisfying limits, box and visibility."""

    poses = np.degrees(random_feasible_poses(design_for_cell(cell, []), n_poses, np.random.default_rng(seed)))
    return {"poses_deg": poses.round(4).tolist(), "repeat": repeat}


def inproc_live(cell, seed: int = 3, store=None, operator=None):
    """(world, Live) of the twin's cell on the in-process doubles; with `store`, the world knows the
    measurements the session holds (a resume sees the noise an uninterrupted run would)."""

    world = World(Twin(cell, seed=seed))
    if store is not None:
        world.restore_counts(measured_keys(store))
    return world, Live(InprocTracker(world), InprocRobot(world), operator or SimOperator(world), world.clock,
                       InprocCellIO(world))  # fmt: skip


def before_call(obj, name: str, n: int, action) -> None:
    """Make obj.name run `action()` just before its n-th call (fault injection at a chosen moment)."""
    original, calls = getattr(obj, name), []

    def wrapped(*args, **kw):
        calls.append(1)
        if len(calls) == n:
            action()
        return original(*args, **kw)

    setattr(obj, name, wrapped)
