"""Traceability on the ISO 9283 report (#39): the tracker's serial and certificate from the session's hardware config,
a certificate past its due date on the day of the test refused for a report (one line, exit 2) unless asked, and the
item: customer, report id, the person authorising."""

import re
from pathlib import Path

import pytest
import yaml

from tests.helpers import inproc_live
from trackcal.campaign.cli import main
from trackcal.campaign.jobs.campaign import new_session, run_session
from trackcal.campaign.jobs.iso9283 import PlanOptions, make_plan

SEED = 4
EXAMPLE = Path(__file__).parents[3] / "configs" / "hardware" / "example-cell.yaml"


def hardware_text(date: str, due: str) -> str:
    doc = yaml.safe_load(EXAMPLE.read_text())
    doc["tracker"].update(
        {"serial": "AT901-12345", "certificate": "CAL-2019-77", "certificate_date": date, "certificate_due": due}
    )
    return yaml.safe_dump(doc)


@pytest.fixture(scope="module")
def tested(tmp_path_factory, kr270):
    """A calibration (simulate, identify) and two ISO sessions of 2 cycles whose hardware config names the tracker's
    certificate: one due in 2019 (the test, run today, is after it), one due in 2999."""
    d = tmp_path_factory.mktemp("trace")
    assert main(["simulate", "--cell", "kr270", "--poses", "40", "--seed", str(SEED), "--out", str(d / "t.csv")]) == 0
    assert main(["identify", str(d / "t.csv"), "--cell", "kr270", "--out", str(d / "model.json")]) == 0
    plan = make_plan(
        PlanOptions(
            cell="kr270", json=str(d / "iso.json"), cycles=2, vap_cycles=0, load="unloaded", velocities=(100.0,)
        )
    )
    for name, due in (("expired", "2019-12-31"), ("valid", "2999-12-31")):
        store, campaign = new_session(
            d / name, "kr270", plan, "sim", SEED, hardware=(hardware_text("2018-12-31", due), "hw.yaml")
        )
        assert run_session(store, campaign, inproc_live(kr270, SEED)[1]).exit_status == "success"
        store.close()
    return d


def compare(d, session, *extra):
    return main(["iso9283", "compare", str(d / session), "--model", str(d / "model.json"), *extra])


def test_expired_certificate_is_refused_for_a_report_unless_asked(tested, capsys):
    d = tested
    capsys.readouterr()
    assert compare(d, "expired", "--report", str(d / "r.html")) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "was due on 2019-12-31" in err and "--accept-expired-certificate" in err
    assert not (d / "r.html").exists()
    # figures alone (no report) are not a certificate: a warning
    assert compare(d, "expired", "--json", str(d / "e.json")) == 0
    assert "was due on 2019-12-31" in capsys.readouterr().err
    assert compare(d, "expired", "--report", str(d / "r.html"), "--accept-expired-certificate") == 0
    page = (d / "r.html").read_text(encoding="utf-8")
    assert "was due on 2019-12-31, before the test of" in page  # a note on the report itself


def test_report_states_the_tracker_and_the_item(tested):
    d = tested
    assert (
        compare(
            d,
            "valid",
            "--report",
            str(d / "v.html"),
            "--customer",
            "ACME Robotics",
            "--report-id",
            "R-2026-001",
            "--authorised-by",
            "J. Smith",
        )
        == 0
    )
    page = (d / "v.html").read_text(encoding="utf-8")
    assert "AT901-12345" in page and "CAL-2019-77, calibrated 2018-12-31, due 2999-12-31" in page
    assert "Report R-2026-001" in page and "Customer: ACME Robotics" in page
    assert re.search(r"Authorised by</td><td class=l>J\. Smith</td>", page)
    assert "was due on" not in page
