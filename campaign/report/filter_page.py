"""The page of a program's filtering (`trackcal filter`): one self-contained HTML table of its targets, rendered from
filter.json's document (campaign.jobs.filter_program): it computes nothing."""

from __future__ import annotations

from pathlib import Path

from trackcal.calib.io.files import write_text
from trackcal.campaign.errors import InputError
from trackcal.campaign.report.html import STYLE, esc, fmt, table_html

HEADER = [
    "file",
    "line",
    "name",
    "kind",
    "move",
    "status",
    "correction mm",
    "correction deg",
    "predicted mm",
    "sigma mm",
    "95 % bound mm",
    "pass",
    "why kept / flags",
]


def pass_text(value, covered=True) -> str:
    if value is None:
        return "unknown" if covered is False else "-"
    return "pass" if value else "FAIL"


def outside_text(t: dict) -> str:
    """How far a target lies outside the space the model was measured in ("" inside or unknown)."""
    if t.get("measured_space") != "outside":
        return ""
    far = [f"A{j.split('_')[1]} +{d:.1f} deg" for j, d in t["outside_joints_deg"].items()]
    far += [f"{t['outside_volume_mm']:.0f} mm out of the volume"] if t["outside_volume_mm"] else []
    return f"outside the measured space ({', '.join(far)}): bound not covered"


def filter_rows(doc: dict) -> list[list[str]]:
    """One row per target of filter.json."""
    rows = []
    for t in doc["targets"]:
        flags = [t["why"] or "", outside_text(t)]
        flags += ["outside the model's fitted joint ranges"] if t["outside_fitted_ranges"] else []
        bound = fmt(t["bound95_mm"], 4) + ("*" if t.get("bound_covered") is False else "")
        rows.append(
            [
                t["file"],
                str(t["line"]),
                t["name"],
                t["kind"],
                t["motion"] or "-",
                t["status"],
                fmt(t["correction_mm"], 4),
                fmt(t["correction_deg"], 4),
                fmt(t["predicted_mm"], 4),
                fmt(t["sigma_mm"], 4),
                bound,
                pass_text(t["pass"], t.get("bound_covered")),
                "; ".join(f for f in flags if f),
            ]
        )
    return rows


def write_filter_page(path: Path, doc: dict) -> Path:
    """filter.html of filter.json's document, written atomically."""
    tol = doc["tolerance_mm"]
    facts = [
        ["program", doc["program"]],
        ["language", doc["language"]],
        ["model", doc["model"]],
        ["targets", f"{doc['filtered']} filtered, {doc['kept']} kept as they were"],
        ["tolerance", "none given" if tol is None else f"{tol:g} mm: {doc['failed']} target(s) fail it"],
        [
            "outside the measured space",
            f"{doc.get('outside_measured', 0)} target(s): their bounds (marked *) "
            "are extrapolations, their pass/fail unknown",
        ],
    ]
    warnings = "".join(f'<p class="warn">{esc(w)}</p>' for w in doc["warnings"])
    page = (
        f'<!DOCTYPE html><html><head><meta charset="utf-8"><title>trackcal filter: {esc(doc["program"])}'
        f"</title><style>{STYLE}</style></head><body><h1>Program filtering</h1>{table_html(None, facts)}"
        f"{warnings}<h2>Targets</h2>{table_html(HEADER, filter_rows(doc), left=6)}"
        f'<p class="note">{esc(doc["note"])}</p></body></html>\n'
    )
    write_text(path, page, InputError)
    return path
