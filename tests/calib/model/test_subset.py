"""calib.subset: the largest identifiable subset of the irreducible set for the reference points at hand."""

import numpy as np

from trackcal.calib.model.cell import load_robot
from trackcal.calib.model.identifiability import identification_jacobian, numerical_rank, random_configuration
from trackcal.calib.model.params import irreducible_params
from trackcal.calib.model.subset import identifiable_subset


def _q(chain, seed=0, m=40):
    return random_configuration(chain, m, np.random.default_rng(seed))


def test_kr270_three_points_keep_the_whole_irreducible_set(kr270, kr270_params):
    # paper section 3 / eq. (6): with three non-collinear points the 18 parameters are identifiable
    kept, dropped = identifiable_subset(kr270.chain, kr270_params, _q(kr270.chain), kr270.tool_points)
    assert kept == kr270_params
    assert dropped == []


def test_kr270_one_point_on_the_flange_axis_loses_the_last_wrist_parameters(kr270, kr270_params):
    # A single reflector on the A6 axis (x of the wrist frame): A6 no longer moves it, the orientation of the
    # last frame about that point is invisible, and two link-5 parameters merge with dq5 / the link-4 ones.
    point = {"F": np.array([277.0, 0.0, 0.0])}
    q = _q(kr270.chain)
    kept, dropped = identifiable_subset(kr270.chain, kr270_params, q, point)
    assert [p.name for p, _ in dropped] == ["pz5", "phiz5"]
    assert [p for p in kr270_params if p not in kept] == [p for p, _ in dropped]
    assert all("1 reference point" in why for _, why in dropped)
    tool = np.array(list(point.values()))
    j = identification_jacobian(kr270.chain, kept, q, tool)
    assert numerical_rank(j) == j.shape[1]  # the kept set is identifiable
    for p, _ in dropped:  # and it is maximal: any dropped parameter added back loses rank
        j = identification_jacobian(kr270.chain, kept + [p], q, tool)
        assert numerical_rank(j) < j.shape[1]


def test_kr270_one_point_off_the_axis_still_sees_the_wrist(kr270, kr270_params):
    # Off the A6 axis the point turns with A6 and reveals the last frame's orientation: nothing is lost
    kept, dropped = identifiable_subset(kr270.chain, kr270_params, _q(kr270.chain), {"P1": kr270.tool_points["P1"]})
    assert kept == kr270_params and dropped == []


def test_ur10_tmac_on_the_wrist_3_axis():
    chain, _ = load_robot("ur10")
    irr, _ = irreducible_params(chain)
    kept, dropped = identifiable_subset(chain, irr, _q(chain, 1, 60), {"TMAC": [0.0, 0.0, 109.0]})
    assert len(irr) == 18 and len(kept) == 16
    assert {p.name for p, _ in dropped} == {"px5", "phix5"}
