"""calib raises CalibError subclasses only, for its input: a caller catches the one it handles, the CLI the base."""

import ast
from dataclasses import replace

import numpy as np
import pytest

from tests.helpers import ROOT
from trackcal.calib.diagnose.extensions import build_extension
from trackcal.calib.diagnose.joint_map import Arc, JointMapError, parse_name
from trackcal.calib.doe.design import DesignError, design_for_cell
from trackcal.calib.errors import CalibError
from trackcal.calib.identify.noise import NoiseError, noise_for
from trackcal.calib.model.chain import ChainError
from trackcal.calib.model.extension import ExtensionError
from trackcal.calib.model.kinematics import Kinematics
from trackcal.calib.model.rigid import RigidError, kabsch
from trackcal.mocks.twin import Twin, simulate_campaign

CALIB = ROOT / "calib"
PLAIN = ("ValueError", "TypeError", "KeyError", "IndexError", "RuntimeError", "Exception")


def test_calib_raises_no_plain_python_errors():
    """Every `raise X(...)` in calib names a CalibError subclass (or the `error` class a reader is given)."""
    plain = []
    for path in sorted(CALIB.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            call = node.exc if isinstance(node, ast.Raise) else None
            if isinstance(call, ast.Call) and isinstance(call.func, ast.Name) and call.func.id in PLAIN:
                plain.append(f"{path.relative_to(CALIB)}:{node.lineno}")
    assert not plain, plain


def test_calib_error_is_not_a_value_error():
    assert not issubclass(CalibError, ValueError)


def test_each_module_refines_the_base(kr270):
    table = simulate_campaign(Twin(kr270), np.zeros((1, kr270.chain.dof)), noise_free=True)
    with pytest.raises(NoiseError, match="weighting 'x'"):
        noise_for("x")
    with pytest.raises(RigidError, match="collinear"):
        kabsch(np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]]), np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]]))
    with pytest.raises(ChainError, match="joint values per row"):
        Kinematics(kr270.chain, []).end_frames(np.zeros((1, 2)))
    with pytest.raises(JointMapError, match="not a joint error map coefficient"):
        parse_name("x1")
    with pytest.raises(JointMapError, match="no angles"):
        Arc.covering(np.array([]))
    with pytest.raises(DesignError, match="no test_pose_deg"):
        design_for_cell(replace(kr270, test_pose=None), [])
    with pytest.raises(ExtensionError, match="unknown model extension"):
        build_extension("gremlins", kr270.chain, table)
    assert all(issubclass(e, CalibError) for e in (NoiseError, RigidError, JointMapError, DesignError, ExtensionError))
