"""`trackcal filter` (campaign/jobs/filter_program.py, campaign/cli/filter.py): the sample URScript program filtered
with a model of the UR10 twin; the files, filter.json, filter.html; targets kept with their reason; one-line refusals.
"""

import json
from pathlib import Path

import numpy as np
import pytest

from tests.calib.test_program_filter import independent_fk
from trackcal.calib.model_file import load_model
from trackcal.calib.model_trust import sealed
from trackcal.campaign.cli import main
from trackcal.drivers.ur.urscript_reader import read_urscript

SAMPLE = Path(__file__).resolve().parents[3] / "configs" / "programs" / "ur" / "cell_demo.script"


@pytest.fixture(scope="module")
def ur10_model(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("model")
    assert main(["simulate", "--cell", "ur10", "--poses", "20", "--seed", "1", "--out", str(d / "t.csv")]) == 0
    assert main(["identify", str(d / "t.csv"), "--cell", "ur10", "--out", str(d / "m.json")]) == 0
    return d / "m.json"


def strict_json(path: Path) -> dict:
    def refuse(token):
        raise ValueError(f"not JSON: {token}")

    return json.loads(path.read_text(), parse_constant=refuse)


def test_the_sample_program_filtered(ur10_model, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["filter", str(SAMPLE), "--model", str(ur10_model), "--out", str(out), "--tolerance-mm", "0.5"]) == 0
    printed = capsys.readouterr().out
    assert "8 of 8 targets filtered; 0 fail the tolerance of 0.5 mm" in printed
    source = SAMPLE.read_text()
    written = (out / SAMPLE.name).read_text()
    before, after = read_urscript({"s": source}), read_urscript({"s": written})
    assert len(after.targets) == len(before.targets) == 8
    # only the targets' text changed: the rest (comments, speeds, logic) is the same, line for line
    for a, b in zip(source.splitlines(), written.splitlines(), strict=True):
        if "p[" not in a and "movej([" not in a and not a.startswith("  home ="):
            assert a == b
    doc = strict_json(out / "filter.json")
    assert doc["language"] == "URScript" and doc["filtered"] == 8 and doc["kept"] == 0
    model = load_model(ur10_model)
    for row, t in zip(doc["targets"], after.targets, strict=True):
        assert row["status"] == "filtered" and row["pass"] is True
        assert row["line"] == t.line and row["name"] == t.name
        # the model moves the UR10's TCP by about its deviations (0.3 mm per link, mocks.twin): well under 10 mm
        assert 0.0 < row["correction_mm"] < 10.0
        assert 0.0 < row["sigma_mm"] <= row["bound95_mm"]
    assert model.cause == "none"
    assert "<table>" in (out / "filter.html").read_text()


def test_an_unreachable_target_is_kept_and_marked(ur10_model, tmp_path, capsys):
    script = tmp_path / "far.script"
    script.write_text(
        "def far():\n  movej([0.0, -1.5708, 1.5708, -1.5708, -1.5708, 0.0])\n"
        "  movel(p[3.000000, 0.000000, 0.500000, 3.141593, 0.000000, 0.000000], a=0.5, v=0.1)  # 3 m\n"
        "end\n"
    )
    out = tmp_path / "out"
    args = ["filter", str(script), "--model", str(ur10_model), "--out", str(out), "--tolerance-mm", "0.5"]
    assert main(args) == 0
    captured = capsys.readouterr()
    assert "far.script: line 3: kept as it was (commented): unreachable" in captured.err
    lines = (out / "far.script").read_text().splitlines()
    assert lines[2].startswith("  movel(p[3.000000, 0.000000, 0.500000, 3.141593, 0.000000, 0.000000], a=0.5")
    assert lines[2].endswith(
        "# 3 m # trackcal filter: kept as it was: unreachable: the nominal kinematics has no "
        "solution for it (outside the workspace)"
    )
    doc = strict_json(out / "filter.json")
    assert [r["status"] for r in doc["targets"]] == ["filtered", "kept"]
    assert doc["targets"][1]["bound95_mm"] is None and doc["targets"][1]["pass"] is False
    assert main([*args, "--strict"]) == 1  # a target fails the tolerance: --strict says so


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["nope.txt"], "no reader for .txt programs"),
        (["missing.script"], "missing.script: no such file"),
        (["broken.script"], "broken.script: line 2: a pose p[x, y, z, rx, ry, rz] needs 6 numbers, got 3"),
        (["ok.script", "--tolerance-mm", "-1"], "--tolerance-mm -1"),
        (["ok.script", "--out", "."], "would overwrite the input"),
        # a KRL program for the UR10's model (its robot config names its controller: configs/robots/ur10.yaml)
        (["PALLET.src"], "PALLET.src: a KRL program, but the model's robot runs a"),
    ],
)
def test_mistakes_are_one_line(ur10_model, tmp_path, monkeypatch, capsys, argv, message):
    monkeypatch.chdir(tmp_path)
    Path("nope.txt").write_text("x")
    Path("broken.script").write_text("def a():\n  movel(p[0.1, 0.2, 0.3])\nend\n")
    Path("ok.script").write_text("def a():\n  movel(p[0.5, 0.2, 0.3, 3.14, 0, 0])\nend\n")
    Path("PALLET.src").write_text("DEF PALLET()\n  PTP {A1 0,A2 -90,A3 90,A4 0,A5 30,A6 0}\nEND\n")
    out = [] if "--out" in argv else ["--out", "o"]
    assert main(["filter", *argv, "--model", str(ur10_model), *out]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err
    assert Path("ok.script").read_text().startswith("def a():\n  movel(p[0.5, ")  # never written over


def test_a_filtered_program_filtered_again_moves_little(ur10_model, tmp_path):
    """Filtering is not idempotent (the second pass corrects the corrected targets), but a target's second correction
    is the model's correction at a pose 1-2 mm away: the same to first order, so the two passes differ by far less
    than the first correction."""
    assert main(["filter", str(SAMPLE), "--model", str(ur10_model), "--out", str(tmp_path / "a")]) == 0
    assert (
        main(["filter", str(tmp_path / "a" / SAMPLE.name), "--model", str(ur10_model), "--out", str(tmp_path / "b")])
        == 0
    )
    first = strict_json(tmp_path / "a" / "filter.json")["targets"]
    second = strict_json(tmp_path / "b" / "filter.json")["targets"]
    for a, b in zip(first, second, strict=True):
        assert abs(a["correction_mm"] - b["correction_mm"]) < 0.05 * a["correction_mm"] + 1e-3
    assert np.isfinite([t["sigma_mm"] for t in second]).all()


def test_an_edited_model_is_refused_as_compensate_refuses_it(ur10_model, tmp_path, capsys):
    doc = json.loads(ur10_model.read_text())
    name = next(iter(doc["parameters"]))
    doc["parameters"][name]["value"] += 0.5  # edited by hand: its digest no longer matches (calib.model_trust)
    edited = tmp_path / "edited.json"
    edited.write_text(json.dumps(doc))
    argv = ["filter", str(SAMPLE), "--model", str(edited), "--out", str(tmp_path / "o")]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--accept-edited" in err[0]
    assert not (tmp_path / "o").exists()
    assert main([*argv, "--accept-edited"]) == 0


def resealed(ur10_model: Path, path: Path, edit) -> Path:
    """The model with `edit(doc)` applied, sealed again as trackcal writes it (calib.model_trust.sealed)."""
    doc = json.loads(ur10_model.read_text())
    edit(doc)
    path.write_text(json.dumps(sealed(doc)))
    return path


def test_targets_outside_the_measured_volume_are_flagged_and_never_pass(ur10_model, tmp_path, capsys):
    """A model measured on a ring of radius 0 to 1 mm about the base's axis: every target of the sample lies outside
    it by its TCP's distance from the axis less 1 mm (the height range holds them all), its bound not covered."""

    def narrow(doc):
        doc["measured"]["volume"].update(radius_mm=[0.0, 1.0], height_mm=[-1e4, 1e4])

    model = resealed(ur10_model, tmp_path / "narrow.json", narrow)
    out = tmp_path / "out"
    args = ["filter", str(SAMPLE), "--model", str(model), "--out", str(out), "--tolerance-mm", "0.5"]
    assert main(args) == 0
    printed = capsys.readouterr()
    assert "0 fail the tolerance of 0.5 mm; 8 outside the space the model was measured in" in printed.out
    assert "8 pass/fail unknown" in printed.out and "8 of 8 target(s) lie outside" in printed.err
    doc = strict_json(out / "filter.json")
    assert doc["outside_measured"] == 8 and doc["unknown"] == 8 and doc["failed"] == 0
    targets = read_urscript({"s": SAMPLE.read_text()}).targets
    for row, t in zip(doc["targets"], targets, strict=True):
        # the intended TCP in the base frame (a joint target: the nominal robot's, an FK written from the YAML)
        tcp = ((independent_fk("ur10", np.radians(t.value)) @ t.tool) if t.joint else t.base @ t.value)[:3, 3]
        assert row["measured_space"] == "outside" and row["bound_covered"] is False and row["pass"] is None
        assert row["outside_volume_mm"] == pytest.approx(np.hypot(tcp[0], tcp[1]) - 1.0, abs=1e-6)
    written = (out / SAMPLE.name).read_text()
    assert written.count("# trackcal filter: outside the calibration's measured space (TCP ") == 8
    page = (out / "filter.html").read_text()
    assert page.count("bound not covered") == 8 and ">unknown<" in page
    assert main([*args, "--strict"]) == 1  # unknown is not a pass: --strict says so


def test_a_model_that_does_not_record_where_it_was_measured_says_unknown(ur10_model, tmp_path, capsys):
    model = resealed(ur10_model, tmp_path / "old.json", lambda doc: doc.pop("measured"))
    out = tmp_path / "out"
    assert main(["filter", str(SAMPLE), "--model", str(model), "--out", str(out), "--tolerance-mm", "0.5"]) == 0
    assert "does not record where it was measured" in capsys.readouterr().err
    rows = strict_json(out / "filter.json")["targets"]
    assert {r["measured_space"] for r in rows} == {"unknown"} and all(r["pass"] is True for r in rows)
    assert all(r["bound_covered"] is None and r["outside_volume_mm"] is None for r in rows)
