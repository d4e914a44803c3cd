"""A session's cell loads from the documents the session stores, with no temporary directory (issue 37): the same
cell as the configs it was copied from, a URDF robot included; and a replay copies those documents as they are."""

import tempfile

import numpy as np
import pytest
import yaml

from tests.helpers import ROOT, feasible_plan
from trackcal.calib.model.cell import load_cell
from trackcal.calib.model.kinematics import Kinematics
from trackcal.calib.model.urdf import chain_to_urdf
from trackcal.campaign.jobs.campaign import new_session
from trackcal.campaign.session.session import session_cell, stored_config


@pytest.fixture
def no_temporary_directory(monkeypatch):
    def refused(*args, **kw):
        raise AssertionError("a temporary directory was made")

    monkeypatch.setattr(tempfile, "TemporaryDirectory", refused)
    monkeypatch.setattr(tempfile, "mkdtemp", refused)


def same_cell(a, b) -> None:
    """The same cell: names, limits, tool, stations, the robot's forward kinematics at a pose."""
    assert (a.name, a.nominal, a.max_skipped_share) == (b.name, b.nominal, b.max_skipped_share)
    assert a.tool_points.keys() == b.tool_points.keys() and a.stations.keys() == b.stations.keys()
    assert np.array_equal(a.chain.limits_array(), b.chain.limits_array())
    ids = sorted(a.tool_points)
    q = np.radians(np.tile([10.0, -80.0, 95.0, 20.0, 30.0, -40.0], (len(ids), 1)))
    points = [Kinematics(c.chain, []).points(q, np.array([c.tool_points[k] for k in ids])) for c in (a, b)]
    assert np.allclose(points[0], points[1], atol=1e-9)


def test_a_sessions_cell_is_read_from_its_stored_documents(kr270, tmp_path, no_temporary_directory):
    store, campaign = new_session(tmp_path / "s", "kr270", feasible_plan(kr270, 3, seed=5, repeat=1), "sim", 3)
    (tmp_path / "s" / "config" / "cell.yaml").unlink()  # the copy beside the database is not what is read
    same_cell(session_cell(store), kr270)
    assert set(stored_config(store)) == {"config/cell.yaml", "config/robot.yaml", "config/tool.yaml"}
    store.close()


def test_a_stored_urdf_robot_is_read_from_its_text(kr270, tmp_path, no_temporary_directory):
    cell_doc = yaml.safe_load((ROOT / "configs" / "cells" / "kr270.yaml").read_text())
    (tmp_path / "robot.urdf").write_text(chain_to_urdf(kr270.chain))
    tool = cell_doc["tool"]
    (tmp_path / "tool.yaml").write_text((ROOT / "configs" / "tools" / f"{tool}.yaml").read_text())
    cell_doc.update(robot="robot.urdf", tool="tool.yaml", name="kr270")
    (tmp_path / "cell.yaml").write_text(yaml.safe_dump(cell_doc))
    on_disk = load_cell(str(tmp_path / "cell.yaml"))
    store, _ = new_session(
        tmp_path / "s", str(tmp_path / "cell.yaml"), feasible_plan(kr270, 3, seed=5, repeat=1), "sim", 3
    )
    for name in ("cell.yaml", "robot.urdf", "tool.yaml"):
        (tmp_path / name).unlink()
        (tmp_path / "s" / "config" / name).unlink()
    same_cell(session_cell(store), on_disk)
    store.close()
