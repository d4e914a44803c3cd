"""The complete and irreducible parameter set (paper section 3) and its numerical verification."""

import numpy as np
import pytest

from tests.helpers import ROOT
from trackcal.calib.model.cell import load_robot
from trackcal.calib.model.chain import ChainError, chain_from_dict, chain_from_urdf
from trackcal.calib.model.identifiability import identification_jacobian, numerical_rank, random_configuration
from trackcal.calib.model.params import complete_params, irreducible_params

# Paper eq. (6), in this order.
PAPER_EQ6 = [
    "px1",
    "py1",
    "phix1",
    "dq2",
    "px2",
    "phix2",
    "phiz2",
    "dq3",
    "px3",
    "pz3",
    "phiz3",
    "dq4",
    "py4",
    "pz4",
    "phiz4",
    "dq5",
    "pz5",
    "phiz5",
]

# Paper section 3: eliminated from the redundant model (4) by the rules for consecutive joints.
PAPER_ELIMINATED_BY_RULES = {"phiy1", "pz2", "phix3", "phiy4", "px5", "phix5"}

UR_LIKE_URDF = ROOT / "tests" / "data" / "ur_like_dh.urdf"

TOOL = np.array([[277.0, -47, -94], [276, -48, 94], [278, 104, -2]])


def assert_irreducible(chain, seed=0):
    """Full column rank with the kept set; rank lost when any eliminated parameter is added back."""
    kept, eliminated = irreducible_params(chain)
    q = random_configuration(chain, 40, np.random.default_rng(seed))
    j = identification_jacobian(chain, kept, q, TOOL)
    assert numerical_rank(j) == j.shape[1]
    for e in eliminated:
        j_plus = identification_jacobian(chain, kept + [e.param], q, TOOL)
        assert numerical_rank(j_plus) == j_plus.shape[1] - 1, e.param.name
    return kept, eliminated


def test_kr270_is_the_papers_eq6_set(kr270):
    kept, eliminated = irreducible_params(kr270.chain)
    assert [p.name for p in kept] == PAPER_EQ6
    assert {e.param.name for e in eliminated} >= PAPER_ELIMINATED_BY_RULES
    # 30 complete parameters = 18 kept + dq1 (base) + dq6 and 4 last-link ones (tool) + 6 by the rules
    assert len(complete_params(kr270.chain)) == 30 and len(eliminated) == 12


def test_kr270_numerically_irreducible(kr270):
    assert_irreducible(kr270.chain)


def test_ur_like_yaml_three_parallel_axes(tmp_path):
    chain, _ = load_robot("ur-like")
    kept, eliminated = assert_irreducible(chain, seed=1)
    # 6R robot, position-only with free base and tool: 30 - 6 - 6 = 18 (Zhuang's count, paper footnote 1)
    assert len(kept) == 18
    names = {e.param.name for e in eliminated}
    # the two parallel pairs (2,3) and (3,4): the translation across the common normal goes
    assert {"pz2", "pz3"} <= names


def test_urdf_dh_frames_through_pinocchio(tmp_path):
    chain = chain_from_urdf(str(UR_LIKE_URDF))
    assert chain.dof == 6 and all(j.axis == 2 for j in chain.joints)
    kept, _ = assert_irreducible(chain, seed=2)
    assert len(kept) == 18


def test_non_aligned_axes_get_their_parameters():
    # issue 23: axes that are neither parallel nor perpendicular were refused; tests/test_chains.py checks the set
    doc = {"joints": [{"axis": "z", "link_mm": [100, 0, 0], "link_rpy_deg": [30, 0, 0]}, {"axis": "y"}]}
    kept, _ = irreducible_params(chain_from_dict(doc))
    assert len(kept) == 2  # 4n - 6 with n = 2: the distance and the angle between the two axes


def test_bad_axis_is_a_clear_error():
    with pytest.raises(ChainError, match=r"joints\[0\]: axis must be x, y or z"):
        chain_from_dict({"joints": [{"axis": "w"}]})


def test_coincident_parallel_axes_are_refused():
    doc = {"joints": [{"axis": "z"}, {"axis": "z"}, {"axis": "y"}]}
    with pytest.raises(ChainError, match="coincide"):
        irreducible_params(chain_from_dict(doc))
