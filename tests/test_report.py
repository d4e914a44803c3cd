"""The campaign report: report.html with its PNG plots, Table 8 and Table 9 content, escaping, the CLI."""

import json
import re
from html.parser import HTMLParser
from pathlib import Path

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
import pytest

from calib.diagnose import diagnose
from calib.noise import TrackerNoise
from calib.table import read_table, write_table
from campaign.analysis import choose_params, run_identify, verdict_doc
from campaign.cli import main
from campaign.report.html import write_report
from tests.conftest import kr270_campaign

ODD_STATION = 'S"1<&>'  # a station id HTML must escape
TITLE = "KR-270 <script>alert('x')</script> & co"


class Page(HTMLParser):
    """Collects image sources, table cells (text) and checks the tag structure of the page."""

    def __init__(self):
        super().__init__()
        self.images, self.cells, self.tags = [], [], []

    def handle_starttag(self, tag, attrs):
        self.tags.append(tag)
        if tag == "img":
            self.images.append(dict(attrs)["src"])

    def handle_data(self, data):
        self.cells.append(data)


@pytest.fixture(scope="module")
def campaign(kr270, tmp_path_factory):
    d = tmp_path_factory.mktemp("report")
    _, table = kr270_campaign(kr270, seed=41, n_poses=30)
    table.station = [ODD_STATION if s == "S1" else s for s in table.station]
    write_table(table, d / "table.csv")
    table = read_table(d / "table.csv", n_joints=kr270.chain.dof)
    outcome = run_identify(kr270, table, choose_params(kr270, None), "tracker")
    (d / "model.json").write_text(json.dumps(outcome.doc))
    plan = {"rho0_mm": 0.00231, "repeat": 3, "criterion": "rho0", "params": ["px1", "px2"],
            "poses_deg": [[10.0, -90.0, 90.0, 0.0, 45.0, 0.0], [-30.0, -60.0, 40.0, 90.0, -30.0, 10.0]],
            "test_pose_deg": [76.7, -56.9, 89.3, 45.1, 76, 57.2]}  # fmt: skip
    verdict = {"cause": "none", "candidates": [{"cause": "backlash", "n_params": 5, "holdout_rms_mm": 0.0161,
               "rms_mm": 0.0149, "f_pvalue": 0.41, "delta_bic": 12.0, "significant": False}],
               "geometric": {"rms_mm": 0.0150}, "extended": {"rms_mm": 0.0150}, "noise_floor_mm": 0.0151,
               "noise_floor_source": "tracker noise model",
               "holdout": {"rms_geometric_mm": 0.0162, "rms_extended_mm": 0.0162}}  # fmt: skip
    (d / "plan.json").write_text(json.dumps(plan))
    (d / "verdict.json").write_text(json.dumps(verdict))
    return d, table, outcome, plan, verdict


def table9_expected(before: np.ndarray, after: np.ndarray) -> list[str]:
    """Paper Table 9, computed here: coordinate-based (every |x|, |y|, |z|) and distance-based (3-D norms)."""
    out = []
    for r in (before, after):
        coord = np.abs(r).ravel()
        dist = np.sqrt((r**2).sum(axis=1))
        out += [coord.max(), np.sqrt((coord**2).mean()), dist.max(), np.sqrt((dist**2).mean())]
    return [f"{v:.4f}" for v in out]


def test_report_has_plots_parameters_and_table9(kr270, campaign, tmp_path):
    d, table, outcome, plan, verdict = campaign
    path = write_report(tmp_path / "rep", kr270, table, outcome.doc, plan, verdict, TITLE)
    assert path == tmp_path / "rep" / "report.html"
    text = path.read_text()
    page = Page()
    page.feed(text)
    # every image is a PNG next to the report, and exists; nothing external
    assert len(page.images) >= 4
    for src in page.images:
        assert src.endswith(".png") and not src.startswith(("/", "http"))
        assert (path.parent / src).is_file() and (path.parent / src).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "script" not in page.tags and "link" not in page.tags and "http" not in text
    cells = [c.strip() for c in page.cells]
    for name in outcome.doc["parameters"]:
        assert name in cells
    # Table 9 from the identification's own residuals (the fit after, the nominal robot before)
    b, a = outcome.before.residuals, outcome.result.residuals
    expected = table9_expected(b, a)
    section = text.split("Table 9")[1].split("<h2>")[0]
    for v in expected:
        assert f"<td>{v}</td>" in section, v
    ratio = np.sqrt((np.abs(b) ** 2).mean()) / np.sqrt((np.abs(a) ** 2).mean())
    assert f"{ratio:.1f}" in section
    # the plan and the diagnosis
    assert "2.310" in text and "-90.00" in text
    assert "backlash" in cells and "16.1" in cells


def test_text_is_escaped(kr270, campaign, tmp_path):
    d, table, outcome, plan, verdict = campaign
    text = write_report(tmp_path / "rep", kr270, table, outcome.doc, plan, verdict, TITLE).read_text()
    assert "<script>" not in text and ODD_STATION not in text
    assert "KR-270 &lt;script&gt;alert(&#x27;x&#x27;)&lt;/script&gt; &amp; co" in text
    assert "S&quot;1&lt;&amp;&gt;" in text
    page = Page()
    page.feed(text)
    assert ODD_STATION in [c.strip() for c in page.cells]  # and it reads back as the original id


def test_report_without_plan_or_verdict_and_with_extra_images(kr270, campaign, tmp_path):
    matplotlib.use("Agg")

    d, table, outcome, _, _ = campaign
    extra = tmp_path / "parameters.png"  # same name as one of the report's own plots: must not replace it
    fig, ax = plt.subplots()
    ax.plot([0, 1], [0, 1])
    fig.savefig(extra)
    plt.close(fig)
    out = tmp_path / "rep"
    text = write_report(out, kr270, table, outcome.doc, None, None, "t", extra_images=[extra]).read_text()
    assert "No plan given" in text
    assert 'src="extra/parameters.png"' in text and 'src="parameters.png"' in text
    assert (out / "extra" / "parameters.png").read_bytes() == extra.read_bytes()
    assert (out / "parameters.png").read_bytes() != extra.read_bytes()


def test_cli_report(campaign, tmp_path, capsys):
    d, *_ = campaign
    out = tmp_path / "cli"
    argv = ["report", "--table", str(d / "table.csv"), "--model", str(d / "model.json"), "--plan", str(d / "plan.json"),
            "--verdict", str(d / "verdict.json"), "--out", str(out)]  # fmt: skip
    assert main(argv) == 0
    assert "report written to" in capsys.readouterr().out
    text = (out / "report.html").read_text()
    assert "kr270" in text and all((out / src).is_file() for src in re.findall(r'src="([^"]+)"', text))


def test_cli_user_mistakes_end_in_one_line_and_exit_2(campaign, tmp_path, capsys):
    d, *_ = campaign
    nocell = tmp_path / "nocell.json"
    doc = json.loads((d / "model.json").read_text())
    doc.pop("cell")
    nocell.write_text(json.dumps(doc))
    notjson = tmp_path / "plan.json"
    notjson.write_text("{nope")
    base = ["report", "--table", str(d / "table.csv"), "--out", str(tmp_path / "o")]
    cases = [
        (["--model", str(tmp_path / "missing.json")], "no such file"),
        (["--model", str(nocell)], "--cell"),
        (["--model", str(d / "model.json"), "--plan", str(notjson)], "line 1: not JSON"),
        (["--model", str(d / "model.json"), "--verdict", str(tmp_path / "v.json")], "no such file"),
        (["--model", str(d / "model.json"), "--plots", str(tmp_path / "nodir")], "not a directory"),
    ]
    for extra, message in cases:
        assert main(base + extra) == 2, extra
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith("error: ") and message in err, err
    assert not Path(tmp_path / "o" / "report.html").exists()


def test_report_embeds_the_diagnosis_plots(kr270, campaign, tmp_path):
    d, table, outcome, plan, _ = campaign
    diag = diagnose(kr270.chain, table, kr270.tool_points, choose_params(kr270, None), TrackerNoise(), folds=3)
    out = tmp_path / "rep"
    text = write_report(out, kr270, table, outcome.doc, plan, verdict_doc(kr270, diag), "t", diagnosis=diag).read_text()
    for name in ("diagnosis/signature.png", "diagnosis/structure.png"):
        assert f'src="{name}"' in text and (out / name).is_file()
    assert f"Cause: <b>{diag.cause}</b>" in text
