"""calib.diagnose.structure: the residual-structure tests' figures do not depend on rounding."""

import numpy as np
import pytest

from trackcal.calib.diagnose import fits, structure
from trackcal.calib.doe.poses import random_poses
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.identify.solver import identify
from trackcal.calib.model.cell import load_cell
from trackcal.calib.model.params import irreducible_params
from trackcal.mocks.twin import Twin, simulate_campaign

CELL = load_cell("kr270")


def test_end_frame_test_does_not_count_rounding_as_rank(monkeypatch):
    """The end-frame test's F statistic is the same when the fit's Jacobian moves by 1e-15 of its entries (a sum taken
    in another order moves it so). The geometric model's columns that the per-pose end frames take whole (an
    end-frame motion at every pose) are left as rounding by the projection; scaled by their own norm afterwards
    (before issue 41) that rounding counted as rank (18 columns here), and this change of 1e-15 moved the p-value of
    this 40-pose twin campaign between 0.007 and 0.042, across a 5 % level."""
    twin = Twin(CELL, seed=2)
    table = simulate_campaign(twin, np.degrees(random_poses(CELL, 40, np.random.default_rng(2))))
    params = irreducible_params(CELL.chain)[0]
    geo = identify(CELL.chain, table, CELL.tool_points, params, noise=TrackerNoise())
    ctx = fits.context(CELL.chain, table, params, TrackerNoise(), geo, ())
    fit = fits.whole_fit(ctx, ())
    base = structure.pose_frame_test(ctx, fit, table)
    exact = fit.rows
    for seed in range(3):
        rng = np.random.default_rng(seed)

        def perturbed(rows, rng=rng):
            r, j = exact(rows)
            return r, j * (1.0 + 1e-15 * rng.standard_normal(j.shape))

        monkeypatch.setattr(fit, "rows", perturbed)
        moved = structure.pose_frame_test(ctx, fit, table)
        assert moved["dof"] == base["dof"]
        assert moved["pvalue"] == pytest.approx(base["pvalue"], rel=1e-6)
