"""The ISO 9283:1998 clauses trackcal cites (calib.iso9283_clauses, issue 39): the table against the standard's table
of contents, the figures citing from it, and no other clause number anywhere in the code or the pages it writes."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from trackcal.calib.iso9283 import Figure, distance_accuracy, drift, multidirectional_variation, pose_accuracy
from trackcal.calib.iso9283_clauses import CLAUSES, clause
from trackcal.campaign.report.iso9283 import DEFINITIONS

ROOT = Path(__file__).resolve().parents[2]

# ISO 9283:1998(E), second edition 1998-04-01, "Contents" (the public sample pages of the standard and of its
# adoption SIST EN ISO 9283:2003): the clause numbers and titles of clauses 6 and 7, written from that page
CONTENTS = {
    "6.1": "robot mounting",
    "6.2": "conditions prior to testing",
    "6.3": "operating and environmental conditions",
    "6.4": "displacement measurement principles",
    "6.5": "instrumentation",
    "6.6": "load to the mechanical interface",
    "6.7": "test velocities",
    "6.8": "definitions of poses to be tested and paths to be followed",
    "6.9": "number of cycles",
    "6.10": "test procedure",
    "6.11": "characteristics to be tested - applications",
    "7.1": "general description",
    "7.2": "pose accuracy and pose repeatability",
    "7.3": "distance accuracy and repeatability",
    "7.4": "position stabilization time",
    "7.5": "position overshoot",
    "7.6": "drift of pose characteristics",
    "7.7": "exchangeability",
}

# what each cited thing is, by the clause titles above (the multi-directional pose accuracy variation has no clause
# of its own in the contents: it lies within 7.2, pages 17-23, before 7.3 on page 24)
EXPECTED = {
    "warm-up": "6.2",
    "environment": "6.3",
    "load": "6.6",
    "velocities": "6.7",
    "poses": "6.8",
    "cycles": "6.9",
    "AP": "7.2",
    "RP": "7.2",
    "vAP": "7.2",
    "AD": "7.3",
    "RD": "7.3",
    "drift": "7.6",
}


def test_the_clause_table_is_the_standards_contents():
    assert {k: v[0] for k, v in CLAUSES.items()} == EXPECTED
    for number, title in CLAUSES.values():
        assert CONTENTS[number] == title


def test_the_figures_cite_the_table():
    x = np.array([[1.0, 0, 0], [3.0, 0, 0], [2.0, 1.0, 0]])
    ap, _ = pose_accuracy(x, np.zeros(3))
    ad, rd = distance_accuracy(x, x + [10.0, 0, 0], np.zeros(3), np.array([10.0, 0, 0]))
    vap = multidirectional_variation([x, x + 0.1])
    d = drift(ap, Figure(0.1, 0.0, clause("AP")))
    assert (ap.clause, ad.clause, rd.clause, vap.clause, d.clause) == (
        "ISO 9283:1998, 7.2",
        "ISO 9283:1998, 7.3",
        "ISO 9283:1998, 7.3",
        "ISO 9283:1998, 7.2",
        "ISO 9283:1998, 7.6",
    )
    cited = {c for _, _, c in DEFINITIONS if c}
    assert cited <= {clause(k) for k in CLAUSES}


CITATION = re.compile(r"9283(?::1998)?,?\s+(?:section\s+|clause\s+)?(\d+(?:\.\d+)+)")


def test_no_other_clause_number_is_cited_in_the_code_or_the_pages():
    """Every "ISO 9283:1998, N" in the code, the studies and the pages trackcal writes is a clause of the table (the
    numbers the contents confirm); README.md is the docs' to keep (it is not scanned)."""
    allowed = {v[0] for v in CLAUSES.values()}
    files = [p for d in ("calib", "campaign", "drivers", "mocks", "studies") for p in (ROOT / d).rglob("*.py")]
    files += [ROOT / "docs" / "certificate.md", ROOT / "docs" / "ur10-iso9283.md"]
    bad = []
    for path in files:
        if path.name == "iso9283_clauses.py":
            continue  # its docstring lists the numbers it replaced
        text = path.read_text(encoding="utf-8")
        bad += [
            f"{path.relative_to(ROOT)}: {m.group(0)!r}" for m in CITATION.finditer(text) if m.group(1) not in allowed
        ]
    assert not bad, "\n".join(bad)
