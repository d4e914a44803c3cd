"""The clauses of ISO 9283:1998 that trackcal cites, in one table: the figures, the plan, the report and the CLI read
their clause from here (tests/test_iso9283_clauses.py pins the table and scans the sources for any other number).

Checked against the standard's table of contents: ISO 9283:1998(E), second edition 1998-04-01, "Contents", as the
public sample pages show it (isostandard.asia/isostandard/494440; SIST EN ISO 9283:2003 is the same text, EN ISO
9283:1998). Clause 6 "Performance testing conditions": 6.1 robot mounting, 6.2 conditions prior to testing, 6.3
operating and environmental conditions, 6.4 displacement measurement principles, 6.5 instrumentation, 6.6 load to the
mechanical interface, 6.7 test velocities, 6.8 definitions of poses to be tested and paths to be followed, 6.9 number
of cycles, 6.10 test procedure, 6.11 characteristics to be tested - applications. Clause 7 "Pose characteristics":
7.1 general description, 7.2 pose accuracy and pose repeatability (page 17), 7.3 distance accuracy and repeatability
(page 24), 7.4 position stabilization time, 7.5 position overshoot, 7.6 drift of pose characteristics, 7.7
exchangeability.

The contents list no subclauses under 7.2 and 7.3, and no clause of its own for the multi-directional pose accuracy
variation: it lies within 7.2 (pages 17-23, before 7.3 on page 24). So AP, RP and vAP cite 7.2, AD and RD cite 7.3:
the numbers the contents confirm. trackcal cited before: 6.7 for the cube (6.7 is test velocities), 6.8 for the 30
cycles (6.9), 6.2 for the load (6.6), 7.3 for vAP (7.3 is distance), 7.4 for AD and RD (7.4 is position
stabilization time), 7.7 for drift (7.7 is exchangeability; drift is 7.6), and 7.2.1, 7.2.2, 7.4.1, 7.4.2, which the
contents cannot confirm.
"""

from __future__ import annotations

STANDARD = "ISO 9283:1998"

# what trackcal cites -> (clause number, the clause's title as the contents give it)
CLAUSES: dict[str, tuple[str, str]] = {
    "warm-up": ("6.2", "conditions prior to testing"),
    "environment": ("6.3", "operating and environmental conditions"),
    "load": ("6.6", "load to the mechanical interface"),
    "velocities": ("6.7", "test velocities"),
    "poses": ("6.8", "definitions of poses to be tested and paths to be followed"),
    "cycles": ("6.9", "number of cycles"),
    "AP": ("7.2", "pose accuracy and pose repeatability"),
    "RP": ("7.2", "pose accuracy and pose repeatability"),
    "vAP": ("7.2", "pose accuracy and pose repeatability"),
    "AD": ("7.3", "distance accuracy and repeatability"),
    "RD": ("7.3", "distance accuracy and repeatability"),
    "drift": ("7.6", "drift of pose characteristics"),
}


def clause(key: str) -> str:
    """The citation of what `key` names, e.g. clause("AP") == "ISO 9283:1998, 7.2"."""
    return f"{STANDARD}, {CLAUSES[key][0]}"
