"""Issue 35: the report's plan table says what the plan was computed for: the robot parameters and, as unknowns too,
every tracker station (6 each: a translation and a rotation) and every reference point (3 each)."""

import re

from trackcal.calib.doe.design import design_for_cell
from trackcal.calib.identify.unknowns import PAPER_KNOWN, campaign_params
from trackcal.campaign.jobs.plan import unknowns_doc
from trackcal.campaign.report.html import section_plan


def plan_table(kr270, tmp_path, known=()) -> dict[str, str]:
    design = design_for_cell(kr270, campaign_params(kr270.chain), known=known)
    doc = {
        "rho0_mm": 0.004,
        "repeat": 1,
        "criterion": "rho0",
        "params": [p.name for p in design.params],
        "unknowns": unknowns_doc(design),
    }  # as `trackcal plan` writes them (no poses: no plot)
    html = section_plan(doc, kr270, tmp_path)
    cells = [re.sub("<[^>]+>", "", c) for c in re.findall(r"<t[dh][^>]*>(.*?)</t[dh]>", html)]
    return dict(zip(cells[::2], cells[1::2], strict=True))


def test_the_plan_table_names_the_stations_and_points_as_unknowns(kr270, tmp_path):
    """The KR-270 cell has stations S1, S2 and reference points P1, P2, P3 (configs/cells/kr270.yaml): one row each,
    with the count and the names."""
    rows = plan_table(kr270, tmp_path)
    assert rows["stations (6 unknowns each)"] == "2: S1 S2"
    assert rows["reference points (3 unknowns each)"] == "3: P1 P2 P3"
    assert len(rows["robot parameters"].split()) == 18  # the irreducible set (paper eq. 6)


def test_a_plan_with_stations_and_points_known_says_so(kr270, tmp_path):
    """The paper's planning assumption (section 7.2): base and tool known."""
    rows = plan_table(kr270, tmp_path, known=PAPER_KNOWN)
    assert rows["stations (6 unknowns each)"] == "known (held at nominal)"
    assert rows["reference points (3 unknowns each)"] == "known (held at nominal)"
