import numpy as np
import pytest

from calib.cell import load_cell
from calib.params import irreducible_params
from calib.poses import random_poses
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
