"""Where a calibration measured (calib.measured_space): the joint ranges and the reflectors' volume in the base's
cylinder coordinates, what model.json records of them, and how far a point or a pose lies outside."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from trackcal.calib.measured_space import CHUNK, MeasuredSpace, MeasuredSpaceError, fitted_space, space_of
from trackcal.calib.model.cell import load_cell
from trackcal.calib.model.kinematics import Kinematics

# reflectors on a ring: radius 1000 to 2000 mm about the base's z axis, height 0 to 500 mm
POINTS = np.array([[1000.0, 0.0, 0.0], [0.0, 2000.0, 500.0], [-1500.0, 0.0, 250.0]])
Q = np.radians([[-10.0, 20.0], [30.0, 40.0], [0.0, 25.0]])


def test_the_space_of_a_table_is_its_joint_ranges_and_its_ring():
    space = MeasuredSpace.of(Q, POINTS)
    np.testing.assert_allclose(np.degrees(space.joints_rad), [[-10.0, 30.0], [20.0, 40.0]])
    assert space.radius_mm == (1000.0, 2000.0) and space.height_mm == (0.0, 500.0)


def test_how_far_outside():
    space = MeasuredSpace.of(Q, POINTS)
    # joint 1 at 45 deg: 15 deg beyond its 30; joint 2 at 10 deg: 10 below its 20
    np.testing.assert_allclose(
        space.joint_excess_deg(np.radians([[45.0, 10.0], [0.0, 30.0]])), [[15.0, 10.0], [0.0, 0.0]], atol=1e-9
    )
    # at any azimuth: 3 m out and 900 mm high is (1000, 400) from the ring's corner (2000, 500): 1077.03 mm
    # (sqrt(1000^2 + 400^2)); 500 mm from the axis at mid height: 500 mm in; inside the ring: 0
    pts = np.array([[0.0, -3000.0, 900.0], [300.0, 400.0, 250.0], [1200.0, 900.0, 100.0]])
    np.testing.assert_allclose(space.volume_excess_mm(pts), [np.hypot(1000.0, 400.0), 500.0, 0.0])


def test_model_json_round_trip_and_old_files():
    space = MeasuredSpace.of(Q, POINTS)
    back = space_of({"measured": space.to_doc()}, 2)
    np.testing.assert_allclose(back.joints_rad, space.joints_rad, atol=1e-15)
    assert back.radius_mm == space.radius_mm and back.height_mm == space.height_mm
    assert space_of({}, 2) is None  # written before it was recorded: unknown


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda d: d["joints"].pop("joint_2"), "incomplete"),
        (lambda d: d["volume"].update(radius_mm=[2.0, 1.0]), "measured.volume.radius_mm"),
        (lambda d: d["joints"]["joint_1"].update(to_deg="x"), "measured.joints.joint_1"),
    ],
)
def test_a_malformed_entry_is_named(edit, message):
    doc = MeasuredSpace.of(Q, POINTS).to_doc()
    edit(doc)
    with pytest.raises(MeasuredSpaceError, match=message):
        space_of({"measured": doc}, 2)


@given(st.lists(st.tuples(*[st.floats(-3000, 3000)] * 3), min_size=1, max_size=20))
def test_every_measured_point_is_inside(pts):
    pts = np.array(pts)
    space = MeasuredSpace.of(np.zeros((len(pts), 1)), pts)
    assert np.all(space.volume_excess_mm(pts) == 0.0)


def test_the_space_of_a_fit_is_its_reflectors_in_the_base_frame():
    """More rows than one chunk of forward kinematics: the same ring as the points computed at once."""
    chain = load_cell("ur10").chain
    kin = Kinematics(chain, [])
    rng = np.random.default_rng(0)
    q = rng.uniform(-np.pi, np.pi, (CHUNK + 10, chain.dof))
    points = {"a": np.array([0.0, 0.0, 100.0]), "b": np.array([50.0, 0.0, 0.0])}
    ids = list(rng.choice(["a", "b"], len(q)))
    space = fitted_space(kin, np.zeros(0), points, q, ids)
    whole = kin.points(q, np.array([points[i] for i in ids]))
    r, z = np.hypot(whole[:, 0], whole[:, 1]), whole[:, 2]
    assert space.radius_mm == (r.min(), r.max()) and space.height_mm == (z.min(), z.max())
