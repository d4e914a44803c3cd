"""issue 25: a model extended by several causes names every one of them (model.json `causes`, `cause` the main one,
per DESIGN.md), in the identify printout and in what predict and compensate read back."""

import json

import numpy as np
import pytest

from tests.helpers import kr270_campaign
from trackcal.calib.compensate import compensate
from trackcal.calib.io.table import write_table
from trackcal.calib.model.cell import load_cell
from trackcal.calib.model.params import irreducible_params
from trackcal.calib.model_file import ModelError, load_model, model_from_doc
from trackcal.campaign.cli import main
from trackcal.campaign.jobs.identify import run_identify


@pytest.fixture(scope="module")
def two_causes(tmp_path_factory):
    """A twin with gravity compliance and backlash, both at 3x the tracker noise (0.045 mm of what geometry
    cannot absorb; the AT901 model's ~15 um per coordinate at 2-4 m, README)."""
    cell = load_cell("kr270")
    _, table = kr270_campaign(cell, seed=11, effects={"joint_compliance": 0.045, "backlash": 0.045})
    path = tmp_path_factory.mktemp("causes") / "t.csv"
    write_table(table, str(path))
    return cell, table, path


def test_identify_names_every_fitted_cause(two_causes, tmp_path, capsys):
    cell, table, path = two_causes
    out = tmp_path / "m.json"
    assert (
        main(["identify", str(path), "--cell", "kr270", "--extend", "joint_compliance+backlash", "--out", str(out)])
        == 0
    )
    printed = capsys.readouterr().out
    assert "joint_compliance + backlash" in printed
    ext = json.loads(out.read_text())["extension"]
    assert ext["cause"] == "joint_compliance"
    assert ext["causes"] == ["joint_compliance", "backlash"]
    assert any(n.startswith("b") for n in ext["parameters"])  # backlash widths b1..b6 are fitted
    model = load_model(str(out))
    assert model.causes == ["joint_compliance", "backlash"]
    assert {c for c, _ in model.parts()} == {"joint_compliance", "backlash"}


def test_compensate_reports_every_cause(two_causes, tmp_path):
    cell, table, _ = two_causes
    doc = run_identify(cell, table, cell_params(cell), extend="backlash+joint_compliance").doc
    assert doc["extension"]["causes"] == ["backlash", "joint_compliance"]
    _, report = compensate(model_from_doc(doc), np.radians(table.q_deg[:3]), cell.tcp)
    assert report.to_doc()["causes"] == ["backlash", "joint_compliance"]


def cell_params(cell):
    return irreducible_params(cell.chain)[0]


def test_causes_must_begin_with_the_main_cause(two_causes):
    cell, table, _ = two_causes
    doc = run_identify(cell, table, cell_params(cell), extend="joint_compliance+backlash").doc
    doc["extension"]["causes"] = ["backlash", "joint_compliance"]
    with pytest.raises(ModelError, match="extension.causes"):
        model_from_doc(doc)
    doc["extension"]["causes"] = ["joint_compliance", "gremlins"]
    with pytest.raises(ModelError, match="extension.causes"):
        model_from_doc(doc)


def test_a_model_written_before_causes_reads_its_parts(two_causes):
    cell, table, _ = two_causes
    doc = run_identify(cell, table, cell_params(cell), extend="joint_compliance+backlash").doc
    del doc["extension"]["causes"]
    assert model_from_doc(doc).causes == ["joint_compliance", "backlash"]
