"""The ISO 9283 report as a certificate (issue 39): the decision rule from its definitions (ILAC-G8:09/2019 simple
acceptance, ISO 14253-1:2017 guarded acceptance), the conformity statement of the report, its id and signature
fields, and the PDF headless chromium prints of it (text extracted by pdftotext: every figure with the same digits,
the id and "page N of M" on every page)."""

from __future__ import annotations

import html as html_lib
import math
import os
import re
import shutil
import subprocess
from collections import Counter

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tests.helpers import TRACKCAL
from trackcal.calib.decision_rule import FAIL, NOT_PROVEN, PASS, DecisionError, decide
from trackcal.calib.doe.iso_cube import POSE_NAMES
from trackcal.calib.iso9283 import (
    Figure,
    IsoFigures,
    PoseFigures,
    distance_accuracy,
    multidirectional_variation,
    pose_accuracy,
    pose_repeatability,
)
from trackcal.campaign.errors import OptionError
from trackcal.campaign.report import iso9283 as report_iso
from trackcal.campaign.report import pdf as pdf_module
from trackcal.campaign.report.iso9283 import render, report_id
from trackcal.campaign.report.iso9283_conformity import parse_tolerances, verdicts
from trackcal.campaign.report.pdf import html_to_pdf

# --- the decision rule, hand-worked (T the upper limit, y the figure, U its expanded uncertainty; binary fractions,
# so every sum below is exact in floating point)


@pytest.mark.parametrize(
    ("y", "u", "rule", "expected"),
    [
        # simple acceptance, w = 0: y <= T passes whatever U (0.5 <= 0.5; 0.25 <= 0.5 even with U = 0.5), y > T fails
        (0.5, 0.25, "simple", PASS),
        (0.25, 0.5, "simple", PASS),
        (0.625, 0.25, "simple", FAIL),
        # guarded, w = U: y + U <= T passes (0.25 + 0.25 = 0.5), y - U > T fails (0.875 - 0.25 = 0.625 > 0.5)
        (0.25, 0.25, "guarded", PASS),
        (0.875, 0.25, "guarded", FAIL),
        # the interval straddles T: 0.375 + 0.25 = 0.625 > 0.5 but 0.375 - 0.25 = 0.125 <= 0.5, neither proven
        (0.375, 0.25, "guarded", NOT_PROVEN),
        # y - U = 0.75 - 0.25 = 0.5 is not above T: non-conformity not proven; simple acceptance fails the same figure
        (0.75, 0.25, "guarded", NOT_PROVEN),
        (0.75, 0.25, "simple", FAIL),
        # no stated U: guarded acceptance proves nothing, simple acceptance goes by the value
        (0.25, math.nan, "guarded", NOT_PROVEN),
        (0.25, math.nan, "simple", PASS),
    ],
)
def test_decision_rule_by_hand(y, u, rule, expected):
    assert decide(y, u, 0.5, rule) == expected


@given(st.floats(0, 10), st.floats(0, 5), st.floats(0.01, 10))
def test_guarded_acceptance_never_contradicts_simple_and_is_simple_at_zero_uncertainty(y, u, limit):
    """A guarded pass is a simple pass and a guarded fail a simple fail (the conformity zone lies inside the
    tolerance zone, the non-conformity zone outside it); with U = 0 the guard band is 0: the two rules agree."""
    guarded, simple = decide(y, u, limit, "guarded"), decide(y, u, limit, "simple")
    assert guarded in (NOT_PROVEN, simple)
    assert decide(y, 0.0, limit, "guarded") == simple


def test_decision_rule_refuses_an_unknown_rule_or_limit():
    with pytest.raises(DecisionError):
        decide(0.1, 0.01, 0.5, "lenient")
    with pytest.raises(DecisionError):
        decide(0.1, 0.01, 0.0, "simple")


def test_tolerances_are_parsed_or_refused_in_one_line():
    assert parse_tolerances("AP=0.5,RP=0.1") == {"AP": 0.5, "RP": 0.1}
    assert parse_tolerances(None) == {}
    for bad in ("AP=abc", "XY=0.5", "AP=-1", "AP=0.5,AP=0.2", "AP", "AP=nan"):
        with pytest.raises(OptionError) as err:
            parse_tolerances(bad)
        assert "\n" not in str(err.value)


# --- a test's figures from synthetic clusters (the report's layout, not the twin's physics)


def synthetic(session: str, compensated: bool, offset_mm: float, seed: int) -> IsoFigures:
    rng = np.random.default_rng(seed)
    cmd = np.array([[0, 0, 1000.0], [200, 200, 1200], [200, -200, 1200], [-200, -200, 800], [-200, 200, 800]])
    att = [c + rng.normal(0.0, 0.02, (30, 3)) + rng.normal(0.0, offset_mm, 3) for c in cmd]
    cov = np.eye(3) * 0.005**2  # 5 µm per axis, the tracker's noise
    poses = []
    for name, a, c in zip(POSE_NAMES, att, cmd, strict=True):
        ap, off = pose_accuracy(a, c, cov)
        rp, lbar, s = pose_repeatability(a, cov)
        poses.append(PoseFigures(name, len(a), ap, off, rp, lbar, s))
    ad, rd = distance_accuracy(att[1], att[3], cmd[1], cmd[3], cov, cov)
    vap = {"P1": multidirectional_variation([att[0], att[0] + 0.01], [cov, cov])}
    return IsoFigures(
        session,
        compensated,
        poses,
        ad,
        rd,
        att,
        cmd,
        {"load": "10 kg, 100 % rated"},
        [],
        vap,
        {"P1": {"-x": att[0], "-y": att[0]}},
    )


@pytest.fixture(scope="module")
def tests_pair():
    return [synthetic("before", False, 0.4, 1), synthetic("after", True, 0.05, 2)]


TOLERANCES = {"AP": 0.1, "RP": 0.1, "AD": 0.5, "vAP": 0.02}


@pytest.fixture(scope="module")
def page(tests_pair):
    """The report page with its conformity statement (rendered once: its five cluster figures take seconds)."""
    return render(tests_pair, [], "model.json", ("guarded", TOLERANCES, verdicts(tests_pair, TOLERANCES, "guarded")))


def test_verdicts_of_every_toleranced_figure(tests_pair):
    t = tests_pair[0]
    t_neg = IsoFigures(
        t.session,
        t.compensated,
        t.poses,
        Figure(-0.3, 0.01, t.ad.clause),
        t.rd,
        t.attained_mm,
        t.commanded_mm,
        t.conditions,
    )
    found = verdicts([t_neg], {"AP": 10.0, "AD": 0.25, "vAP": 1.0}, "guarded")
    assert [v.figure for v in found] == [f"AP_P {n}" for n in POSE_NAMES] + ["|AD_P|"]  # no vAP test: no vAP verdict
    ad = found[-1]
    # |AD_P| = 0.3 mm against 0.25 mm: 0.3 - 0.01 = 0.29 > 0.25, non-conformity proven
    assert (ad.value_mm, ad.verdict) == (0.3, FAIL)
    with pytest.raises(OptionError):
        verdicts([t], {"AP": 1.0}, "lenient")


def test_the_report_states_the_rule_the_verdicts_its_id_and_signature_fields(tests_pair, page, monkeypatch):
    assert "guarded acceptance (ISO 14253-1:2017" in page and "Conformity statement" in page
    # 2 tests x (AP and RP at 5 poses, AD, vAP at P1)
    assert page.count("<td class='l pass'>pass</td>") + page.count("<td class='l fail'>fail</td>") + page.count(
        "<td class='l open'>not proven</td>"
    ) == 2 * (2 * 5 + 2)
    rid = report_id(tests_pair)
    assert re.fullmatch(r"ISO9283-[0-9A-F]{10}", rid) and rid in page
    assert report_id([synthetic("before", False, 0.4, 1), synthetic("after", True, 0.05, 2)]) == rid
    assert report_id(tests_pair[:1]) != rid
    for field in ("Name", "Role", "Date", "Signature", "Tested by", "Authorised by"):
        assert f">{field}<" in page
    monkeypatch.setattr(report_iso, "cluster_figure", lambda tests, i: "")  # the images are not what this checks
    assert "Conformity statement" not in report_iso.render(tests_pair, [], "model.json")


# --- the PDF


def tools() -> tuple[str, str]:
    chromium, pdftotext = shutil.which("chromium"), shutil.which("pdftotext")
    if chromium is None or pdftotext is None:
        if os.environ.get("CI") == "true":
            pytest.fail("chromium or pdftotext is missing in CI: .ci/run installs chromium and poppler-utils")
        pytest.skip("chromium or pdftotext is not installed (apt-get install chromium poppler-utils)")
    return chromium, pdftotext


NUMBER = re.compile(r"-?\d+(?:\.\d+)?")


def page_numbers(page: str) -> Counter:
    """Every number the page shows as text (not in its images or its style)."""
    body = re.sub(r"<style>.*?</style>|src='[^']*'|<[^>]+>", " ", page, flags=re.S)
    return Counter(NUMBER.findall(html_lib.unescape(body)))


def test_the_pdf_holds_every_figure_of_the_page_with_page_numbers_and_the_id(tests_pair, page, tmp_path):
    _, pdftotext = tools()
    rid = report_id(tests_pair)
    pdf = html_to_pdf(page, tmp_path / "iso.pdf", f"ISO 9283:1998 acceptance test, report {rid}")
    assert pdf.read_bytes().startswith(b"%PDF-")
    text = subprocess.run([pdftotext, "-layout", str(pdf), "-"], capture_output=True, text=True, check=True).stdout
    pages = text.split("\f")
    pages = [p for p in pages if p.strip()]
    assert len(pages) >= 2
    for i, p in enumerate(pages, 1):  # the footer of every page: the report's id and "page i of n"
        assert rid in p and f"page {i} of {len(pages)}" in p, p[-300:]
    shown = page_numbers(page)
    printed = Counter(NUMBER.findall(text))
    missing = {n: c - printed[n] for n, c in shown.items() if printed[n] < c}
    assert not missing, missing
    for field in ("Name", "Role", "Date", "Signature", "Authorised by"):
        assert field in text


def test_cli_refuses_a_bad_tolerance_in_one_line(tmp_path):
    done = subprocess.run(
        [*TRACKCAL, "iso9283", "compare", "nosuch", "--model", "m.json", "--tolerance", "AP=x"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
    )
    assert done.returncode == 2 and done.stderr.count("\n") == 1 and "--tolerance" in done.stderr, done.stderr


def test_no_chromium_is_one_line_naming_the_package(tmp_path, monkeypatch):
    monkeypatch.setattr(pdf_module.shutil, "which", lambda name: None)
    with pytest.raises(pdf_module.PdfError) as err:
        html_to_pdf("<p>1</p>", tmp_path / "x.pdf", "id")
    assert "\n" not in str(err.value) and "apt-get install chromium" in str(err.value)
    assert not (tmp_path / "x.pdf").exists()
