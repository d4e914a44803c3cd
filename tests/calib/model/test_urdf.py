"""URDF out (`trackcal export-urdf`): the written URDF, built by pinocchio, gives the model's forward kinematics to
1e-6 mm; read back by trackcal's URDF loader it is the same chain; what a URDF cannot hold goes beside it."""

import json

import numpy as np
import pinocchio as pin
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.helpers import kr270_campaign
from trackcal.calib.identify.solver import identify
from trackcal.calib.io.files import write_json
from trackcal.calib.model.cell import load_robot
from trackcal.calib.model.chain import chain_from_urdf
from trackcal.calib.model.kinematics import Kinematics, calibrated_chain
from trackcal.calib.model.params import complete_params, irreducible_params
from trackcal.calib.model.rigid import rpy_matrix
from trackcal.calib.model.urdf import rpy_of
from trackcal.calib.model_file import identification_to_doc, load_model
from trackcal.campaign.errors import OptionError
from trackcal.campaign.jobs.export_urdf import SIDECAR_FORMAT, ExportUrdfOptions, export_urdf

Q = np.random.default_rng(23).uniform(-np.pi, np.pi, size=(50, 6))


@pytest.fixture(scope="module")
def kr270_model(kr270, tmp_path_factory):
    """A model.json identified from a simulated KR-270 campaign (the twin's Table 8 deviations)."""
    _, table = kr270_campaign(kr270, seed=4)
    res = identify(kr270.chain, table, kr270.tool_points, irreducible_params(kr270.chain)[0])
    path = tmp_path_factory.mktemp("urdf") / "model.json"
    write_json(path, identification_to_doc(res))
    return path


def pinocchio_points(urdf, q, point_ids):
    model = pin.buildModelFromUrdf(str(urdf))
    data = model.createData()
    out = []
    for qi in q:
        pin.framesForwardKinematics(model, data, qi)
        out.append([1000.0 * data.oMf[model.getFrameId(f"point_{pid}")].translation for pid in point_ids])
    return np.array(out)  # (poses, points, 3), mm


def test_exported_urdf_is_the_model_through_pinocchio(kr270_model, tmp_path):
    out = tmp_path / "robot.urdf"
    done = export_urdf(ExportUrdfOptions(out=str(out), model=str(kr270_model)))
    model = load_model(kr270_model)
    assert np.max(np.abs(model.dev)) > 0  # a calibrated model, not the nominal robot
    ids = list(model.points)
    ours = np.stack(
        [Kinematics(model.chain, model.params).points(Q, model.points[pid], model.dev) for pid in ids], axis=1
    )
    np.testing.assert_allclose(pinocchio_points(out, Q, ids), ours, atol=1e-6)
    # the nominal robot differs by far more: the test can fail
    nominal = np.stack([Kinematics(model.chain, []).points(Q, model.points[pid]) for pid in ids], axis=1)
    assert np.max(np.abs(nominal - ours)) > 0.1
    # round trip through trackcal's own URDF loader: the same chain, to the flange
    back = chain_from_urdf(str(out))
    r0, o0 = Kinematics(model.chain, model.params).end_frames(Q, model.dev)
    r1, o1 = Kinematics(back, []).end_frames(Q)
    np.testing.assert_allclose(o1, o0, atol=1e-6)
    np.testing.assert_allclose(r1, r0, atol=1e-12)
    assert [j.name for j in back.joints] == [j.name for j in model.chain.joints]
    np.testing.assert_allclose(np.array(back.limits_array()), model.chain.limits_array(), atol=1e-15)
    # the sidecar: named in the URDF's comment, holding what the URDF cannot
    side = json.loads(done.sidecar.read_text())
    assert done.sidecar.name == "robot.trackcal.json" and "robot.trackcal.json" in out.read_text().split("-->")[0]
    assert side["format"] == SIDECAR_FORMAT and side["urdf"] == "robot.urdf"
    assert side["extension"] == model.doc["extension"] and side["stations"] == model.doc["stations"]
    assert side["parameters"] == model.doc["parameters"] and side["joints"] == [j.name for j in model.chain.joints]


def test_an_extension_goes_to_the_sidecar(kr270_model, tmp_path):
    doc = json.loads(kr270_model.read_text())
    doc["extension"] = {
        "cause": "backlash",
        "parameters": {"backlash_a2": {"value": 0.01, "ci95": 0.001, "unit": "deg"}},
    }
    write_json(tmp_path / "ext.json", doc)
    done = export_urdf(ExportUrdfOptions(out=str(tmp_path / "r.urdf"), model=str(tmp_path / "ext.json")))
    assert json.loads(done.sidecar.read_text())["extension"] == doc["extension"]
    assert "the model's extension: backlash" in (tmp_path / "r.urdf").read_text()


@pytest.mark.parametrize("robot", ["ur10", "ur10-dh", "kr270-dh", "irb120-dh"])
def test_robot_descriptions_round_trip_with_deviations(robot, tmp_path):
    """Every complete-model deviation folded in (calibrated_chain), written, built by pinocchio and read back."""
    chain, _ = load_robot(robot)
    params = complete_params(chain)
    rng = np.random.default_rng(5)
    dev = np.array([rng.normal(0, 1.0) if p.is_length else rng.normal(0, 0.01) for p in params])
    r0, o0 = Kinematics(chain, params).end_frames(Q, dev)
    r1, o1 = Kinematics(calibrated_chain(chain, params, dev), []).end_frames(Q)
    np.testing.assert_allclose(o1, o0, atol=1e-9)
    export_urdf(ExportUrdfOptions(out=str(tmp_path / "r.urdf"), robot=robot))
    back = chain_from_urdf(str(tmp_path / "r.urdf"))
    r2, o2 = Kinematics(back, []).end_frames(Q)
    r3, o3 = Kinematics(chain, []).end_frames(Q)
    np.testing.assert_allclose(o2, o3, atol=1e-6)
    np.testing.assert_allclose(r2, r3, atol=1e-12)


@settings(max_examples=60, deadline=None)
@given(
    roll=st.floats(-np.pi, np.pi),
    yaw=st.floats(-np.pi, np.pi),
    pitch=st.one_of(
        st.floats(-np.pi / 2, np.pi / 2), st.sampled_from([np.pi / 2, -np.pi / 2]).map(lambda p: p * (1 - 1e-9))
    ),
)
def test_rpy_gives_the_rotation_back_even_near_pitch_90(roll, pitch, yaw):
    r = rpy_matrix(roll, pitch, yaw)
    np.testing.assert_allclose(rpy_matrix(*rpy_of(r)), r, atol=1e-14)


@pytest.mark.parametrize(
    ("opts", "message"),
    [
        ({}, "give one of model, cell or robot"),
        ({"cell": "kr270", "robot": "ur10"}, r"give one of model, cell or robot \(not several\)"),
        ({"robot": "ur10", "out": "x.txt"}, "out x.txt: a URDF file name ends in .urdf"),
    ],
)
def test_option_mistakes(opts, message):
    with pytest.raises(OptionError, match=message):
        export_urdf(ExportUrdfOptions(**{"out": "x.urdf", **opts}))


TILTED_URDF = """<?xml version="1.0"?>
<robot name="tilted">
  <link name="base_link"/>
  <joint name="torso" type="revolute"><parent link="base_link"/><child link="l1"/>
    <origin xyz="0 0 0.3" rpy="0 0 0"/><axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="0" velocity="0"/></joint>
  <link name="l1"/>
  <joint name="shoulder" type="revolute"><parent link="l1"/><child link="l2"/>
    <origin xyz="0.15 0 0.2" rpy="0.1 0 0"/><axis xyz="0 0.25881904510252074 0.9659258262890683"/>
    <limit lower="-3" upper="3" effort="0" velocity="0"/></joint>
  <link name="l2"><inertial><mass value="2"/><origin xyz="0.1 0.02 0"/>
    <inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/></inertial></link>
  <joint name="elbow" type="revolute"><parent link="l2"/><child link="l3"/>
    <origin xyz="0.6 0 0" rpy="0 0 0"/><axis xyz="0.6 -0.8 0"/>
    <limit lower="-3" upper="3" effort="0" velocity="0"/></joint>
  <link name="l3"/>
  <joint name="wrist" type="revolute"><parent link="l3"/><child link="l4"/>
    <origin xyz="0.4 0.05 0" rpy="0 0.3 0"/><axis xyz="-1 0 0"/>
    <limit lower="-3" upper="3" effort="0" velocity="0"/></joint>
  <link name="l4"/>
</robot>
"""


def test_urdf_joints_about_tilted_axes_are_read(tmp_path):
    """A URDF axis in any direction (here a shoulder tilted 15 deg, an elbow along (0.6, -0.8, 0)) is read as a
    turned frame: the same forward kinematics as pinocchio's model of the file, and a complete set of 4n - 6."""
    path = tmp_path / "tilted.urdf"
    path.write_text(TILTED_URDF)
    chain = chain_from_urdf(str(path))
    model = pin.buildModelFromUrdf(str(path))
    data = model.createData()
    q = np.random.default_rng(2).uniform(-3, 3, size=(30, 4))
    r, o = Kinematics(chain, []).end_frames(q)
    for qi, ri, oi in zip(q, r, o, strict=True):
        pin.forwardKinematics(model, data, qi)
        np.testing.assert_allclose(oi, 1000.0 * data.oMi[4].translation, atol=1e-9)
        np.testing.assert_allclose(
            ri @ np.eye(3)[chain.joints[3].axis] * chain.joints[3].sign,
            data.oMi[4].rotation @ np.array([-1.0, 0, 0]),
            atol=1e-12,
        )
    assert len(irreducible_params(chain)[0]) == 4 * 4 - 6
    # the mass model follows the turned frame: the centre of mass is where the URDF puts it
    pin.forwardKinematics(model, data, q[0])
    com_urdf = 1000.0 * (data.oMi[2].act(model.inertias[2].lever))
    kin2 = Kinematics(type(chain)(chain.name, chain.base, chain.joints[:2]), [])
    r2, o2 = kin2.end_frames(q[:1, :2])
    # end_frames gives the frame after joint 2's link; the com is in the frame right after joint 2's rotation
    turned_frame = r2[0] @ chain.joints[1].rotation.T
    origin = o2[0] - turned_frame @ chain.joints[1].translation
    np.testing.assert_allclose(origin + turned_frame @ chain.joints[1].com, com_urdf, atol=1e-9)
