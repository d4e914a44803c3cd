"""The campaign report: report.html with its PNG plots, header, Table 8 and Table 9 content, escaping, files of
different campaigns refused, the CLI, and the page as headless Chromium renders it."""

import base64
import json
import os
import re
import shutil
import subprocess
from html.parser import HTMLParser
from pathlib import Path

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
import pytest

from tests.helpers import kr270_campaign
from trackcal.calib.diagnose import diagnose
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.io.table import read_table, write_table
from trackcal.campaign.cli import main
from trackcal.campaign.jobs.diagnose import verdict_doc
from trackcal.campaign.jobs.end_of_run import analysed, diagnosis_of
from trackcal.campaign.jobs.identify import choose_params, run_identify, sha256_of
from trackcal.campaign.report.analysis import Provenance
from trackcal.campaign.report.html import summarise_warnings, write_report

ODD_STATION = 'S"1<&>'  # a station id HTML must escape
SESSION = "KR-270 <script>alert('x')</script> & co"  # a session directory name HTML must escape
PROV = Provenance(session=SESSION, campaign_started="2026-12-01 10:00 UTC", model_path="model.json", cell_ref="kr270")
WARNINGS = ["t = 748 s: P2 not measurable from S1 at Q5: beam broken; skipped here"]


def render(out, cell, table, model, plan, verdict, prov, warnings=None, extra_images=None, diagnosis=None) -> Path:
    """The report of these documents (a verdict without its diagnosis: the table diagnosed again, as `trackcal
    report` does)."""
    if verdict is not None and diagnosis is None:
        diagnosis = diagnosis_of(cell, table, model)
    analysis = analysed(
        cell, table, model, plan=plan, verdict=verdict, diagnosis=diagnosis, warnings=warnings, provenance=prov
    )
    return write_report(analysis, out, extra_images)


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
    configurations = list(dict.fromkeys(tuple(q) for q in table.q_deg.tolist()))  # the table's, in order
    plan = {
        "rho0_mm": 0.00231,
        "repeat": 1,
        "criterion": "rho0",
        "params": ["px1", "px2"],
        "poses_deg": [list(q) for q in configurations],
        "test_pose_deg": [76.7, -56.9, 89.3, 45.1, 76, 57.2],
    }
    verdict = {
        "cause": "none",
        "cell": "kr270",
        "table_sha256": sha256_of(table.source),
        "candidates": [
            {
                "cause": "backlash",
                "n_params": 5,
                "holdout_rms_mm": 0.0161,
                "rms_mm": 0.0149,
                "f_pvalue": 0.41,
                "delta_bic": 12.0,
                "significant": False,
            }
        ],
        "geometric": {"rms_mm": 0.0150},
        "extended": {"rms_mm": 0.0150},
        "noise_floor_mm": 0.0151,
        "noise_floor_source": "tracker noise model",
        "holdout": {"rms_geometric_mm": 0.0162, "rms_extended_mm": 0.0162},
    }
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
    return [f"{1000 * v:.1f}" for v in out]  # the report gives them in µm


@pytest.fixture(scope="module")
def report(kr270, campaign, tmp_path_factory) -> Path:
    """The campaign's report with its plan, verdict, provenance and warnings, rendered once: the tests below read it
    (each rendering diagnoses the table again and draws every figure)."""
    d, table, outcome, plan, verdict = campaign
    out = tmp_path_factory.mktemp("report") / "rep"
    return render(out, kr270, table, outcome.doc, plan, verdict, PROV, WARNINGS)


def test_report_has_plots_parameters_and_table9(campaign, report):
    d, table, outcome, plan, verdict = campaign
    path = report
    assert path.name == "report.html" and path.parent.name == "rep"
    text = path.read_text()
    page = Page()
    page.feed(text)
    # every image is a PNG embedded in the page (the one file is the report); nothing external
    assert len(page.images) >= 4
    for src in page.images:
        assert src.startswith("data:image/png;base64,")
        assert base64.b64decode(src.split(",", 1)[1])[:8] == b"\x89PNG\r\n\x1a\n"
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
    assert "2.310" in text and f"{plan['poses_deg'][0][1]:.2f}" in text
    assert "backlash" in cells and "16.1" in cells


def test_report_header_verdict_what_next_and_warnings(campaign, report):
    d, table, outcome, plan, verdict = campaign
    text = report.read_text()
    page = Page()
    page.feed(text)
    cells = [c.strip() for c in page.cells]
    for fact in ("session", "campaign started", "report written", "trackcal version", "cell"):
        assert fact in cells, fact
    assert "2026-12-01 10:00 UTC" in cells and "kr270" in cells
    sentence = text.split("id='verdict'>")[1].split("</p>")[0]
    assert "fits to the noise floor" in sentence and "no non-geometric effect" in sentence
    # the headline's figure is the one the console and model.json give and the fit verdict judges (RSS / dof), not
    # Table 9's plain RMS (RSS / n) under the same label
    a = outcome.result.residuals
    rms_dof = np.sqrt(np.sum(a**2) / outcome.result.dof)
    assert f"residual RMS {rms_dof * 1000:.1f} µm per coordinate" in sentence
    assert f"{outcome.doc['residual_rms_mm'] * 1000:.1f}" == f"{rms_dof * 1000:.1f}"
    # and the facts table's a-posteriori sigma of a tracker-weighted fit is that same figure
    assert f"{rms_dof * 1000:.1f} (residual RMS over the degrees of freedom; tracker weighting)" in cells
    assert "trackcal compensate --model model.json" in text.split("What next")[1]
    assert "re-plan" not in text  # the verdict names no cause the plan could have missed
    warnings = text.split("Campaign warnings")[1]
    planned = len(table) + 1  # the table's measurements and the one skipped
    assert (
        f"1 of {planned} planned measurements skipped, all at station S1 (point P2; pose Q5) because: beam broken"
        in warnings
    )
    assert "t = 748 s: P2 not measurable from S1 at Q5" in warnings.split("every warning as raised (1)")[1]
    assert "(um)" not in text and " um " not in text


def test_skipped_measurements_are_counted_and_grouped_by_station_and_reason():
    # the engine's words (campaign.engine.engine.Engine._measure) as a `trackcal mock` campaign raised them: two
    # attempts per measurement, the second one skips; only the searched position differs between the points
    why = (
        "tracker 127.0.0.1:41455: not ready to measure: no reflector locked (beam broken or reflector not found) "
        "while searching the reflector near ({}) mm (code 10004)"
    )
    near = {"P1": "4361.280, -1007.061, -260.764", "P2": "4486.365, -1123.017, -339.846"}
    warnings = [
        f"t = {2 + 10 * k} s: {p} not measurable from S1 at Q1: {why.format(near[p])}; {then}"
        for k in range(3)
        for p in ("P1", "P2")
        for then in ("looking again", "skipped here")
    ]
    warnings += [
        "t = 90 s: P3 not measurable from S2 at Q4: beam broken; skipped here",
        "t = 88 s: the cell door opened: motion blocked until resumed",
        "t = 95 s: the cell door opened: motion blocked until resumed",
    ]
    lines = summarise_warnings(warnings, measured=113)
    assert lines[0].startswith(
        "7 of 120 planned measurements skipped, 6 at station S1 (point P1 ×3, P2 ×3; pose "
        "Q1 ×6) because: tracker 127.0.0.1:41455: not ready to measure: no reflector locked"
    )
    assert (
        "near where the model expects it (code 10004); 1 at station S2 (point P3; pose Q4) because: beam broken."
        in lines[0]
    )
    assert lines[1:] == ["the cell door opened: motion blocked until resumed (2 times)"]


def test_a_named_cause_brings_the_replan_advice(kr270, campaign, tmp_path):
    d, table, outcome, plan, verdict = campaign
    backlash = dict(verdict, cause="backlash", extended={"rms_mm": 0.0149})
    text = render(tmp_path / "rep", kr270, table, outcome.doc, plan, backlash, PROV, WARNINGS).read_text()
    sentence = text.split("id='verdict'>")[1].split("</p>")[0]
    assert "shows backlash" in sentence and "15.0" in sentence and "14.9" in sentence
    advice = text.split("What next")[1].split("<h2")[0]
    assert "backlash has no static compensation" in advice
    # twice the plan's configurations, same repeat: `trackcal plan` for the cell the session used
    assert f"trackcal plan --cell kr270 --configs {2 * len(plan['poses_deg'])} --repeat 1" in advice
    assert "both directions" in advice


def test_text_is_escaped(report):
    text = report.read_text()
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
    text = render(out, kr270, table, outcome.doc, None, None, Provenance(), extra_images=[extra]).read_text()
    assert "No plan given" in text
    assert 'title="parameters.png"' in text and text.count("data:image/png") == 4  # 2 residual plots, 2 parameters
    assert base64.b64encode(extra.read_bytes()).decode() in text
    assert (out / "extra" / "parameters.png").read_bytes() == extra.read_bytes()
    assert (out / "parameters.png").read_bytes() != extra.read_bytes()


def test_cli_report(campaign, tmp_path, capsys):
    d, *_ = campaign
    out = tmp_path / "cli"
    argv = [
        "report",
        "--table",
        str(d / "table.csv"),
        "--model",
        str(d / "model.json"),
        "--plan",
        str(d / "plan.json"),
        "--verdict",
        str(d / "verdict.json"),
        "--out",
        str(out),
    ]
    assert main(argv) == 0
    assert "report written to" in capsys.readouterr().out
    text = (out / "report.html").read_text()
    sources = re.findall(r'src="([^"]+)"', text)
    assert "kr270" in text and sources and all(src.startswith("data:image/png;base64,") for src in sources)


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


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"cause": False}, "cause: expected a name, got False"),  # found by test_cli_fuzz: it crashed the report
        ({"cause": "bumped"}, "cause: expected one of"),
        ({"cause": "backlash", "extended": {}}, "cause backlash without extended.rms_mm"),
        ({"causes": [{"cause": "backlash", "gain_mm": "x"}]}, "causes[0].gain_mm: expected a number"),
        ({"candidates": [{"cause": "backlash", "n_params": 2.5}]}, "candidates[0].n_params: expected an integer"),
        ({"noise_note": ["a"]}, "noise_note: expected a name"),
    ],
)
def test_a_verdict_the_report_cannot_quote_is_refused_in_one_line(campaign, tmp_path, capsys, change, message):
    d, *_, verdict = campaign
    bad = tmp_path / "verdict.json"
    bad.write_text(json.dumps({**verdict, **change}))
    argv = [
        "report",
        "--table",
        str(d / "table.csv"),
        "--model",
        str(d / "model.json"),
        "--verdict",
        str(bad),
        "--out",
        str(tmp_path / "o"),
    ]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: ") and message in err, err
    assert not (tmp_path / "o" / "report.html").exists()


def test_report_embeds_the_diagnosis_plots(kr270, campaign, tmp_path):
    d, table, outcome, plan, _ = campaign
    diag = diagnose(kr270.chain, table, kr270.tool_points, choose_params(kr270, None), TrackerNoise(), folds=3)
    out = tmp_path / "rep"
    text = render(
        out,
        kr270,
        table,
        outcome.doc,
        plan,
        verdict_doc(kr270, diag, sha256_of(table.source)),
        Provenance(),
        diagnosis=diag,
    ).read_text()
    for name in ("signature.png", "structure.png"):
        assert f'title="{name}"' in text and (out / "diagnosis" / name).is_file()
    assert f"Cause: <b>{diag.cause}</b>" in text


def test_files_of_different_campaigns_are_refused(kr270, campaign, tmp_path, capsys):
    d, table, *_ = campaign
    _, other = kr270_campaign(kr270, seed=42, n_poses=30)  # another campaign: other poses, other noise
    write_table(other, tmp_path / "other.csv")
    other_plan = tmp_path / "other-plan.json"
    other_plan.write_text(json.dumps({"poses_deg": [[0.0, -90.0, 90.0, 0.0, 45.0, 0.0]], "repeat": 1}))
    other_cell = json.loads((d / "verdict.json").read_text()) | {"cell": "ur10-ipa", "table_sha256": None}
    (tmp_path / "v-cell.json").write_text(json.dumps(other_cell))
    files = {"--table": str(d / "table.csv"), "--model": str(d / "model.json"), "--out": str(tmp_path / "o")}
    cases = [
        ({"--table": str(tmp_path / "other.csv")}, "model.json: made from another table"),
        ({"--verdict": str(d / "verdict.json"), "--table": str(tmp_path / "other.csv")}, "made from another table"),
        ({"--plan": str(other_plan)}, "is no pose of this plan"),
        ({"--verdict": str(tmp_path / "v-cell.json")}, "made for cell ur10-ipa, not for kr270"),
    ]
    for change, message in cases:
        argv = ["report", *[x for kv in (files | change).items() for x in kv]]
        assert main(argv) == 2, change
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err, err
    assert not (tmp_path / "o" / "report.html").exists()


# Debian's chromium (.ci/run installs it); the flags keep it off the network and out of any profile
CHROMIUM_FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--virtual-time-budget=20000",
)
# appended to a copy of the page: after the load event each image says whether it decoded (naturalWidth > 0)
MARK_IMAGES = (
    "<script>window.addEventListener('load', () => { for (const i of document.images) "
    "i.setAttribute('data-loaded', String(i.complete && i.naturalWidth > 0)); "
    "document.body.setAttribute('data-checked', 'yes'); });</script>"
)


def rendered_dom(html_path: Path, tmp_path: Path) -> str:
    chromium = shutil.which("chromium")
    if chromium is None:
        if os.environ.get("CI") == "true":
            pytest.fail("chromium is missing in CI: .ci/run installs Debian's chromium")
        pytest.skip("chromium is not installed (apt-get install chromium; CI installs it)")
    probe = html_path.with_name("rendered.html")  # beside the report: same relative image paths
    page = html_path.read_text(encoding="utf-8")
    probe.write_text(page.replace("</body>", MARK_IMAGES + "</body>"), encoding="utf-8")
    profile = tmp_path / "chromium-profile"
    done = subprocess.run(
        [chromium, *CHROMIUM_FLAGS, f"--user-data-dir={profile}", "--dump-dom", probe.as_uri()],
        capture_output=True,
        text=True,
        timeout=300,
        stdin=subprocess.DEVNULL,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    return done.stdout


def test_the_report_renders_in_chromium_with_its_header_verdict_and_every_image(report, tmp_path):
    dom = rendered_dom(report, tmp_path)
    assert 'data-checked="yes"' in dom  # the page loaded and the marking ran
    assert re.search(r"<h1>Calibration report: KR-270 &lt;script&gt;.*cell kr270</h1>", dom)
    assert re.search(r"id=\"verdict\">The geometric calibration fits to the noise floor", dom)
    images = re.findall(r"<img [^>]*>", dom)
    assert len(images) >= 6  # plan, 2 residual plots, parameters, 2 diagnosis plots
    assert all('data-loaded="true"' in img for img in images), [i for i in images if 'data-loaded="true"' not in i]
