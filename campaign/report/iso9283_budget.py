"""The uncertainty budget tables of the ISO 9283 report: per test, for AP_P and RP_l of every pose and for AD_P, each
input's contribution (calib.uncertainty_budget), the combined standard uncertainty u_c, k, U = k u_c and the Monte-Carlo
95 % coverage interval, and the U the figure is stated and decided with."""

from __future__ import annotations

import html

from trackcal.calib.iso9283 import IsoFigures
from trackcal.calib.uncertainty_budget import Budget

EXPLANATION = (
    "Each line is an input of the figure with its standard uncertainty's source and distribution; its contribution "
    "is |c_i| u(x_i), the figure's sensitivity to it times its standard uncertainty (GUM, JCGM 100:2008, 5.1.2). "
    "u_c is the root sum of squares of the contributions (the inputs taken independent), U = k u_c with k = 2. AP_P "
    "and RP_l are not linear in their inputs: their 95 % coverage interval is also computed by Monte-Carlo (JCGM "
    "101:2008, the shortest interval), and the U stated beside the figure, and used as the guard band of a decision, "
    "is the larger distance from the value to that interval's ends. Inputs common to every cycle (the station, the "
    "tool point, the reflector) cancel in RP_l; those common to both poses in AD_P."
)


def _um(v: float) -> str:
    return f"{v * 1000:.2f}"


def _table(title: str, columns: list[str], budgets: list[Budget]) -> list[str]:
    """One budget table: a row per input (its source and distribution from the first budget), a column per figure."""
    out = [
        f"<h3>{html.escape(title)} (µm)</h3><table><tr><th class=l>input</th><th class=l>source</th>"
        "<th class=l>distribution</th>" + "".join(f"<th>{html.escape(c)}</th>" for c in columns) + "</tr>"
    ]
    for k, line in enumerate(budgets[0].lines):
        out.append(
            f"<tr><td class=l>{html.escape(line.name)}</td><td class=l>{html.escape(line.source)}</td>"
            f"<td class=l>{html.escape(line.distribution)}</td>"
            + "".join(f"<td>{_um(b.lines[k].contribution_mm)}</td>" for b in budgets)
            + "</tr>"
        )
    rows = [
        ("value", [_um(b.value) for b in budgets]),
        ("combined standard uncertainty u_c", [_um(b.u_c) for b in budgets]),
        ("coverage factor k", [f"{b.k:g}" for b in budgets]),
        ("expanded uncertainty U = k u_c", [_um(b.k * b.u_c) for b in budgets]),
    ]
    if any(b.interval for b in budgets):
        rows.append(
            (
                "Monte-Carlo 95 % interval",
                [f"{_um(b.interval[0])} to {_um(b.interval[1])}" if b.interval else "-" for b in budgets],
            )
        )
    rows.append(("U stated (± beside the figure)", [_um(b.expanded) for b in budgets]))
    out += [
        f"<tr><th class=l colspan=3>{name}</th>" + "".join(f"<td>{v}</td>" for v in values) + "</tr>"
        for name, values in rows
    ]
    out.append("</table>")
    return out


def budget_section(tests: list[IsoFigures]) -> list[str]:
    """The report's budget section (nothing when no test carries a budget)."""
    out: list[str] = []
    if not any(p.budgets for t in tests for p in t.poses):
        return out
    out.append(f"<h2>Uncertainty budget</h2><p>{html.escape(EXPLANATION)}</p>")
    for t in tests:
        label = f"{t.session} ({'compensated' if t.compensated else 'nominal'} targets)"
        for key in ("AP_P", "RP_l"):
            poses = [p for p in t.poses if key in p.budgets]
            if poses:
                out += _table(f"{key}, {label}", [p.name for p in poses], [p.budgets[key] for p in poses])
        if t.ad_budget is not None:
            out += _table(f"AD_P, {label}", ["AD_P"], [t.ad_budget])
        if t.other_budgets:
            out += _table(f"RD and vAP_P, {label}", list(t.other_budgets), list(t.other_budgets.values()))
        method = next((p.budgets["AP_P"].method for p in t.poses if "AP_P" in p.budgets), "")
        out.append(f"<p>AP_P, RP_l: {html.escape(method)}.</p>")
    return out
