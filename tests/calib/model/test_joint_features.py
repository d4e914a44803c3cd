"""issue 41: joint features in per-joint block form (`JointFeatures`). Every parameter of a joint feature moves one
joint, so the block form holds N e values where the dense (N, n, e) array held N n e, and what is computed from it
is what the dense array gave, bit for bit (model.json and verdicts of diagnose unchanged)."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from trackcal.calib.diagnose.joint_map import harmonic_names, map_extension, map_features
from trackcal.calib.doe.poses import random_poses
from trackcal.calib.model.cell import load_cell
from trackcal.calib.model.extension import JointFeatures, combine

F64 = 8  # bytes of a float64


def held_bytes(feats) -> int:
    """Bytes of the arrays an extension's joint features hold (an array, or the block form's arrays)."""
    if isinstance(feats, np.ndarray):
        return feats.nbytes
    return sum(v.nbytes for v in vars(feats).values() if isinstance(v, np.ndarray))


def test_a_joint_error_map_holds_one_value_per_row_and_coefficient():
    """The KR-270's six joints, harmonics 1..16: 192 coefficients, each moving its own joint. Before issue 41 the
    features were (N, 6, 192) float64, six times the values; the block form holds the values and each coefficient's
    joint (e integers)."""
    cell = load_cell("kr270")
    q = random_poses(cell, 300, np.random.default_rng(1))
    names = [nm for j in range(cell.chain.dof) for nm in harmonic_names(j, 16)]
    ext = map_extension(q, names=names)
    values = len(q) * len(names) * F64
    assert held_bytes(ext.joint_features) <= values + len(names) * F64
    assert held_bytes(combine([ext, ext], cause="cyclic_error").joint_features) <= 2 * (values + len(names) * F64)


def test_the_block_form_gives_back_the_dense_features():
    cell = load_cell("kr270")
    q = random_poses(cell, 50, np.random.default_rng(2))
    names = [nm for j in range(cell.chain.dof) for nm in harmonic_names(j, 4)]
    ext = map_extension(q, names=names)
    assert np.array_equal(ext.joint_features.dense(), map_features(q, names, ext.meta["arcs"]))


@st.composite
def single_joint_features(draw):
    """Dense features (N, n, e) where every parameter moves one joint, and theta."""
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    n_rows = draw(st.integers(1, 192))
    n, e = draw(st.integers(1, 7)), draw(st.integers(0, 40))
    joint = rng.integers(0, n, e)
    dense = np.zeros((n_rows, n, e))
    dense[:, joint, np.arange(e)] = rng.standard_normal((n_rows, e)) * 10.0 ** rng.integers(-6, 3, e)
    return dense, rng.standard_normal(e) * 1e-4


@settings(max_examples=40, deadline=None)
@given(single_joint_features())
def test_offsets_of_the_block_form_are_the_dense_einsum(case):
    """Phi theta, each joint's run of parameters summed on its own, is the einsum of the dense array to rounding: the
    same terms in another order, so at most (e - 1) eps times the sum of their magnitudes (Higham, Accuracy and
    Stability of Numerical Algorithms, 2002, eq. 3.5)."""
    dense, theta = case
    jf = JointFeatures.of(dense)
    assert np.array_equal(jf.dense(), dense)
    bound = max(len(theta) - 1, 0) * np.finfo(float).eps * np.einsum("rje,e->rj", np.abs(dense), np.abs(theta))
    assert np.all(np.abs(jf.offsets(theta) - np.einsum("rje,e->rj", dense, theta)) <= bound)
    # several sets of values at once (the held-out map's coefficients at every ridge): each set's own offsets
    thetas = np.stack([theta, -2.0 * theta], axis=1)
    assert np.all(np.abs(jf.offsets(thetas) - np.einsum("rje,ek->rjk", dense, thetas)) <= 2.0 * bound[:, :, None])
    rows = np.arange(0, len(dense), 3)
    assert np.array_equal(jf.take(rows).dense(), dense[rows])
    assert np.array_equal(jf.moves(), np.abs(dense).max(axis=0, initial=0.0) > 0)


@settings(max_examples=40, deadline=None)
@given(single_joint_features())
def test_lever_columns_of_the_block_form_are_the_dense_product(case):
    """The Jacobian's columns through the joint angles, lever (N, 3, n) @ Phi row by row: each parameter's column is
    its joint's lever times its feature, the product the dense array's matmul formed (row by row, as the solver did
    before issue 41), to the last bit."""
    dense, _ = case
    jf = JointFeatures.of(dense)
    lever = np.random.default_rng(len(dense)).standard_normal((len(dense), 3, dense.shape[1])) * 1e3
    out = np.full((len(dense), 3, dense.shape[2]), np.nan)
    jf.lever_columns(lever, out)
    assert np.array_equal(out, np.matmul(lever, jf.dense()))


@settings(max_examples=40, deadline=None)
@given(single_joint_features(), st.integers(0, 5))
def test_gram_and_cross_from_the_levers_are_the_products_of_the_columns(case, n_other):
    """C^T C and O^T C of the columns C = lever_columns(lever) formed from each row's lever (`JointFeatures.gram`,
    `cross`: N e^2 where the columns take 3 N e^2) are the dense products, to rounding: the same sums in another
    order (relative to the product of the columns' norms, the scale of each entry's rounding)."""
    dense, _ = case
    jf = JointFeatures.of(dense)
    rng = np.random.default_rng(len(dense))
    lever = rng.standard_normal((len(dense), 3, dense.shape[1])) * 1e3
    other = rng.standard_normal((len(dense), 3, n_other))
    cols = np.empty((len(dense), 3, dense.shape[2]))
    jf.lever_columns(lever, cols)
    c, o = cols.reshape(3 * len(dense), dense.shape[2]), other.reshape(3 * len(dense), n_other)
    norm_c, norm_o = np.linalg.norm(c, axis=0), np.linalg.norm(o, axis=0)
    assert np.all(np.abs(jf.gram(lever) - c.T @ c) <= 1e-13 * np.outer(norm_c, norm_c))
    assert np.all(np.abs(jf.cross(lever, other) - o.T @ c) <= 1e-13 * np.outer(norm_o, norm_c))
