"""Issue 35: the plan search, cheaper and no worse. The exchange finds each swap by branch and bound (the same swap as
scoring every candidate), the refinement keeps what it gained when one pose ends infeasible, and the default search
(4 starts, each exchanged and refined) reaches the rho0 of a search four times its size."""

import numpy as np
import pytest

from trackcal.calib.doe.design import (
    _best_rho0_swap,
    _rho0_swaps,
    design_for_cell,
    exchange,
    optimize_plan,
    random_feasible_poses,
    refine,
)
from trackcal.calib.identify.unknowns import campaign_params
from trackcal.campaign.jobs.plan import PlanOptions, build_design, plan_size


@pytest.fixture(scope="module")
def campaign_design(kr270):
    return design_for_cell(kr270, campaign_params(kr270.chain), sigma_mm=0.01)


@pytest.mark.parametrize("seed", [3, 4, 5])
def test_branch_and_bound_swap_is_the_best_swap(campaign_design, seed):
    """The bounded search returns the argmin of rho0 over every allowed candidate (the Woodbury values of all)."""
    d = campaign_design
    pool = random_feasible_poses(d, 300, np.random.default_rng(seed))
    infos, bs = d.pose_information(pool), d.pose_factors(pool) / d.scale
    rng = np.random.default_rng(seed)
    plan = rng.choice(len(pool), 14, replace=False)
    rest = infos[plan[1:]].sum(axis=0)
    allowed = np.ones(len(pool), dtype=bool)
    allowed[plan] = False
    every = _rho0_swaps(d, rest, bs)
    every[~allowed] = np.inf
    assert _best_rho0_swap(d, rest, bs, allowed) == int(np.argmin(every))


@pytest.mark.slow
def test_refinement_keeps_its_gain_at_24_configurations(kr270):
    """At 24 configurations the solver's last iterate often leaves one pose at a station's cone edge or outside the
    box; the plan was then dropped whole and the exchange's plan kept (3 of the 4 best screened starts here). Each
    pose's feasibility is its own: the refined plan keeps every feasible pose and rho0 drops well below the
    exchange's (SLSQP moves poses onto the box and the cones' edges, where the pool's random poses seldom lie)."""
    d = build_design(kr270, PlanOptions())
    rng = np.random.default_rng(0)
    pool = random_feasible_poses(d, 2000, rng)
    infos, factors = d.pose_information(pool), d.pose_factors(pool)
    screened = np.array([rng.choice(len(pool), 24, replace=False) for _ in range(1000)])
    scores = d.criterion_values(infos[screened].sum(axis=1), "rho0")
    start = screened[np.argsort(scores)[1]]
    q = pool[exchange(d, infos, start, "rho0", factors=factors)]
    out = refine(d, q, "rho0")
    assert d.feasible(out).all()
    assert d.rho0(out) < 0.95 * d.rho0(q)


@pytest.mark.slow
def test_the_default_search_is_as_good_as_four_times_the_starts(kr270):
    """The default plan (KR-270, its 13 configurations, 1000 screened, 4 starts) within 1 % of the best of 16 starts
    each exchanged and refined (a superset of the search before, which refined the best 2 of 16 exchanged)."""
    d = build_design(kr270, PlanOptions())
    m, repeat, _ = plan_size(d, None, None)
    default = optimize_plan(d, m, repeat)
    larger = optimize_plan(d, m, repeat, refined=16)
    assert default.criteria["rho0_mm"] <= 1.01 * larger.criteria["rho0_mm"]
