"""The chain as a pinocchio model (SI units: m, kg), for gravity torques and cross-checks."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from trackcal.calib.model.chain import Chain

if TYPE_CHECKING:
    import pinocchio as pin

G = 9.80665  # standard gravity, m/s^2


def pinocchio_model(chain: Chain, tool_mm: np.ndarray | None = None) -> pin.Model:
    """Nominal chain with point-mass bodies (mass model of the robot config); optional frame "tip"."""
    import pinocchio as pin  # lazy: ~0.3 s at start-up, for the few commands that need gravity torques

    model = pin.Model()
    model.gravity = pin.Motion(np.array([0.0, 0.0, -G]), np.zeros(3))
    parent = 0
    placement = pin.SE3(chain.base[:3, :3].copy(), chain.base[:3, 3] / 1000.0)
    for jt in chain.joints:
        if jt.sign > 0:
            jm = [pin.JointModelRX, pin.JointModelRY, pin.JointModelRZ][jt.axis]()
        else:
            jm = pin.JointModelRevoluteUnaligned(-np.eye(3)[jt.axis])
        parent = model.addJoint(parent, jm, placement, jt.name)
        model.appendBodyToJoint(parent, pin.Inertia(jt.mass_kg, jt.com / 1000.0, np.zeros((3, 3))), pin.SE3.Identity())
        placement = pin.SE3(jt.rotation.copy(), jt.translation / 1000.0)
    if tool_mm is not None:
        tip = pin.SE3(np.eye(3), np.asarray(tool_mm) / 1000.0)
        model.addFrame(pin.Frame("tip", parent, tip, pin.FrameType.OP_FRAME))
    return model


def gravity_torques(chain: Chain, q: np.ndarray) -> np.ndarray:
    """(N, n) joint torques (N m) that hold the arm against gravity at each pose q (N, n) rad."""
    import pinocchio as pin  # lazy, as in pinocchio_model

    model = pinocchio_model(chain)
    data = model.createData()
    return np.array([pin.computeGeneralizedGravity(model, data, qi).copy() for qi in np.atleast_2d(q)])
