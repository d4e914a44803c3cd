"""The campaign report: one self-contained HTML page, PNG plots next to it, rendered from the CampaignAnalysis it is
given (campaign.jobs.end_of_run makes it at the end of `trackcal run` and reads it back for `trackcal report`).

Its header: the session, the campaign's date, the trackcal version, the cell and the outcome in one sentence, then
"what next" (the compensate command; a re-plan when the verdict names a cause the plan was not made to reveal)
and the campaign's warnings. Then, after the paper (Wu, Klimchik et al., RCIM 2015, section 7): the plan (its poses and
rho0), the residuals after calibration per axis with a fitted normal (Fig. 10), the residual distance per
configuration before and after (Fig. 11), the parameters with 95 % confidence intervals (Table 8), the
residual statistics before and after (Table 9: coordinate- and distance-based, max and RMS, improvement
factor), the stations and reference points with their intervals, the model extension, and the diagnosis
(verdict of `trackcal diagnose`, its plots).

It renders what the analysis holds and computes nothing: the residuals (campaign.report.residuals: "after" is the
table minus the model's prediction, so a report on a validation table shows how the model predicts), the diagnosis,
the TCP difference and the test-pose figure were derived once when the analysis was made; the plots are
campaign.report.plots. No external CSS or JavaScript; every text is HTML-escaped.
"""

from __future__ import annotations

import base64
import html
import re
import shutil
from dataclasses import dataclass
from datetime import UTC, datetime
from importlib.metadata import version
from pathlib import Path

import numpy as np

from trackcal.calib.identify.noise import model_instrument
from trackcal.calib.io.files import write_text
from trackcal.calib.model.cell import Cell
from trackcal.calib.model_trust import unusable_why
from trackcal.campaign.errors import InputError
from trackcal.campaign.report.analysis import CampaignAnalysis, Provenance
from trackcal.campaign.report.diagnosis_plots import plots
from trackcal.campaign.report.plots import plot_histograms, plot_parameters, plot_per_pose, plot_plan
from trackcal.campaign.report.residuals import Residuals, pose_order
from trackcal.campaign.report.tcp import DETERMINED_SIGMAS, TcpDifference

TABLE9_ROWS = (
    ("coord_max_mm", "coordinate-based, max"),
    ("coord_rms_mm", "coordinate-based, RMS"),
    ("dist_max_mm", "distance-based, max"),
    ("dist_rms_mm", "distance-based, RMS"),
)
STYLE = """
body { font-family: sans-serif; max-width: 1100px; margin: 1em auto; color: #222; }
h1 { border-bottom: 2px solid #444; } h2 { border-bottom: 1px solid #aaa; margin-top: 1.6em; }
table { border-collapse: collapse; margin: 0.6em 0; font-size: 0.92em; }
th, td { border: 1px solid #bbb; padding: 0.2em 0.6em; text-align: right; }
th { background: #eee; } td.l, th.l { text-align: left; }
img { max-width: 100%; border: 1px solid #ddd; margin: 0.4em 0; }
.note { color: #555; font-size: 0.9em; } .warn { color: #a40; }
p.verdict { font-size: 1.15em; background: #f4f4f4; border-left: 4px solid #444; padding: 0.5em 0.8em; }
code { background: #f4f4f4; padding: 0.1em 0.3em; }
p.unusable { font-size: 1.1em; font-weight: bold; color: #fff; background: #b00; padding: 0.6em 0.8em; }
"""
# what a campaign must contain to reveal each cause (README, `trackcal diagnose`): the re-plan advice
CAUSE_NEEDS = {
    "joint_compliance": "poses with different gravity loads (arm stretched and folded)",
    "backlash": "each joint approaching the poses from both directions",
    "encoder_scale": "a wide range of each joint angle",
    "cyclic_error": "joint angles spread over the period",
    "thermal_drift": "repeated poses at different times (drift checks over a longer campaign)",
    "station_shift": "drift-check poses revisited within each station block",
    "thermal_warmup": "rows spread over the warm-up (a campaign longer than its time constant, drift checks)",
    "payload_compliance": "poses of different gravity loads measured with each payload (the table's load_kg column)",
    "wrist_coupling": "a wide range of the wrist's angles (A4 and A5 turned far both ways)",
    "range_scale": "the same poses measured from two or more stations (a scale is relative to the first station)",
    "nest_sag": "two or more reference points measured over many flange orientations",
}
NO_STATIC_COMPENSATION = ("backlash", "thermal_drift")


def esc(value) -> str:
    return html.escape(str(value), quote=True)


# ------------------------------------------------------------------------------------------------- html
def table_html(header: list[str] | None, rows: list[list], left: int = 1) -> str:
    """A table; the first `left` columns are text (left-aligned); no header row when `header` is None (a table of
    facts). Every cell is escaped."""

    def cls(i: int) -> str:
        return ' class="l"' if i < left else ""

    head = (
        ""
        if header is None
        else ("<thead><tr>" + "".join(f"<th{cls(i)}>{esc(h)}</th>" for i, h in enumerate(header)) + "</tr></thead>")
    )
    body = "".join("<tr>" + "".join(f"<td{cls(i)}>{esc(c)}</td>" for i, c in enumerate(r)) + "</tr>" for r in rows)
    return f"<table>{head}<tbody>{body}</tbody></table>"


def img_html(path: Path, alt: str) -> str:
    """The PNG at `path` embedded in the page (a data: URI): the one HTML file is the whole report, the PNG files
    beside it are copies for slides."""
    data = base64.b64encode(Path(path).read_bytes()).decode("ascii")
    return f'<p><img src="data:image/png;base64,{data}" alt="{esc(alt)}" title="{esc(Path(path).name)}"></p>'


def pvalue_text(p) -> str:
    return "-" if p is None else f"{float(p):.2g}"


def fmt(v, digits: int = 4) -> str:
    if v is None:
        return "-"
    try:
        f = float(v)
    except (TypeError, ValueError):
        return str(v)
    return f"{f:.{digits}f}" if np.isfinite(f) else str(f)


def duration_text(seconds: float | None) -> str:
    if seconds is None:
        return "not known (a report from files)"
    h, rest = divmod(int(round(seconds)), 3600)
    return f"{h} h {rest // 60:02d} min" if h else f"{rest // 60} min {rest % 60:02d} s"


def floor_text(res: Residuals) -> str:
    """The one noise floor, with both of its forms: per coordinate (Table 9, the histograms) and for a 3-D
    distance (the per-configuration plot): sqrt(3) times, the RMS length of three independent coordinates."""
    return (
        f"{res.floor_mm * 1000:.1f} per coordinate ({res.floor_source}); {np.sqrt(3.0) * res.floor_mm * 1000:.1f} "
        "for a 3-D distance (√3 × the per-coordinate floor)"
    )


def table9_rows(res: Residuals) -> list[list[str]]:
    rows = []
    for key, label in TABLE9_ROWS:
        b, a = res.stats_before[key], res.stats_after[key]
        rows.append([label, fmt(1000 * b, 1), fmt(1000 * a, 1), f"{b / a:.1f}" if a > 0 else "-"])
    return rows


def parameter_rows(model_doc: dict, planned: list[str] | None) -> list[list[str]]:
    """Table 8, and whether the plan was optimised for each parameter ("-" without a plan)."""
    rows = []
    for name, p in model_doc.get("parameters", {}).items():
        value, ci = float(p["value"]), float(p.get("ci95", float("nan")))
        significant = "yes" if abs(value) > ci else "no"
        in_plan = "-" if planned is None else "yes" if name in planned else "no"
        rows.append(
            [name, p.get("unit", ""), fmt(p.get("nominal"), 1), f"{value:+.4f}", f"±{ci:.4f}", significant, in_plan]
        )
    return rows


def parameters_note(model_doc: dict, plan_doc: dict | None, sigma_mm: float | None) -> str:
    """What the plan determines: the parameters it was optimised for, the others fitted beside them, and how well
    the model's TCP at the test pose is determined by this campaign."""
    text = "Deviations from nominal; significant when the 95 % interval excludes zero."
    fitted = list(model_doc.get("parameters", {}))
    planned = list((plan_doc or {}).get("params") or [])
    if planned:
        extra = [n for n in fitted if n not in planned]
        left = [n for n in planned if n not in fitted]
        text += (
            f" The plan was optimised for {len(planned)} parameters ({' '.join(planned)}); the model fits "
            f"{len(fitted)}, the irreducible set with the stations and reference points free."
        )
        if left:
            text += (
                f" {' '.join(left)} of the plan cannot be told apart from the stations' placement and "
                f"{'is' if len(left) == 1 else 'are'} not fitted."
            )
        if extra:
            text += (
                f" {' '.join(extra)} are not in the plan: these configurations were not chosen to determine "
                "them: their intervals say how well they are determined all the same."
            )
    if sigma_mm is not None:
        rho = (plan_doc or {}).get("rho0_mm")
        promised = f" (the plan's rho0, for its own parameters only: {float(rho) * 1000:.2f} µm)" if rho else ""
        text += (
            f" This model's TCP at the test pose is determined to ±{sigma_mm * 1000:.1f} µm by this campaign "
            f"(1σ 3-D, from its covariance){promised}."
        )
    return text


def plan_unknown_rows(plan_doc: dict, cell: Cell) -> list[tuple[str, str]]:
    """The stations and reference points the plan counted as unknowns besides the robot's (calib.identify.unknowns:
    6 per station, 3 per point), with their names from the cell; "-" for a plan that does not record them."""
    u = plan_doc.get("unknowns") or {}
    rows = []
    for key, label, per, names in (
        ("stations", "stations", 6, list(cell.stations)),
        ("points", "reference points", 3, sorted(cell.tool_points)),
    ):
        n = u.get(key)
        text = "-" if n is None else "known (held at nominal)" if n == 0 else f"{n}: {' '.join(names[:n])}"
        rows.append((f"{label} ({per} unknowns each)", text))
    return rows


def section_plan(plan_doc: dict | None, cell: Cell, out_dir: Path) -> str:
    if not plan_doc:
        return "<h2>Measurement plan</h2><p class='note'>No plan given.</p>"
    parts = ["<h2>Measurement plan</h2>"]
    rho = plan_doc.get("rho0_mm")
    facts = [
        ("criterion", plan_doc.get("criterion", "-")),
        ("repeat", plan_doc.get("repeat", "-")),
        ("rho0 at the test pose (µm)", f"{rho * 1000:.3f}" if rho is not None else "-"),
        ("robot parameters", " ".join(plan_doc.get("params", [])) or "-"),
        *plan_unknown_rows(plan_doc, cell),
        ("test pose (deg)", ", ".join(fmt(v, 2) for v in plan_doc.get("test_pose_deg") or []) or "-"),
    ]
    parts.append(table_html(None, [list(f) for f in facts], left=2))
    poses = plan_doc.get("poses_deg") or []
    if poses:
        n = len(poses[0])
        parts.append(
            table_html(
                ["configuration", *[f"q{j + 1} (deg)" for j in range(n)]],
                [[str(k + 1), *[fmt(v, 2) for v in q]] for k, q in enumerate(poses)],
            )
        )
    if plot_plan(plan_doc, cell, out_dir / "plan.png") is not None:
        parts.append(img_html(out_dir / "plan.png", "measurement plan"))
    return "".join(parts)


def section_stations_points(model_doc: dict) -> str:
    parts = ["<h2>Tracker stations and reference points</h2>"]
    rows = []
    for sid, s in model_doc.get("stations", {}).items():
        t, ct = s.get("translation_mm", [np.nan] * 3), s.get("ci95_translation_mm", [np.nan] * 3)
        cr = s.get("ci95_rotation_deg", [np.nan] * 3)
        rows.append([sid, *[fmt(v, 3) for v in t], *[f"±{fmt(v, 4)}" for v in ct], *[f"±{fmt(v, 5)}" for v in cr]])
    parts.append(
        table_html(
            [
                "station",
                "tx (mm)",
                "ty (mm)",
                "tz (mm)",
                "CI tx",
                "CI ty",
                "CI tz",
                "CI rx (deg)",
                "CI ry (deg)",
                "CI rz (deg)",
            ],
            rows,
        )
    )
    parts.append(
        "<p class='note'>Station transforms map the robot base frame into each tracker's frame; intervals are 95 %.</p>"
    )
    rows = []
    for pid, p in model_doc.get("tool_points", {}).items():
        rows.append([pid, *[fmt(v, 4) for v in p["xyz_mm"]], *[f"±{fmt(v, 4)}" for v in p.get("ci95_mm", [])]])
    parts.append(table_html(["point", "x (mm)", "y (mm)", "z (mm)", "CI x", "CI y", "CI z"], rows))
    return "".join(parts)


def section_extension(model_doc: dict) -> str:
    ext = model_doc.get("extension") or {"cause": "none"}
    cause = ext.get("cause", "none")
    if cause == "none":
        return "<h2>Model extension</h2><p>None: the model is purely geometric.</p>"
    parts = [f"<h2>Model extension</h2><p>Cause: <b>{esc(cause)}</b></p>"]
    if cause == "station_shift":
        parts.append(
            f"<p>Station {esc(ext.get('station', '?'))} moved after t = {esc(fmt(ext.get('after_t_s'), 1))} s"
            "; its later transform is identified separately.</p>"
        )
    pars = ext.get("parameters") or {}
    if pars:
        rows = [
            [n, p.get("unit", ""), f"{float(p['value']):+.4g}", f"±{float(p.get('ci95', np.nan)):.3g}"]
            for n, p in pars.items()
        ]
        parts.append(table_html(["parameter", "unit", "value", "95 % CI"], rows, left=2))
    return "".join(parts)


# a held-out RMS more than this many times the candidate's own fit RMS says the held-out rows were needed to
# determine the model (a scheme the campaign cannot support, e.g. whole configurations left out of a plan of a few):
# with N rows and p unknowns a model that holds predicts held-out rows at about sqrt(N / (N - p)) times its fit RMS
HOLDOUT_TRUST = 3.0


def holdout_trusted(holdout_mm, fit_mm) -> bool:
    return holdout_mm is not None and fit_mm is not None and float(holdout_mm) <= HOLDOUT_TRUST * float(fit_mm)


def micro(v) -> str:
    """mm -> µm text ("-" for none)."""
    return fmt(1000 * float(v), 1) if v is not None else "-"


def candidate_row(c: dict) -> list[str]:
    """One candidate of one selection step: a candidate with nothing to fit, or whose held-out figure the campaign
    cannot support, says so instead of a number."""
    n = c.get("n_params")
    step = str(c.get("step", "-"))
    if n == 0:
        return [
            step,
            c.get("cause", "?"),
            "0",
            "-",
            "-",
            "-",
            "-",
            "no",
            "not fitted: none of its parameters is identifiable from these poses",
        ]
    hold, note = c.get("holdout_rms_mm"), c.get("cv_note") or ""
    if hold is not None and not holdout_trusted(hold, c.get("rms_mm")):
        note = (
            f"held out by {c.get('cv_scheme') or '?'}: not shown, over {HOLDOUT_TRUST:.0f}x its fit RMS (the "
            "held-out rows are needed to determine the model): not a scheme this campaign supports"
        )
        hold = None
    return [
        step,
        c.get("cause", "?"),
        "-" if n is None else str(n),
        micro(hold),
        micro(c.get("rms_mm")),
        pvalue_text(c.get("f_pvalue")),
        fmt(c.get("delta_bic"), 0),
        "yes" if c.get("significant") else "no",
        note,
    ]


def tcp_text(tcp: TcpDifference, plan_doc: dict | None, model_doc: dict) -> str:
    """The TCP difference at the test pose, with its uncertainty, or why it is not determined."""
    diff = f"{tcp.difference_mm * 1000:.1f}"
    if tcp.sigma_mm is None:
        return f"{diff} (its uncertainty is not known: no covariance)"
    unc = (
        f"geometric ±{tcp.sigma_geometric_mm * 1000:.1f}, extended ±{tcp.sigma_extended_mm * 1000:.1f} µm, "
        "1σ 3-D at the noise the extended model leaves"
    )
    if tcp.determined:
        return (
            f"{diff} ± {tcp.sigma_mm * 1000:.1f} ({unc}): where the geometric model would put the TCP, "
            "compared with the model that explains the cause"
        )
    planned = (plan_doc or {}).get("params") or []
    why = (
        f"; the plan was optimised for {len(planned)} parameters ({' '.join(planned)}), the model fits "
        f"{len(model_doc.get('parameters', {}))}"
        if planned
        else ""
    )
    return (
        f"not determined by this campaign: the two models' TCPs differ by {diff} µm, within "
        f"{DETERMINED_SIGMAS:.0f}σ of their own uncertainty at the test pose ({unc}){why}"
    )


def section_diagnosis(
    verdict_doc: dict | None,
    images: list[Path],
    tcp: TcpDifference | None = None,
    plan_doc: dict | None = None,
    model_doc: dict | None = None,
) -> str:
    if not verdict_doc and not images:
        return "<h2>Diagnosis</h2><p class='note'>No diagnosis given (run trackcal diagnose).</p>"
    parts = ["<h2>Diagnosis</h2>"]
    if verdict_doc:
        parts.append(f"<p>Cause: <b>{esc(verdict_doc.get('cause', '?'))}</b></p>")
        causes = [c.get("cause", "?") for c in verdict_doc.get("causes", [])]
        if len(causes) > 1:
            parts.append(f"<p>Causes, in the order forward selection added them: {esc(', '.join(causes))}</p>")
        hold = verdict_doc.get("holdout", {})
        geo_rms = verdict_doc.get("geometric", {}).get("rms_mm")
        ext_rms = verdict_doc.get("extended", {}).get("rms_mm")
        facts = [
            ("noise floor (µm, per coordinate)", micro(verdict_doc.get("noise_floor_mm"))),
            ("noise floor from", verdict_doc.get("noise_floor_source", "-")),
            ("geometric model RMS (µm, per coordinate)", micro(geo_rms)),
            (
                "extended model RMS (µm, per coordinate)",
                micro(ext_rms) if verdict_doc.get("cause") not in ("none", "unexplained") else "- (no cause chosen)",
            ),
        ]
        untrusted = []
        for label, key, fit in (("geometric", "rms_geometric_mm", geo_rms), ("extended", "rms_extended_mm", ext_rms)):
            value = hold.get(key)
            if value is not None and not holdout_trusted(value, fit):
                untrusted.append(label)
                value = None
            facts.append((f"held-out RMS, {label} (µm)", micro(value)))
        facts += [(label, verdict_doc[key]) for label, key in (("noise", "noise_note"),) if verdict_doc.get(key)]
        if hold.get("note"):
            facts.append(("held-out figures", hold["note"]))
        if untrusted:
            facts.append(
                (
                    "held-out figures not shown",
                    f"{' and '.join(untrusted)}: over {HOLDOUT_TRUST:.0f}x the "
                    "fit RMS, the held-out scheme is not one this campaign supports",
                )
            )
        if tcp is not None:
            facts.append(
                (
                    f"TCP difference at the test pose (µm, station {tcp.station} frame)",
                    tcp_text(tcp, plan_doc, model_doc or {}),
                )
            )
        parts.append(table_html(None, [list(f) for f in facts], left=2))
        rows = [candidate_row(c) for c in verdict_doc.get("candidates", [])]
        if rows:
            parts.append(
                "<p class='note'>Every candidate of every forward-selection step: at each step the "
                "candidates are fitted on top of the causes chosen before it.</p>"
            )
            parts.append(
                table_html(
                    [
                        "step",
                        "candidate",
                        "params",
                        "held-out RMS (µm)",
                        "fit RMS (µm)",
                        "F-test p",
                        "dBIC",
                        "significant",
                        "note",
                    ],
                    rows,
                    left=2,
                )
            )
    parts += [img_html(path, "diagnosis plot") for path in images]
    return "".join(parts)


def verdict_sentence(model_doc: dict, verdict_doc: dict | None, res: Residuals) -> str:
    """The outcome of the campaign in one sentence."""
    # the fit verdict's own figure (model.json residual_rms_mm: RSS over the degrees of freedom, what fit_ratio
    # compares with the floor); Table 9's plain RMS (RSS / n) is smaller and would read as a different fit
    rms = model_doc.get("residual_rms_mm", res.stats_after["coord_rms_mm"])
    fit = f"residual RMS {rms * 1000:.1f} µm per coordinate against a noise floor of {res.floor_mm * 1000:.1f} µm"
    cause = (verdict_doc or {}).get("cause")
    if cause is None:
        quality = model_doc.get("fit", "?")
        return f"The model leaves {fit}: fit {quality}" + (
            " (no diagnosis given: run trackcal diagnose)." if quality == "poor" else "; no diagnosis given."
        )
    if cause == "none":
        return f"The geometric calibration fits to the noise floor ({fit}); no non-geometric effect was found."
    geo = 1000 * float(verdict_doc.get("geometric", {}).get("rms_mm", np.nan))
    if cause == "unexplained":
        return (
            f"The geometric model leaves {geo:.1f} µm against a noise floor of {res.floor_mm * 1000:.1f} µm and no "
            "candidate cause explains it: the residual structure is unexplained."
        )
    ext = 1000 * float(verdict_doc.get("extended", {}).get("rms_mm", np.nan))
    return (
        f"The robot shows {cause.replace('_', ' ')}: the geometric model leaves {geo:.1f} µm, the model extended "
        f"by {cause} {ext:.1f} µm, against a noise floor of {res.floor_mm * 1000:.1f} µm."
    )


def what_next(
    model_doc: dict, plan_doc: dict | None, verdict_doc: dict | None, prov: Provenance, cell_name: str = ""
) -> list[str]:
    """The next steps, as HTML paragraphs (commands in <code>); `cell_name` names the cell when the provenance
    does not."""
    cause = (verdict_doc or {}).get("cause")
    cell_ref = prov.cell_ref or cell_name
    steps = []
    if model_doc.get("fit") == "poor" and cause in (None, "unexplained"):
        steps.append(
            "The model does not reach the noise floor, so its intervals cannot be trusted: look at the "
            "diagnosis plots, the parameters left out and the set-up before compensating."
        )
    ignored = f" ({esc(cause)} has no static compensation and is ignored)" if cause in NO_STATIC_COMPENSATION else ""
    steps.append(
        f"Correct the robot's joint targets{ignored}: <code>trackcal compensate --model "
        f"{esc(prov.model_path)} TARGETS.csv --out corrected.csv --krl CALPOS</code> (TARGETS.csv: "
        "columns name, q1_deg..qn_deg)."
    )
    if cause in CAUSE_NEEDS:
        configs = len((plan_doc or {}).get("poses_deg") or []) or 6
        repeat = (plan_doc or {}).get("repeat", 3)
        planned = " ".join((plan_doc or {}).get("params", [])) or "the geometric parameters"
        steps.append(
            f"The plan was optimised for {esc(planned)} only, not to reveal {esc(cause)}, which needs "
            f"{esc(CAUSE_NEEDS[cause])}. To pin it down, re-plan with more configurations and measure "
            f"again: <code>trackcal plan --cell {esc(cell_ref)} --configs {2 * configs} --repeat "
            f"{repeat} --json plan-2.json</code>, then <code>trackcal run --cell {esc(cell_ref)} "
            "--plan plan-2.json ...</code>."
        )
    return steps


# the engine's words for a point it could not measure (campaign.engine.engine.Engine._measure)
NOT_MEASURABLE = re.compile(
    r"^(?:t = [-0-9.]+ s: )?(?P<point>.+?) not measurable from (?P<station>.+?) at "
    r"(?P<pose>.+?): (?P<why>.*); (?P<then>skipped here|looking again)$"
)


# what differs from one skip to the next of one cause: where the tracker searched (the expected position)
SEARCHED_AT = re.compile(r" near \([-0-9., ]+\) mm")


def counted(names: list[str]) -> str:
    """`P1 x5, P2 x5` (first-seen order), a name alone when it occurs once."""
    counts: dict[str, int] = {}
    for n in names:
        counts[n] = counts.get(n, 0) + 1
    return ", ".join(f"{n} ×{c}" if c > 1 else n for n, c in counts.items())


def summarise_warnings(warnings: list[str], measured: int) -> list[str]:
    """The campaign's warnings as an engineer reads them: the skipped measurements counted against the planned
    ones and grouped by station and reason (where the tracker searched left out), with their points and poses
    (each attempt that looked again is part of its skip), then every other warning once per message, with its
    count."""
    skipped: dict[tuple[str, str], list[tuple[str, str]]] = {}
    others: dict[str, int] = {}
    for w in warnings:
        m = NOT_MEASURABLE.match(w)
        if m is None:
            text = re.sub(r"^t = [-0-9.]+ s: ", "", w)
            others[text] = others.get(text, 0) + 1
        elif m["then"] == "skipped here":
            why = SEARCHED_AT.sub(" near where the model expects it", m["why"])
            skipped.setdefault((m["station"], why), []).append((m["point"], m["pose"]))
    lines = []
    n_skipped = sum(len(v) for v in skipped.values())
    if n_skipped:
        groups = "; ".join(
            f"{'all' if len(skips) == n_skipped else len(skips)} at station {station} (point "
            f"{counted([p for p, _ in skips])}; pose {counted([q for _, q in skips])}) because: {why}"
            for (station, why), skips in skipped.items()
        )
        lines.append(f"{n_skipped} of {measured + n_skipped} planned measurements skipped, {groups}.")
    lines += [f"{text} ({n} times)" if n > 1 else text for text, n in others.items()]
    return lines


def section_warnings(warnings: list[str] | None, measured: int) -> str:
    if warnings is None:
        return (
            "<h2>Campaign warnings</h2><p class='note'>Not known: a report from files (the warnings are in the "
            "session; give the SESSION directory).</p>"
        )
    if not warnings:
        return "<h2>Campaign warnings</h2><p>None: every planned measurement was made, no drift, no blocked motion.</p>"
    summary = "".join(f"<li>{esc(w)}</li>" for w in summarise_warnings(warnings, measured))
    raw = "".join(f"<li>{esc(w)}</li>" for w in warnings)
    return (
        f"<h2>Campaign warnings</h2><ul class='warn' id='warnings'>{summary}</ul>"
        f"<details><summary>every warning as raised ({len(warnings)})</summary><ul>{raw}</ul></details>"
    )


def _extra_images(out_dir: Path, extra_images) -> list[Path]:
    names = []
    for p in extra_images or []:
        p = Path(p)
        if not p.is_file():
            raise InputError(f"{p}: no such image")
        target = out_dir / "extra" / p.name  # a subdirectory: never overwrites the report's own plots
        target.parent.mkdir(exist_ok=True)
        if p.resolve() != target.resolve():
            shutil.copy2(p, target)
        names.append(target)
    return names


def unusable_banner(analysis: CampaignAnalysis) -> str:
    """A red paragraph at the top of the page for each of the campaign's models marked unusable (calib.model_trust):
    compensate refuses them; empty when both are usable."""
    prov, files = analysis.provenance, analysis.files
    models = [(prov.model_path, "The model", analysis.model)]
    if analysis.geometric_model is not None:
        where = str(files.geometric_model) if files is not None else "the geometric model"
        models.append((where, "The purely geometric model", analysis.geometric_model))
    out = []
    for path, what, doc in models:
        why = unusable_why(doc)
        if why:
            out.append(
                f"<p class='unusable'>UNUSABLE: {esc(what)} ({esc(path)}) must not be used to "
                f"compensate the robot: {esc(why)}. <code>trackcal compensate</code> refuses it (unless "
                "<code>--accept-poor</code>).</p>"
            )
    return f"<div id='unusable'>{''.join(out)}</div>" if out else ""


def report_dir(out_dir: Path) -> Path:
    out_dir = Path(out_dir)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"{out_dir}: cannot create the report directory ({exc.strerror or exc})") from None
    return out_dir


@dataclass(frozen=True)
class Drawn:
    """The report's plots, drawn in its folder: the parameters' (None without parameters) and the diagnosis'."""

    parameters: Path | None
    diagnosis: list[Path]


def draw(analysis: CampaignAnalysis, out_dir: Path, extra_images: list[Path] | None) -> Drawn:
    """The plots of `analysis` in `out_dir` (the plan's is drawn with its section); with a verdict and the diagnosis
    it was made from, the diagnosis plots, then `extra_images` copied beside them."""
    res, table = analysis.residuals, analysis.table
    plot_histograms(res, out_dir / "residuals_xyz.png")
    plot_per_pose(table, res, out_dir / "residuals_per_pose.png")
    par_plot = plot_parameters(analysis.model, out_dir / "parameters.png")
    d = analysis.diagnosis
    images = plots(analysis.cell, d, out_dir / "diagnosis") if analysis.verdict and d is not None else []
    return Drawn(par_plot, images + _extra_images(out_dir, extra_images))


def header_facts(analysis: CampaignAnalysis) -> list[list[str]]:
    """The facts under the title: the session, the campaign, the cell and the fit."""
    cell, table, model_doc, prov, res = (
        analysis.cell,
        analysis.table,
        analysis.model,
        analysis.provenance,
        analysis.residuals,
    )
    digest = f" (sha256 {analysis.table_sha256[:12]})" if analysis.table_sha256 else ""
    sigma = model_doc.get("sigma_mm")
    facts = [
        ("session", prov.session or "none (a report from files)"),
        ("campaign started", prov.campaign_started or "not known (a report from files)"),
        ("campaign ended", prov.campaign_ended or "not known (a report from files)"),
        ("duration", duration_text(prov.duration_s)),
        ("report written", datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")),
        ("trackcal version", version("trackcal")),
        ("cell", cell.name),
        ("robot", model_doc.get("robot", {}).get("name", cell.chain.name)),
        ("nominal robot", model_doc.get("nominal") or f"{cell.nominal} (the cell's: the model does not say)"),
        ("measurement table", table.source + digest),
        ("measurements", str(len(table))),
        ("configurations", str(len(pose_order(table)))),
        ("stations", ", ".join(dict.fromkeys(table.station))),
        ("reference points", ", ".join(dict.fromkeys(table.point))),
        ("tracker", (model_instrument(model_doc) if "tracker" in model_doc else cell.tracker).describe()),
        ("weighting", model_doc.get("weighting", "-")),
        ("iterations", str(model_doc.get("iterations", "-"))),
        (
            "a-posteriori sigma (µm)",
            fmt(1000 * sigma, 1)
            if sigma is not None
            else f"{fmt(1000 * model_doc.get('residual_rms_mm', res.stats_after['coord_rms_mm']), 1)} (residual RMS "
            "over the degrees of freedom; tracker weighting)",
        ),
        ("variance factor", fmt(model_doc.get("variance_factor"), 3)),
        ("noise floor (µm)", floor_text(res)),
        ("model extension", (model_doc.get("extension") or {}).get("cause", "none")),
    ]
    return [list(f) for f in facts]


def section_residuals(res: Residuals, out_dir: Path) -> str:
    return "\n".join(
        [
            "<h2>Residuals before and after calibration (Table 9)</h2>",
            table_html(["residual (µm)", "before", "after", "improvement factor"], table9_rows(res)),
            "<p class='note'>Before: the nominal robot, with the stations and reference points fitted to this table. "
            "After: this table minus the model's prediction. Coordinate-based: every x, y, z; distance-based: the "
            "3-D distance of each measurement. The dashed lines mark the noise floor: what the tracker alone "
            "gives.</p>",
            img_html(out_dir / "residuals_xyz.png", "residual histograms per axis"),
            img_html(out_dir / "residuals_per_pose.png", "residual distance per configuration"),
        ]
    )


def section_parameters(analysis: CampaignAnalysis, par_plot: Path | None) -> str:
    model_doc, plan_doc = analysis.model, analysis.plan
    planned = list(plan_doc.get("params") or []) if plan_doc else None
    return "\n".join(
        [
            "<h2>Identified parameters (Table 8)</h2>",
            table_html(
                ["parameter", "unit", "nominal", "deviation", "95 % CI", "significant", "in the plan"],
                parameter_rows(model_doc, planned),
            ),
            f"<p class='note'>{esc(parameters_note(model_doc, plan_doc, analysis.test_pose_sigma_mm))}</p>",
            img_html(par_plot, "identified parameters") if par_plot is not None else "",
        ]
    )


def write_report(analysis: CampaignAnalysis, out_dir: Path, extra_images: list[Path] | None = None) -> Path:
    """Write out_dir/report.html and its PNG plots for `analysis`; returns the HTML path. `extra_images` are PNGs
    copied next to the report and shown in the diagnosis section."""
    cell, model_doc, plan_doc, verdict_doc, prov = (
        analysis.cell,
        analysis.model,
        analysis.plan,
        analysis.verdict,
        analysis.provenance,
    )
    out_dir = report_dir(out_dir)
    drawn = draw(analysis, out_dir, extra_images)
    next_steps = what_next(model_doc, plan_doc, verdict_doc, prov, cell.name)
    title = f"Calibration report: {prov.session or Path(analysis.table.source).name}, cell {cell.name}"
    body = [
        f"<h1>{esc(title)}</h1>",
        unusable_banner(analysis),
        f"<p class='verdict' id='verdict'>{esc(verdict_sentence(model_doc, verdict_doc, analysis.residuals))}</p>",
        table_html(None, header_facts(analysis), left=2),
        "".join(f"<p class='note'>{esc(n)}</p>" for n in prov.notes),
        "<h2 id='what-next'>What next</h2><ul>" + "".join(f"<li>{s}</li>" for s in next_steps) + "</ul>",
        section_warnings(analysis.warnings, len(analysis.table)),
        section_plan(plan_doc, cell, out_dir),
        section_residuals(analysis.residuals, out_dir),
        section_parameters(analysis, drawn.parameters),
        section_stations_points(model_doc),
        section_extension(model_doc),
        section_diagnosis(verdict_doc, drawn.diagnosis, analysis.tcp, plan_doc, model_doc),
    ]
    page = (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        f"<title>{esc(title)}</title><style>{STYLE}</style></head><body>\n" + "\n".join(body) + "\n</body></html>\n"
    )
    path = out_dir / "report.html"
    write_text(path, page, InputError)
    return path
