"""The devices' identities on the ISO 9283 report (#39): an ISO session whose hardware file states tracker serial
AT901-12345 while the tracker of the run reports 390777 keeps both identities (the `identity` document), warns once
(a `warning` document), and its report's conditions box shows each identity with its source ("read from the
device", "from the hardware file") and the mismatch, in the HTML and in the PDF's text (pdftotext).
The serials are made-up labels: only their (in)equality matters."""

import html
import re
import subprocess
from pathlib import Path

import numpy as np
import pytest
import yaml

from tests.helpers import inproc_live
from trackcal.calib.doe.iso_cube import POSE_NAMES
from trackcal.calib.iso9283 import IsoFigures, PoseFigures, distance_accuracy, pose_accuracy, pose_repeatability
from trackcal.campaign.jobs.campaign import new_session, run_session
from trackcal.campaign.jobs.iso9283 import PlanOptions, make_plan
from trackcal.campaign.jobs.iso9283_trace import traceability
from trackcal.campaign.report.iso9283 import render
from trackcal.campaign.report.pdf import html_to_pdf
from trackcal.campaign.session.session import campaign_warnings
from trackcal.drivers.interfaces import READ_FROM_DEVICE, DeviceIdentity

SEED = 4
EXAMPLE = Path(__file__).parents[3] / "configs" / "hardware" / "example-cell.yaml"
TRACKER = DeviceIdentity("390777", "AT901-LR (ES_LTSensorType 15)", "LCP firmware 3.6, emScon 3.6.0", READ_FROM_DEVICE)


@pytest.fixture(scope="module")
def tested(tmp_path_factory, kr270):
    """One ISO session of 2 cycles (in-process twin) whose hardware file names tracker AT901-12345 and its
    certificate, measured by a tracker that says it is 390777."""
    d = tmp_path_factory.mktemp("identity")
    doc = yaml.safe_load(EXAMPLE.read_text())
    doc["tracker"].update(
        {
            "serial": "AT901-12345",
            "certificate": "CAL-2026-77",
            "certificate_date": "2026-06-01",
            "certificate_due": "2999-06-01",
        }
    )
    plan = make_plan(
        PlanOptions(
            cell="kr270", json=str(d / "iso.json"), cycles=2, vap_cycles=0, load="unloaded", velocities=(100.0,)
        )
    )
    store, campaign = new_session(d / "s", "kr270", plan, "sim", SEED, hardware=(yaml.safe_dump(doc), "hw.yaml"))
    _, live = inproc_live(kr270, SEED)
    live.tracker.identity = lambda: TRACKER  # type: ignore[method-assign]  (the tracker of this run)
    assert run_session(store, campaign, live).exit_status == "success"
    yield d / "s", store
    store.close()


def test_the_session_keeps_the_identities_and_warns_once_of_the_other_tracker(tested):
    _, store = tested
    (identity,) = [e.data for e in store.events("identity")]
    assert identity["tracker"]["serial"] == "390777" and identity["tracker"]["source"] == "read from the device"
    warned = [w for w in campaign_warnings(store) if "390777" in w]
    assert len(warned) == 1 and "AT901-12345" in warned[0] and "CAL-2026-77" in warned[0]


def test_the_conditions_show_each_identity_with_its_source_and_the_mismatch(tested):
    directory, store = tested
    rows = traceability(store, directory)
    assert rows["tracker serial"] == "AT901-12345 (from the hardware file)"
    assert rows["tracker identity"] == (
        "AT901-LR (ES_LTSensorType 15), serial 390777, LCP firmware 3.6, emScon 3.6.0 (read from the device)"
    )
    assert rows["robot controller identity"].endswith("(simulated)")  # the in-process twin's robot
    assert rows["tracker serial check"].startswith("MISMATCH: the tracker reports serial number 390777")


def figures(conditions: dict[str, str]) -> IsoFigures:
    """A test's figures from synthetic clusters (the report's layout, not the twin's physics) with `conditions`."""
    rng = np.random.default_rng(1)
    cmd = np.array([[0, 0, 1000.0], [200, 200, 1200], [200, -200, 1200], [-200, -200, 800], [-200, 200, 800]])
    att = [c + rng.normal(0.0, 0.02, (30, 3)) for c in cmd]
    cov = np.eye(3) * 0.005**2
    poses = []
    for name, a, c in zip(POSE_NAMES, att, cmd, strict=True):
        ap, off = pose_accuracy(a, c, cov)
        rp, lbar, s = pose_repeatability(a, cov)
        poses.append(PoseFigures(name, len(a), ap, off, rp, lbar, s))
    ad, rd = distance_accuracy(att[1], att[3], cmd[1], cmd[3], cov, cov)
    return IsoFigures("s", False, poses, ad, rd, att, cmd, conditions)


def test_the_report_and_its_pdf_print_the_identities(tested, tmp_path):
    directory, store = tested
    rows = traceability(store, directory)
    page = render([figures(rows)], [], "model.json")
    for key, value in rows.items():  # the row's name, then its value in the test's column
        assert re.search(
            rf"<td class=l>{re.escape(html.escape(key))}</td>\s*<td class=l>"
            rf"{re.escape(html.escape(value))}</td>",
            page,
        ), key
    pdf = html_to_pdf(page, tmp_path / "r.pdf", "ISO 9283:1998 acceptance test, report R-1")
    text = " ".join(
        subprocess.run(["pdftotext", str(pdf), "-"], capture_output=True, text=True, check=True).stdout.split()
    )
    for phrase in (
        "tracker identity",
        "serial 390777",
        "read from the device",
        "MISMATCH",
        "AT901-12345 (from the hardware file)",
        "robot controller identity",
    ):
        assert phrase in text, phrase
