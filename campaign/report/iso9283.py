"""The ISO 9283 acceptance report: one self-contained HTML page (figures embedded as PNG data) with the conditions
of each test, the standard's figures side by side, their definitions, and per pose the cluster of attained
positions around the commanded one, before and after compensation."""

from __future__ import annotations

import base64
import hashlib
import html
import io
import json
import math
from dataclasses import dataclass
from pathlib import Path

from trackcal.calib.decision_rule import FAIL, NOT_PROVEN, PASS, RULES
from trackcal.calib.doe.iso_cube import POSE_NAMES
from trackcal.calib.io.files import write_text
from trackcal.calib.iso9283 import DISTANCE_POSES, IsoFigures
from trackcal.calib.iso9283_clauses import clause
from trackcal.campaign.errors import InputError
from trackcal.campaign.report.figures import subplots, tight
from trackcal.campaign.report.iso9283_budget import budget_section
from trackcal.campaign.report.iso9283_conformity import TOLERANCED, Verdict
from trackcal.campaign.report.iso9283_departures import departures_box
from trackcal.campaign.report.pdf import html_to_pdf

DEFINITIONS = [
    (
        "AP_P",
        "pose accuracy: |x̄ − c|, the distance from the commanded position c to the barycentre x̄ of the n "
        "attained positions",
        clause("AP"),
    ),
    ("AP_x, AP_y, AP_z", "the barycentre's offset from the commanded position along each base axis", clause("AP")),
    (
        "RP_l",
        "pose repeatability: l̄ + 3 S_l, l_j = |x_j − x̄|, S_l the sample standard deviation of the l_j",
        clause("RP"),
    ),
    (
        "vAP_P",
        "multi-directional pose accuracy variation: the largest distance between the barycentres of the "
        "positions attained when the pose is approached from three orthogonal directions parallel to the base "
        "axes",
        clause("vAP"),
    ),
    (
        "AP_a, AP_b, AP_c",
        "orientation accuracy: the mean attained orientation less the commanded one, as rotations "
        "about the base x, y, z axes; each cycle's orientation is the least-squares rigid fit of "
        "the tool's reference points, cycle j taking the j-th visit of each point",
        clause("AP"),
    ),
    (
        "RP_a, RP_b, RP_c",
        "orientation repeatability: 3 S_a, S_a the sample standard deviation of the attained angle about the axis",
        clause("RP"),
    ),
    (
        "AD_P",
        "distance accuracy: D̄ − D_c, the mean attained distance between two poses less the commanded one",
        clause("AD"),
    ),
    ("RD", "distance repeatability: 3 S_D, S_D the sample standard deviation of the attained distances", clause("RD")),
    (
        "dAP, dRP",
        "drift of pose accuracy and repeatability: |AP(first test) − AP(last test)| of tests with the same "
        "targets repeated over time, RP alike",
        clause("drift"),
    ),
    (
        "± U",
        "the figure's expanded uncertainty from its budget (section Uncertainty budget): the tracker, the "
        "calibration's station and tool point, the reflector's centring, the temperature and the robot's "
        "repeatability for AP_P and AD_P (GUM, JCGM 100:2008; AP_P and RP_l by Monte-Carlo, JCGM 101:2008); the "
        "tracker's alone (k = 2) for vAP_P, RD and the orientation figures, whose other inputs cancel",
        "",
    ),
]

STYLE = """body{font-family:sans-serif;max-width:1100px;margin:2em auto;padding:0 1.5em;color:#222}
table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #bbb;padding:4px 8px;text-align:right}
th{background:#eee}td.l,th.l{text-align:left}td:not(.l),td.c{white-space:nowrap}img{max-width:100%}
td.pass{background:#dfd}td.fail{background:#fdd}td.open{background:#ffd}table.sign td{height:2.2em;min-width:14em}
@media print{body{max-width:none;margin:0;padding:0;font-size:10pt}tr,img{break-inside:avoid}h2{break-after:avoid}}"""


def _um(value: float, u: float | None = None) -> str:
    text = f"{value * 1000:.1f}"
    return text if u is None else f"{text} ± {u * 1000:.1f}"


def _png(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def cluster_figure(tests: list[IsoFigures], i: int) -> str:
    """Pose i: one row per test, its attained positions around the commanded one (µm) in the base frame's x-y and
    x-z planes, with the barycentre marked; each row on its own scale, so the spread shows beside the offset."""
    fig, axes = subplots(len(tests), 2, figsize=(8, 3.2 * len(tests)), squeeze=False)
    for row, t in zip(axes, tests, strict=True):
        d = (t.attained_mm[i] - t.commanded_mm[i]) * 1000.0
        bar = d.mean(axis=0)
        label = "compensated" if t.compensated else "nominal"
        for ax, (a, b) in zip(row, ((0, 1), (0, 2)), strict=True):
            ax.scatter(d[:, a], d[:, b], s=12, color="tab:blue", alpha=0.6, label="attained")
            ax.plot(bar[a], bar[b], marker="x", markersize=10, color="tab:red", linestyle="", label="barycentre")
            ax.plot(0, 0, marker="+", markersize=14, color="black", linestyle="", label="commanded")
            ax.set_xlabel(f"{'xyz'[a]} − commanded (µm)")
            ax.set_ylabel(f"{'xyz'[b]} − commanded (µm)")
            ax.set_title(f"{POSE_NAMES[i]}, {label} targets", fontsize=9)
            ax.set_aspect("equal", adjustable="datalim")
            ax.locator_params(nbins=4)  # tick labels of up to five digits side by side on a 3-inch axis
            ax.grid(alpha=0.3)
        row[1].legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=8, frameon=False)
    tight(fig)
    return _png(fig)


@dataclass(frozen=True)
class Item:
    """What the report states about itself beyond the tests: the customer, its id (None: `report_id`'s digest) and
    the person authorising it (`iso9283 compare --customer --report-id --authorised-by`)."""

    customer: str | None = None
    report_id: str | None = None
    authorised_by: str | None = None


def report_id(tests: list[IsoFigures]) -> str:
    """The report's id: a digest of the figures it states (the same tests give the same id; any change, another)."""
    doc = json.dumps([t.to_doc() for t in tests], sort_keys=True, default=str).encode()
    return "ISO9283-" + hashlib.sha256(doc).hexdigest()[:10].upper()


def _conformity(rule: str, tolerances: dict[str, float], found: list[Verdict]) -> list[str]:
    out = [
        "<h2>Conformity statement</h2>",
        f"<p>Decision rule: {html.escape(RULES[rule])}.</p><p>Tolerances (upper limits): "
        + ", ".join(f"{TOLERANCED[k]} ≤ {v * 1000:g} µm" for k, v in tolerances.items())
        + ".</p>",
        "<table><tr><th class=l>test</th><th class=l>figure</th><th>value ± U (µm)</th><th>tolerance (µm)</th>"
        "<th class=l>verdict</th><th class=l>clause</th></tr>",
    ]
    css = {PASS: "pass", FAIL: "fail", NOT_PROVEN: "open"}
    for v in found:
        u = f"{v.u95_mm * 1000:.1f}" if math.isfinite(v.u95_mm) else "not stated"
        out.append(
            f"<tr><td class=l>{html.escape(v.session)} ({'compensated' if v.compensated else 'nominal'})</td>"
            f"<td class=l>{html.escape(v.figure)}</td><td>{v.value_mm * 1000:.1f} ± {u}</td>"
            f"<td>{v.limit_mm * 1000:g}</td><td class='l {css[v.verdict]}'>{v.verdict}</td>"
            f"<td class='l c'>{clause(v.key)}</td></tr>"
        )
    counts = {k: sum(v.verdict == k for v in found) for k in (PASS, FAIL, NOT_PROVEN)}
    out.append("</table><p>" + ", ".join(f"{n} {k}" for k, n in counts.items()) + f" of {len(found)} figures.</p>")
    return out


def _signatures(authorised_by: str | None = None) -> list[str]:
    names = {"Tested by": "", "Authorised by": html.escape(authorised_by or "")}
    rows = "".join(
        f"<tr><td class=l>{who}</td><td class=l>{name}</td>" + "<td></td>" * 3 + "</tr>" for who, name in names.items()
    )
    return [
        "<h2>Authorisation</h2><table class=sign><tr><th class=l></th><th class=l>Name</th><th class=l>Role</th>"
        f"<th class=l>Date</th><th class=l>Signature</th></tr>{rows}</table>"
    ]


def render(
    tests: list[IsoFigures],
    drift_list: list[dict],
    model_path: str,
    conformity: tuple[str, dict[str, float], list[Verdict]] | None = None,
    item: Item | None = None,
) -> str:
    """The report page; `conformity` (rule, tolerances, verdicts) adds the conformity statement, `item` the
    customer, the report's id and the person authorising it."""
    label = [t.label for t in tests]
    item = item or Item()
    rid = html.escape(item.report_id or report_id(tests))
    out = [
        f"<!doctype html><html><head><meta charset='utf-8'><title>ISO 9283 acceptance test {rid}</title>",
        f"<style>{STYLE}</style></head><body><h1>ISO 9283:1998 acceptance test</h1>",
        f"<p>Report {rid}</p><p>Customer: {html.escape(item.customer or 'not stated')}</p>",
    ]
    keys = list(dict.fromkeys(k for t in tests for k in t.conditions))
    out.append("<h2>Conditions of the test</h2><table><tr><th class=l></th>")
    out += [
        f"<th class=l>{html.escape(t.session)} ({'compensated' if t.compensated else 'nominal'} targets)</th>"
        for t in tests
    ]
    out.append("</tr>")
    for k in keys:
        out.append(f"<tr><td class=l>{html.escape(k)}</td>")
        out += [f"<td class=l>{html.escape(t.conditions.get(k, '-'))}</td>" for t in tests]
        out.append("</tr>")
    out.append(
        f"<tr><td class=l>base frame</td><td class=l colspan={len(tests)}>the station estimate of "
        f"{html.escape(model_path)}</td></tr></table>"
    )
    out += departures_box(tests)
    out.append("<h2>Pose characteristics (µm)</h2><table><tr><th class=l>pose</th>")
    for lab in label:
        out += [f"<th>AP_P {lab}</th><th>AP_x, AP_y, AP_z {lab}</th><th>RP_l {lab}</th>"]
    out.append("</tr>")
    for i, name in enumerate(POSE_NAMES):
        out.append(f"<tr><td class=l>{name}</td>")
        for t in tests:
            p = t.poses[i]
            xyz = ", ".join(f"{v * 1000:.1f}" for v in p.offset_mm)
            out.append(f"<td>{_um(p.ap.value, p.ap.u95)}</td><td>{xyz}</td><td>{_um(p.rp.value, p.rp.u95)}</td>")
        out.append("</tr>")
    out.append("</table>")
    out += _orientation_section(tests, label)
    a, b = DISTANCE_POSES
    out.append(f"<h2>Distance characteristics, {POSE_NAMES[a]}–{POSE_NAMES[b]} (µm)</h2><table><tr>")
    out += [f"<th>AD_P {lab}</th><th>RD {lab}</th>" for lab in label]
    out.append("</tr><tr>")
    for t in tests:
        ad = _um(t.ad.value, t.ad.u95) if t.ad else "-"
        rd = _um(t.rd.value, t.rd.u95) if t.rd else "-"
        out.append(f"<td>{ad}</td><td>{rd}</td>")
    out.append("</tr></table>")
    vap = [(t, lab) for t, lab in zip(tests, label, strict=True) if t.vap]  # at the first velocity only
    out += _vap_section([t for t, _ in vap], [lab for _, lab in vap]) + _drift_sections(drift_list)
    out += budget_section(tests)
    if conformity is not None:
        out += _conformity(*conformity)
    out.append(
        "<h2>Definitions</h2><table><tr><th class=l>figure</th><th class=l>definition</th><th class=l>clause</th></tr>"
    )
    out += [
        f"<tr><td class=l>{html.escape(n)}</td><td class=l>{html.escape(d)}</td><td class='l c'>{c}</td></tr>"
        for n, d, c in DEFINITIONS
    ]
    out.append("</table><h2>Attained positions</h2>")
    out += [f"<p><img alt='{POSE_NAMES[i]}' src='{cluster_figure(tests, i)}'></p>" for i in range(len(POSE_NAMES))]
    notes = [f"{t.session}: {n}" for t in tests for n in t.notes]
    if notes:
        out.append("<h2>Notes</h2><ul>" + "".join(f"<li>{html.escape(n)}</li>" for n in notes) + "</ul>")
    out += _signatures(item.authorised_by)
    out.append("</body></html>\n")
    return "\n".join(out)


def _orientation_section(tests: list[IsoFigures], label: list[str]) -> list[str]:
    """The orientation characteristics' table (none when no test measured orientations)."""
    out: list[str] = []
    if not any(p.orientation for t in tests for p in t.poses):
        return out
    out.append("<h2>Orientation characteristics (millidegrees)</h2><table><tr><th class=l>pose</th>")
    for lab in label:
        out += [f"<th>AP_a, AP_b, AP_c {lab}</th><th>RP_a, RP_b, RP_c {lab}</th>"]
    out.append("</tr>")
    for i, name in enumerate(POSE_NAMES):
        out.append(f"<tr><td class=l>{name}</td>")
        for t in tests:
            o = t.poses[i].orientation
            for kind in ("AP", "RP"):
                figs = [o.get(f"{kind}_{a}") for a in "abc"]
                out.append(
                    "<td>"
                    + "<br>".join(
                        f"{a}: " + ("-" if f is None else _um(f.value, f.u95)) for a, f in zip("abc", figs, strict=True)
                    )
                    + "</td>"
                )
        out.append("</tr>")
    out.append("</table>")
    return out


def _vap_section(tests: list[IsoFigures], label: list[str]) -> list[str]:
    """The multi-directional pose accuracy variation's table (none without vAP visits)."""
    out: list[str] = []
    vap_poses = list(dict.fromkeys(name for t in tests for name in t.vap))
    if vap_poses:
        out.append("<h2>Multi-directional pose accuracy variation (µm)</h2><table><tr><th class=l>pose</th>")
        out += [f"<th>vAP_P {lab}</th>" for lab in label]
        out.append("<th class=l>approached from</th></tr>")
        for name in vap_poses:
            sides = next((", ".join(t.vap_attained_mm[name]) for t in tests if name in t.vap_attained_mm), "")
            cells = [_um(t.vap[name].value, t.vap[name].u95) if name in t.vap else "-" for t in tests]
            out.append(
                f"<tr><td class=l>{name}</td>"
                + "".join(f"<td>{c}</td>" for c in cells)
                + f"<td class=l>{sides} sides</td></tr>"
            )
        out.append("</table>")
    return out


def _drift_sections(drift_list: list[dict]) -> list[str]:
    """One table per drift comparison."""
    out: list[str] = []
    for d in drift_list:
        out.append(
            f"<h2>Drift, {html.escape(d['targets'])} targets: {html.escape(d['first'])} to "
            f"{html.escape(d['last'])} (µm)</h2><table><tr><th class=l>pose</th><th>dAP</th><th>dRP</th></tr>"
        )
        out += [
            f"<tr><td class=l>{p['pose']}</td><td>{_um(p['dAP'].value, p['dAP'].u95)}</td>"
            f"<td>{_um(p['dRP'].value, p['dRP'].u95)}</td></tr>"
            for p in d["poses"]
        ]
        out.append("</table>")
    return out


def write_iso_report(
    tests: list[IsoFigures],
    drift_list: list[dict],
    model_path: str,
    path: Path,
    conformity: tuple[str, dict[str, float], list[Verdict]] | None = None,
    item: Item | None = None,
) -> Path:
    write_text(path, render(tests, drift_list, model_path, conformity, item), InputError)
    return path


def write_iso_pdf(
    tests: list[IsoFigures],
    drift_list: list[dict],
    model_path: str,
    path: Path,
    conformity: tuple[str, dict[str, float], list[Verdict]] | None = None,
    item: Item | None = None,
) -> Path:
    """The same page as a PDF (headless chromium), the report id and "page N of M" at the foot of every page."""
    rid = (item.report_id if item else None) or report_id(tests)
    return html_to_pdf(
        render(tests, drift_list, model_path, conformity, item), path, f"ISO 9283:1998 acceptance test, report {rid}"
    )
