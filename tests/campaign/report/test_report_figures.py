"""An independent check of every figure of the campaign report: small simulated campaigns with each cause of
mocks/effects.py (two in the default run, every one under `slow`) are run and analysed as `trackcal run` does, the
report's HTML is parsed, and each number it shows is computed again by a second route from the session's own
files: direct forward kinematics of model.json and model-geometric.json (calib.model.kinematics, not the solver's
predict_points) on table.csv read with the csv module, the residual statistics with numpy, the noise floor from
the repeats with numpy, the times and skips from session.sqlite with sqlite3; the TCP difference at the test pose
also from `trackcal predict`'s function. Any disagreement fails. The page is also rendered in headless Chromium
and its screenshot saved in the test's folder (the path is printed): look at it."""

import base64
import csv
import json
import re
import shutil
import sqlite3
import subprocess
from datetime import UTC, datetime
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

from tests.helpers import feasible_plan
from trackcal.calib.diagnose.noise_floor import CLOSE_IN_TIME, MIN_FLOOR_DOF
from trackcal.calib.io.table import read_table
from trackcal.calib.model.kinematics import Kinematics
from trackcal.calib.model.params import param_by_name
from trackcal.calib.model_file import model_from_doc, predict_table
from trackcal.calib.tcp_figure import tcp_rows
from trackcal.campaign.cli.blas import limited_blas
from trackcal.campaign.engine.engine import Live
from trackcal.campaign.jobs.campaign import new_session, run_stored
from trackcal.campaign.jobs.end_of_run import analyse_session
from trackcal.campaign.jobs.plan import PlanOptions, plan
from trackcal.campaign.report.html import HOLDOUT_TRUST
from trackcal.mocks.cell import World
from trackcal.mocks.effects import CAUSES
from trackcal.mocks.inproc import InprocCellIO, InprocRobot, InprocTracker, SimOperator
from trackcal.mocks.twin import Twin

# 0.05 mm: the magnitude of the issue's campaign (`run --sim --effect backlash:0.05`), ~3x the tracker's noise
MAGNITUDE_MM = 0.05
DEFAULT = ("none", "backlash")
SLOW = tuple(c for c in CAUSES if c not in DEFAULT)
# the report prints µm with one decimal: half a unit of the last digit, plus float noise
ROUNDING_UM = 0.05 + 1e-6


class Tables(HTMLParser):
    """Every table of the page as rows of cell texts, with the h2 heading it stands under; the verdict sentence;
    the image sources; the text of the page."""

    def __init__(self):
        super().__init__()
        self.tables, self.images, self.text = [], [], []
        self.heading, self._in, self._row, self._cell, self._verdict = "", [], None, None, None
        self.verdict = ""

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        self._in.append(tag)
        if tag == "table":
            self.tables.append((self.heading, []))
        elif tag == "tr":
            self._row = []
        elif tag in ("td", "th"):
            self._cell = []
        elif tag == "img":
            self.images.append(a["src"])
        elif tag == "h2":
            self.heading = ""
        elif tag == "p" and a.get("id") == "verdict":
            self._verdict = []

    def handle_endtag(self, tag):
        if self._in:
            self._in.pop()
        if tag in ("td", "th") and self._cell is not None:
            self._row.append("".join(self._cell).strip())
            self._cell = None
        elif tag == "tr" and self._row is not None:
            self.tables[-1][1].append(self._row)
            self._row = None
        elif tag == "p" and self._verdict is not None:
            self.verdict, self._verdict = "".join(self._verdict), None

    def handle_data(self, data):
        self.text.append(data)
        if self._cell is not None:
            self._cell.append(data)
        if self._verdict is not None:
            self._verdict.append(data)
        if self._in and self._in[-1] == "h2":
            self.heading += data

    def table(self, heading: str, index: int = 0) -> list[list[str]]:
        return [rows for h, rows in self.tables if h.startswith(heading)][index]

    def facts(self, heading: str = "", index: int = 0) -> dict[str, str]:
        return {r[0]: r[1] for r in self.table(heading, index) if len(r) == 2}


# ------------------------------------------------------------------------------------------ the second route
def read_csv(path: Path) -> dict[str, list[str]]:
    with open(path, newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh))
    return {name: [r[k] for r in rows[1:]] for k, name in enumerate(rows[0])}


def approach(q: np.ndarray) -> np.ndarray:
    """The sign of each joint's last move before each row (0 before its first): the backlash's side."""
    out, state = np.zeros_like(q), np.zeros(q.shape[1])
    for r in range(1, len(q)):
        d = q[r] - q[r - 1]
        state = np.where(np.abs(d) > 1e-7, np.sign(d), state)
        out[r] = state
    return out


def forward(chain, doc: dict, q_deg: np.ndarray, points: list[str], stations: list[str]) -> np.ndarray:
    """The model file's reflector positions in each row's station frame by direct forward kinematics: its
    parameter values (mm, deg) on the nominal chain, its points, its stations; backlash as half its value times the
    approach side of each joint."""
    pars = doc["parameters"]
    params = [param_by_name(chain, n) for n in pars]
    dev = np.array([pars[n]["value"] if pars[n]["unit"] == "mm" else np.radians(pars[n]["value"]) for n in pars])
    q = np.radians(q_deg)
    ext = doc.get("extension", {})
    if ext.get("cause") == "backlash":
        b = np.radians([ext["parameters"].get(f"b{j + 1}", {"value": 0.0})["value"] for j in range(chain.dof)])
        q = q + 0.5 * approach(q) * b
    tool = np.array([doc["tool_points"][p]["xyz_mm"] for p in points])
    base = Kinematics(chain, params).points(q, tool, dev)
    rot = np.array([doc["stations"][s]["rotation"] for s in stations])
    t = np.array([doc["stations"][s]["translation_mm"] for s in stations])
    return np.einsum("nij,nj->ni", rot, base) + t


def predicted(chain, doc: dict, cols: dict, table) -> np.ndarray:
    """The model's prediction of every row of the table: direct forward kinematics for a geometric or backlash
    model, `trackcal predict`'s function for the other extensions (their features are the model's own)."""
    cause = doc.get("extension", {}).get("cause", "none")
    if cause in ("none", "backlash"):
        q = np.array([[float(cols[f"q{j + 1}_deg"][r]) for j in range(chain.dof)] for r in range(len(cols["seq"]))])
        return forward(chain, doc, q, cols["point"], cols["station"])
    return predict_table(model_from_doc(doc), table).xyz


def stats(r: np.ndarray) -> dict[str, float]:
    """Paper Table 9: coordinate-based (every |x|, |y|, |z|) and distance-based (3-D norms), max and RMS, µm."""
    coord, dist = np.abs(r).ravel(), np.linalg.norm(r, axis=1)
    return {
        "coordinate-based, max": coord.max(),
        "coordinate-based, RMS": np.sqrt(np.mean(coord**2)),
        "distance-based, max": dist.max(),
        "distance-based, RMS": np.sqrt(np.mean(dist**2)),
    }


def floor_from_repeats(cols: dict, q_deg: np.ndarray) -> float | None:
    """The tracker's scatter pooled over repeats of one pose, station, point and approach side close in time
    (README: the noise floor), µm per coordinate; None with too few repeats."""
    t, xyz = np.array(cols["t_s"], float), np.array([cols[c] for c in ("x_mm", "y_mm", "z_mm")], float).T
    side = approach(np.radians(q_deg))
    groups: dict[tuple, list[int]] = {}
    for i, key in enumerate(zip(cols["pose"], cols["station"], cols["point"], map(tuple, side), strict=True)):
        groups.setdefault(key, []).append(i)
    ss, dof, span = 0.0, 0, float(np.ptp(t))
    for rows in groups.values():
        rows = sorted(rows, key=lambda r: t[r])
        clusters, cluster = [], [rows[0]]
        for r in rows[1:]:
            if t[r] - t[cluster[0]] <= CLOSE_IN_TIME * span:
                cluster.append(r)
            else:
                clusters.append(cluster)
                cluster = [r]
        clusters.append(cluster)
        for c in clusters:
            if len(c) > 1:
                ss += float(np.sum((xyz[c] - xyz[c].mean(axis=0)) ** 2))
                dof += len(c) - 1
    return 1000.0 * np.sqrt(ss / (3 * dof)) if dof >= MIN_FLOOR_DOF else None


def number(text: str) -> float:
    """The number a cell starts with (a sign kept, a ± dropped)."""
    return float(re.match(r"\s*([-+]?[0-9.]+(?:e[-+]?\d+)?)", text.replace("±", "")).group(1))


def close(shown: str, value: float, digits: int = 1) -> bool:
    return abs(number(shown) - value) <= 0.5 * 10.0**-digits + 1e-6 * max(1.0, abs(value))


# ------------------------------------------------------------------------------------------ the campaigns
def run_campaign(kr270, directory: Path, effect: str, seed: int = 1, plan_doc: dict | None = None):
    """`plan_doc`, default 6 random feasible configurations measured 3 times (the size of the README's `trackcal plan
    --configs 6 --repeat 3`, said to be for the cell's plan parameters), on the twin with `effect`, analysed as at
    the end of `trackcal run`."""
    doc = plan_doc or feasible_plan(kr270, 6, seed=11, repeat=3) | {"params": list(kr270.plan_params)}
    effects = {} if effect == "none" else {effect: MAGNITUDE_MM}
    store, _ = new_session(directory, "kr270", doc, "sim", seed, effects=effects)
    world = World(Twin(kr270, seed=seed, effects=effects))
    run_stored(
        store, Live(InprocTracker(world), InprocRobot(world), SimOperator(world), world.clock, InprocCellIO(world))
    )
    analysis = analyse_session(store)
    store.close()
    return analysis


def screenshot(html: Path, out: Path) -> Path | None:
    """The page as headless Chromium draws it (None when Debian's chromium is not installed)."""
    chromium = shutil.which("chromium")
    if chromium is None:
        return None
    done = subprocess.run(
        [
            chromium,
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--no-first-run",
            f"--user-data-dir={out.parent / 'chromium-profile'}",
            f"--screenshot={out}",
            "--window-size=1280,5600",
            html.as_uri(),
        ],
        capture_output=True,
        text=True,
        timeout=300,
        stdin=subprocess.DEVNULL,
    )
    assert done.returncode == 0 and out.is_file(), done.stderr[-2000:]
    return out


def check_report(kr270, analysis, tmp_path: Path) -> None:
    files = analysis.files
    d = files.directory
    html = files.report / "report.html"
    page = Tables()
    page.feed(html.read_text(encoding="utf-8"))
    text = "".join(page.text)
    cols = read_csv(files.table)
    table = read_table(files.table, chain=kr270.chain)
    chain = kr270.chain
    q = np.array([[float(cols[f"q{j + 1}_deg"][r]) for j in range(chain.dof)] for r in range(len(cols["seq"]))])
    xyz = np.array([cols[c] for c in ("x_mm", "y_mm", "z_mm")], float).T
    model = json.loads(files.model.read_text())
    geometric = json.loads(files.geometric_model.read_text()) if files.geometric_model.exists() else model
    verdict = json.loads(files.verdict.read_text())
    planned = json.loads(files.plan.read_text())["params"]

    # the header's facts: counts from the table, times from the event store
    facts = page.facts()
    assert "" not in [r[0] for r in page.table("")[:1]]  # no empty header row
    assert facts["measurements"] == str(len(cols["seq"]))
    assert facts["configurations"] == str(len(set(cols["pose"])))
    assert facts["stations"] == ", ".join(dict.fromkeys(cols["station"]))
    with sqlite3.connect(d / "session.sqlite") as db:
        walls = [r[0] for r in db.execute("SELECT t_wall FROM events ORDER BY id")]
        skipped = sum(
            "skipped here" in json.loads(r[0])["message"]
            for r in db.execute("SELECT data FROM events WHERE kind = 'warning'")
        )
    assert facts["campaign started"] == datetime.fromtimestamp(walls[0], UTC).strftime("%Y-%m-%d %H:%M UTC")
    assert facts["campaign ended"] == datetime.fromtimestamp(walls[-1], UTC).strftime("%Y-%m-%d %H:%M UTC")
    minutes, seconds = divmod(round(walls[-1] - walls[0]), 60)
    assert facts["duration"] == f"{minutes} min {seconds:02d} s", facts["duration"]
    # the one noise floor, per coordinate and for a 3-D distance
    floor = floor_from_repeats(cols, q)
    if floor is not None:
        shown = facts["noise floor (µm)"]
        assert close(shown, floor), (shown, floor)
        assert close(shown.split(";")[1], np.sqrt(3.0) * floor), shown  # √3 x the per-coordinate floor
    # Table 9: after = table - model by direct kinematics; before = identify's own document of the nominal robot
    after = xyz - predicted(chain, model, cols, table)
    rows = {r[0]: r[1:] for r in page.table("Residuals before and after")[1:]}
    for label, value in stats(after).items():
        before = (
            1000.0
            * model["residuals"]["before"][
                {
                    "coordinate-based, max": "coord_max_mm",
                    "coordinate-based, RMS": "coord_rms_mm",
                    "distance-based, max": "dist_max_mm",
                    "distance-based, RMS": "dist_rms_mm",
                }[label]
            ]
        )
        b, a, factor = rows[label]
        assert close(a, 1000.0 * value), (label, a, 1000.0 * value)
        assert close(b, before), (label, b, before)
        assert close(factor, before / (1000.0 * value)) or abs(number(factor) - number(b) / number(a)) < 0.06
    # Table 8: the model's parameters, significance and whether the plan was made for them
    for name, unit, _, value, ci, significant, in_plan in page.table("Identified parameters")[1:]:
        p = model["parameters"][name]
        assert unit == p["unit"] and close(value, p["value"], 4) and close(ci, p["ci95"], 4), name
        assert significant == ("yes" if abs(p["value"]) > p["ci95"] else "no")
        assert in_plan == ("yes" if name in planned else "no")
    # the verdict sentence and the diagnosis: each model's RMS by direct kinematics of its own file
    geo_rms = 1000.0 * np.sqrt(np.mean((xyz - predicted(chain, geometric, cols, table)) ** 2))
    ext_rms = 1000.0 * np.sqrt(np.mean(after**2))
    diag = page.facts("Diagnosis")
    assert close(diag["geometric model RMS (µm, per coordinate)"], geo_rms)
    if verdict["cause"] in ("none", "unexplained"):
        assert diag["extended model RMS (µm, per coordinate)"] == "- (no cause chosen)"
    else:
        assert close(diag["extended model RMS (µm, per coordinate)"], ext_rms)
    assert f"{geo_rms:.1f}" in page.verdict or verdict["cause"] == "none"
    if verdict["cause"] not in ("none", "unexplained"):
        assert f"{ext_rms:.1f}" in page.verdict
    assert f"noise floor of {number(facts['noise floor (µm)']):.1f} µm" in page.verdict
    # held-out figures: the verdict's, or not shown when over HOLDOUT_TRUST x the fit RMS
    hold = verdict["holdout"]
    for label, key, fit in (("geometric", "rms_geometric_mm", geo_rms), ("extended", "rms_extended_mm", ext_rms)):
        shown, value = diag[f"held-out RMS, {label} (µm)"], hold.get(key)
        if value is None or 1000.0 * value > HOLDOUT_TRUST * fit * (1 + 1e-6):
            assert shown == "-", (label, shown)
        else:
            assert close(shown, 1000.0 * value), (label, shown, value)
    # the candidates: every step, no figure for a candidate with nothing fitted or an unsupported held-out scheme
    cands = page.table("Diagnosis", 1)
    assert cands[0][:3] == ["step", "candidate", "params"]
    assert len(cands) - 1 == len(verdict["candidates"])
    for row, c in zip(cands[1:], verdict["candidates"], strict=True):
        assert row[0] == str(c["step"]) and row[1] == c["cause"] and row[2] == str(c["n_params"])
        if c["n_params"] == 0:
            assert row[3] == row[4] == "-" and "not fitted" in row[8]
            continue
        h = c.get("holdout_rms_mm")
        if h is None or h > HOLDOUT_TRUST * c["rms_mm"]:
            assert row[3] == "-"
        else:
            assert close(row[3], 1000.0 * h)
        assert close(row[4], 1000.0 * c["rms_mm"])
    # the TCP difference at the test pose: direct kinematics of the two model files, and `trackcal predict`'s
    if model is not geometric:
        station = sorted(geometric["stations"])[0]
        points = sorted(model["tool_points"])
        q0 = np.repeat(np.degrees(kr270.test_pose)[None], len(points), axis=0)
        tcp = [forward(chain, m, q0, points, [station] * len(points)).mean(axis=0) for m in (geometric, model)]
        # backlash at the neutral context (no approach side) is nil: the direct kinematics of the two files
        direct = float(np.linalg.norm(tcp[1] - tcp[0])) if model["extension"]["cause"] == "backlash" else None
        rows_ = tcp_rows(kr270.test_pose, points, station)
        by_predict = [predict_table(model_from_doc(m), rows_).xyz.mean(axis=0) for m in (geometric, model)]
        predicted_diff = float(np.linalg.norm(by_predict[1] - by_predict[0]))
        if direct is not None:
            assert abs(direct - predicted_diff) < 1e-6
        shown = diag[f"TCP difference at the test pose (µm, station {station} frame)"]
        value = number(shown) if shown[0].isdigit() else number(re.search(r"differ by ([0-9.]+) µm", shown)[1])
        assert abs(value - 1000.0 * predicted_diff) <= ROUNDING_UM, (shown, 1000.0 * predicted_diff)
        assert abs(verdict["test_pose"]["tcp_difference_mm"] - predicted_diff) < 1e-6
        if not verdict["test_pose"]["determined"]:
            assert shown.startswith("not determined by this campaign")
    else:
        assert "TCP difference" not in text
    # what next names the cell; the warnings count the skips the event store holds
    advice = text.split("What next")[1].split("Campaign warnings")[0]
    assert "--cell  " not in text and "--cell kr270 " in advice if "re-plan" in advice else "--cell" not in advice
    if skipped:
        assert f"{skipped} of {len(cols['seq']) + skipped} planned measurements skipped" in text
    # every figure is in the page
    assert len(page.images) >= 5
    for src in page.images:
        assert src.startswith("data:image/png;base64,")
        assert base64.b64decode(src.split(",", 1)[1])[:8] == b"\x89PNG\r\n\x1a\n"
    shot = screenshot(html, tmp_path / f"report-{d.name}.png")
    print(f"report {html}; screenshot {shot or 'not taken (chromium is not installed)'}")


@pytest.mark.parametrize("effect", DEFAULT)
def test_every_figure_of_the_report_agrees_with_its_second_computation(kr270, tmp_path, effect):
    analysis = run_campaign(kr270, tmp_path / effect, effect)
    check_report(kr270, analysis, tmp_path)


@pytest.mark.slow
@pytest.mark.parametrize("effect", SLOW)
def test_every_figure_of_the_report_of_every_cause(kr270, tmp_path, effect):
    analysis = run_campaign(kr270, tmp_path / effect, effect)
    check_report(kr270, analysis, tmp_path)


# The issue's campaign ran the README's plan of 6 configurations, where diagnose can no longer name a cause: its
# held-out test is a one-sided signed-rank test per pose at 1 %, whose smallest p-value is 2^-n (every pose better),
# so it needs n >= 7 (calib/diagnose/significance.py's `attainable`: 2^-6 = 1.6 %, 2^-7 = 0.8 %). 7 is not enough
# here (diagnose said `none` on both seeds): the geometric model's held-out RMS was 23 mm, backlash's p = 0.23 (seed 1).
# Measured on this test's two seeds: 8, 9 and 10 configurations name backlash, every pose better (p = 2^-n). 10
# leaves room: at n = 10 the test passes with the worse poses' ranks summing to 5 (at 8: to 1, at 7: to 0).
ISSUE_CONFIGS = 10


@pytest.fixture(scope="module")
def issue_plan(tmp_path_factory):
    """The README's plan with ISSUE_CONFIGS configurations: `trackcal plan --cell kr270 --configs 10 --repeat 3`
    (optimised for the campaign's unknowns: 18 robot parameters, the stations and the points), searched with the
    command's BLAS threads (one by default: 12 s; with two, `trackcal plan --configs 6` took 66 s instead of 9 s)."""
    out = tmp_path_factory.mktemp("plan") / "plan.json"
    with limited_blas():
        return plan("kr270", PlanOptions(configs=ISSUE_CONFIGS, repeat=3), str(out)).doc


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2])
def test_the_backlash_campaign_of_the_issue(kr270, issue_plan, tmp_path, seed):
    # issue 25: `run --sim --effect backlash:0.05` on the README's plan showed a TCP difference at the test pose of
    # 36 mm (seed 1) and 26.7 mm (seed 2): a TCP fixed in the flange frame while each model moves its reference
    # points along the link lengths the plan does not determine
    analysis = run_campaign(kr270, tmp_path / f"backlash-{seed}", "backlash", seed=seed, plan_doc=issue_plan)
    check_report(kr270, analysis, tmp_path)
    tcp = json.loads(analysis.files.verdict.read_text())["test_pose"]
    # the second route to the truth: the twin's own reflectors at the test pose (no backlash at a pose approached
    # from nowhere), in station S1's true frame
    twin = Twin(kr270, seed=seed)
    q0 = np.degrees(kr270.test_pose)
    truth = np.mean([twin.exact(q0, p, tcp["station"]) for p in sorted(kr270.tool_points)], axis=0)
    ext_off = float(np.linalg.norm(np.array(tcp["extended_tcp_mm"]) - truth))
    geo_off = float(np.linalg.norm(np.array(tcp["geometric_tcp_mm"]) - truth))
    print(
        f"seed {seed}: TCP difference {tcp['tcp_difference_mm']:.4f} ± {tcp['sigma_mm']:.4f} mm; from the truth: "
        f"extended {ext_off:.4f} mm, geometric {geo_off:.4f} mm"
    )
    # the model that explains the cause is where the robot is, within its uncertainty (3 x the 1-sigma 3-D radius);
    # the difference says how far the geometric model is from there: a determined difference is the geometric
    # model's error at the test pose, to within the extended model's own error
    assert ext_off < 3.0 * tcp["sigma_extended_mm"], (ext_off, tcp["sigma_extended_mm"])
    assert tcp["determined"] == (tcp["tcp_difference_mm"] > 2.0 * tcp["sigma_mm"])
    if tcp["determined"]:
        assert abs(geo_off - tcp["tcp_difference_mm"]) <= ext_off + 1e-9
