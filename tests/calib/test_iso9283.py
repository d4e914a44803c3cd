"""ISO 9283:1998 figures (calib.iso9283) and the test cube (calib.doe.iso_cube).

The hand-computed examples write the standard's formulas out with numbers chosen so the arithmetic is done by hand
in the comments; the statistical checks use clusters whose offset and spread are known."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from trackcal.calib.doe.iso_cube import CYCLE_ORDER, CubeError, IsoCube, largest_cube
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.iso9283 import (
    Figure,
    IsoError,
    distance_accuracy,
    drift,
    multidirectional_variation,
    orientation_accuracy,
    orientation_repeatability,
    pose_accuracy,
    pose_repeatability,
)

# Four attained positions around the barycentre (2, 0, 0), commanded at the origin:
# offsets from the barycentre (+-1, 0, 0) and (0, +-3, 0), so l_j = 1, 1, 3, 3.
CROSS = np.array([[3.0, 0, 0], [1.0, 0, 0], [2.0, 3, 0], [2.0, -3, 0]])


def test_pose_accuracy_by_hand():
    # x_bar = (2, 0, 0), c = 0: AP_P = 2, (AP_x, AP_y, AP_z) = (2, 0, 0)  (7.2)
    ap, offset = pose_accuracy(CROSS, [0, 0, 0])
    assert ap.value == pytest.approx(2.0, abs=1e-12)
    assert offset == pytest.approx([2.0, 0.0, 0.0], abs=1e-12)
    assert ap.clause.endswith("7.2")


def test_pose_repeatability_by_hand():
    # l = 1, 1, 3, 3: l_bar = 2; S_l = sqrt((1 + 1 + 1 + 1) / 3) = sqrt(4/3) = 1.1547005;
    # RP_l = 2 + 3 * 1.1547005 = 5.4641016  (7.2)
    rp, lbar, s = pose_repeatability(CROSS)
    assert lbar == pytest.approx(2.0, abs=1e-12)
    assert s == pytest.approx(np.sqrt(4.0 / 3.0), abs=1e-12)
    assert rp.value == pytest.approx(2.0 + 3.0 * np.sqrt(4.0 / 3.0), abs=1e-12)


def test_distance_accuracy_and_repeatability_by_hand():
    # Commanded poses 10 mm apart along x; attained distances D_j = 10, 12, 11, 11:
    # D_bar = 11, AD_P = 11 - 10 = 1; S_D = sqrt((1 + 1 + 0 + 0) / 3) = 0.8164966, RD = 3 S_D = 2.4494897  (7.3)
    x2 = np.zeros((4, 3))
    x1 = np.array([[10.0, 0, 0], [0, 12.0, 0], [0, 0, 11.0], [-11.0, 0, 0]])
    ad, rd = distance_accuracy(x1, x2, [10, 0, 0], [0, 0, 0])
    assert ad.value == pytest.approx(1.0, abs=1e-12)
    assert rd.value == pytest.approx(3.0 * np.sqrt(2.0 / 3.0), abs=1e-12)


def test_multidirectional_variation_by_hand():
    # Barycentres of three approaches: (0,0,0), (0.03,0,0), (0,0.04,0); the largest distance is between the
    # second and the third: sqrt(0.03^2 + 0.04^2) = 0.05  (7.2)
    a = np.zeros((3, 3))
    b = a + [0.03, 0, 0]
    c = a + [0, 0.04, 0]
    assert multidirectional_variation([a, b, c]).value == pytest.approx(0.05, abs=1e-12)
    with pytest.raises(IsoError):
        multidirectional_variation([a])


def test_orientation_figures_by_hand_and_across_180():
    # Angles about the commanded (179, 0, 0): attained 179.5 and -179.5 (= 180.5) average to 180 (not 0):
    # AP_a = 180 - 179 = 1 deg; S_a of (0.5, 1.5) about their mean = 0.7071 deg, RP_a = 2.1213 deg  (7.2)
    att = np.array([[179.5, 1.0, 0.0], [-179.5, 3.0, 0.0]])
    assert orientation_accuracy(att, [179.0, 0.0, 0.0]) == pytest.approx([1.0, 2.0, 0.0], abs=1e-9)
    assert orientation_repeatability(att) == pytest.approx([3 * np.sqrt(0.5), 3 * np.sqrt(2.0), 0.0], abs=1e-9)


def test_drift_by_hand():
    d = drift(Figure(0.30, 0.03, "7.2"), Figure(0.22, 0.04, "7.2"))
    assert d.value == pytest.approx(0.08, abs=1e-12)
    assert d.u95 == pytest.approx(0.05, abs=1e-12)  # sqrt(0.03^2 + 0.04^2)


def _fd_u95(fn, points: np.ndarray, sigma: float, h: float = 1e-6) -> float:
    """2 sigma |grad f| with the gradient by central differences: the propagation for Sigma_j = sigma^2 I."""
    g = np.zeros_like(points)
    for idx in np.ndindex(points.shape):
        p, m = points.copy(), points.copy()
        p[idx] += h
        m[idx] -= h
        g[idx] = (fn(p) - fn(m)) / (2 * h)
    return 2.0 * sigma * float(np.linalg.norm(g))


@given(seed=st.integers(0, 2**31 - 1), n=st.integers(3, 12))
def test_uncertainties_are_the_propagated_gradients(seed, n):
    """Each figure's U equals 2 sqrt(sum g_j^T Sigma_j g_j) with g from finite differences (Sigma_j = sigma^2 I)."""
    rng = np.random.default_rng(seed)
    x = rng.normal(0.0, 0.05, (n, 3)) + [800.0, 100.0, 1200.0]
    x2 = rng.normal(0.0, 0.05, (n, 3)) + [800.0, 400.0, 1200.0]
    c = np.array([800.02, 100.01, 1199.97])
    sig, cov = 0.01, np.eye(3) * 0.01**2
    assert pose_accuracy(x, c, cov)[0].u95 == pytest.approx(
        _fd_u95(lambda p: pose_accuracy(p, c)[0].value, x, sig), rel=1e-5
    )
    assert pose_repeatability(x, cov)[0].u95 == pytest.approx(
        _fd_u95(lambda p: pose_repeatability(p)[0].value, x, sig), rel=1e-5
    )
    both = np.vstack([x, x2])
    ad, rd = distance_accuracy(x, x2, c, c + [0, 300, 0], cov, cov)
    assert ad.u95 == pytest.approx(
        _fd_u95(lambda p: distance_accuracy(p[:n], p[n:], c, c + [0, 300, 0])[0].value, both, sig), rel=1e-5
    )
    assert rd.u95 == pytest.approx(
        _fd_u95(lambda p: distance_accuracy(p[:n], p[n:], c, c + [0, 300, 0])[1].value, both, sig), rel=1e-5
    )


def test_accuracy_recovers_a_known_offset_within_its_uncertainty():
    """A perfectly repeatable robot whose attained point sits `m` from the commanded one, measured 30 times by the
    AT901 model at 3 m: AP_P lies within its U (k = 2) of |m| in about 95 % of tests. Over 400 tests the share is
    binomial(400, 0.954): below 0.92 happens with probability < 1e-3."""
    rng = np.random.default_rng(9283)
    noise = TrackerNoise()
    c = np.array([2000.0, 1500.0, 1200.0])
    m = np.array([0.12, -0.08, 0.05])  # |m| = 0.153 mm, far above the noise of a 30-point mean (~2 µm)
    cov = noise.covariance(np.tile(c + m, (30, 1)))
    inside = 0
    for _ in range(400):
        x = c + m + noise.sample(np.tile(c + m, (30, 1)), rng)
        ap = pose_accuracy(x, c, cov)[0]
        inside += abs(ap.value - np.linalg.norm(m)) <= ap.u95
    assert inside / 400 >= 0.92


def test_repeatability_of_a_gaussian_cluster():
    """For an isotropic Gaussian scatter sigma, l_j = |x_j - x_bar| follows Maxwell's law with scale
    sigma sqrt(1 - 1/n): mean 2 sqrt(2/pi) = 1.5958 and standard deviation sqrt(3 - 8/pi) = 0.6734 in that unit,
    so RP_l -> (1.5958 + 3 * 0.6734) sigma sqrt(1 - 1/n) = 3.6160 sigma sqrt(1 - 1/n). With n = 3000 the standard
    error of l_bar is 0.6734 sigma / sqrt(3000) = 0.012 sigma; 0.06 sigma is 5 of them."""
    rng = np.random.default_rng(1)
    sigma, n = 0.02, 3000
    rp, lbar, s = pose_repeatability(rng.normal(0.0, sigma, (n, 3)) + [1000, 0, 500])
    scale = sigma * np.sqrt(1 - 1 / n)
    assert lbar == pytest.approx(2 * np.sqrt(2 / np.pi) * scale, abs=0.06 * sigma / 3)
    assert rp.value == pytest.approx((2 * np.sqrt(2 / np.pi) + 3 * np.sqrt(3 - 8 / np.pi)) * scale, abs=0.06 * sigma)


def test_repeatability_uncertainty_matches_monte_carlo():
    """The robot's attained points fixed (scatter 20 µm), the tracker's noise drawn again and again: the spread of
    RP over the draws is the propagated u (U / 2) to within the Monte Carlo's own error (200 draws: ~5 %)."""
    rng = np.random.default_rng(7)
    noise = TrackerNoise()
    true = rng.normal(0.0, 0.02, (30, 3)) + [2500.0, 0.0, 800.0]
    cov = noise.covariance(true)
    rps = [pose_repeatability(true + noise.sample(true, rng))[0].value for _ in range(200)]
    u = pose_repeatability(true, cov)[0].u95 / 2
    assert np.std(rps, ddof=1) == pytest.approx(u, rel=0.2)


def test_bad_input_is_one_error():
    with pytest.raises(IsoError, match="at least 2"):
        pose_repeatability([[1.0, 2.0, 3.0]])
    with pytest.raises(IsoError, match="finite"):
        pose_accuracy([[1.0, np.nan, 3.0]], [0, 0, 0])
    with pytest.raises(IsoError, match="cycles"):
        distance_accuracy(np.zeros((3, 3)), np.zeros((4, 3)), [0, 0, 0], [1, 0, 0])


@given(
    cx=st.floats(-2000, 2000),
    cy=st.floats(-2000, 2000),
    cz=st.floats(0, 2000),
    side=st.floats(10, 2000),
    fraction=st.floats(0.08, 0.12),
)
def test_cube_geometry(cx, cy, cz, side, fraction):
    """P1 at the centre; P2..P5 on the plane C1-C2-C7-C8, each `fraction` L from its corner on a diagonal toward the
    centre; the plane holds two opposite edges of the cube (C1-C2 and C7-C8, parallel, sqrt(2) side apart)."""
    cube = IsoCube((cx, cy, cz), side)
    p = cube.poses(fraction)
    near = cube.plane_corners()
    assert p[0] == pytest.approx([cx, cy, cz])
    L = cube.diagonal_mm
    assert np.linalg.norm(cube.corners()[6] - cube.corners()[0]) == pytest.approx(L)  # a space diagonal
    assert np.linalg.norm(p[1:] - near, axis=1) == pytest.approx([fraction * L] * 4, rel=1e-9)
    normal = np.cross(near[1] - near[0], near[3] - near[0])
    assert (p[1:] - near[0]) @ normal == pytest.approx([0.0] * 4, abs=1e-9 * side**2)
    assert np.cross(near[1] - near[0], near[2] - near[3]) == pytest.approx([0, 0, 0], abs=1e-9 * side**2)
    assert np.linalg.norm(near[3] - near[0]) == pytest.approx(np.sqrt(2) * side)
    # each pose lies on the line from its corner through the centre (a diagonal of the plane)
    for k in range(4):
        assert np.cross(p[k + 1] - near[k], p[0] - near[k]) == pytest.approx([0, 0, 0], abs=1e-9 * side**2)


def test_cycle_visits_every_pose_once_starting_at_the_centre():
    assert CYCLE_ORDER[0] == 0 and sorted(CYCLE_ORDER) == [0, 1, 2, 3, 4]


def test_largest_cube_in_a_box():
    # Box 1000 x 600 x 800 mm: the largest centred cube has the smallest extent, 600 mm, as side.
    cube = largest_cube([0, 0, 0], [1000, 600, 800])
    assert cube.side_mm == pytest.approx(600.0)
    assert cube.centre_mm == pytest.approx((500.0, 300.0, 400.0))
    # off-centre: limited by the nearest face (100 mm from x = 0)
    assert largest_cube([0, 0, 0], [1000, 600, 800], centre=[100, 300, 400]).side_mm == pytest.approx(200.0)
    with pytest.raises(CubeError):
        largest_cube([0, 0, 0], [0, 600, 800])
    with pytest.raises(CubeError):
        IsoCube((0, 0, 0), 100).poses(0.2)
