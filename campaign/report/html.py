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

The residuals are recomputed from the model and the table given, so a report on a validation table
(poses not used for identification) shows how the model predicts: "after" is the table minus the model's
prediction (`trackcal predict`, extension honoured); "before" is the purely nominal robot with the
stations and reference points fitted to the same table (what `trackcal identify` reports as before).
No external CSS or JavaScript; every text is HTML-escaped.
"""

from __future__ import annotations

import html
import shutil
from dataclasses import dataclass
from datetime import UTC, datetime
from importlib.metadata import version
from pathlib import Path

import numpy as np

from trackcal.calib.diagnose.selection import noise_floor
from trackcal.calib.identify.noise import noise_for
from trackcal.calib.identify.solver import identify, residual_stats
from trackcal.calib.io.files import write_text
from trackcal.calib.io.table import MeasurementTable
from trackcal.calib.model.cell import Cell
from trackcal.calib.model_file import model_from_doc, predict_table
from trackcal.campaign.errors import InputError
from trackcal.campaign.report.analysis import CampaignAnalysis, Provenance
from trackcal.campaign.report.diagnosis_plots import plots
from trackcal.campaign.report.figures import pyplot, save_png

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
"""
# what a campaign must contain to reveal each cause (README, `trackcal diagnose`): the re-plan advice
CAUSE_NEEDS = {
    "joint_compliance": "poses with different gravity loads (arm stretched and folded)",
    "backlash": "each joint approaching the poses from both directions",
    "encoder_scale": "a wide range of each joint angle",
    "cyclic_error": "joint angles spread over the period",
    "thermal_drift": "repeated poses at different times (drift checks over a longer campaign)",
    "station_shift": "drift-check poses revisited within each station block",
}
NO_STATIC_COMPENSATION = ("backlash", "thermal_drift")


def esc(value) -> str:
    return html.escape(str(value), quote=True)


@dataclass
class Residuals:
    before: np.ndarray  # (N, 3) mm, station frames: nominal robot, stations and points fitted
    after: np.ndarray  # (N, 3) mm: measured - predicted by the model
    stats_before: dict[str, float]
    stats_after: dict[str, float]
    floor_mm: float  # expected RMS of one coordinate from the tracker alone (calib.diagnose.noise_floor)
    floor_source: str


def compute_residuals(cell: Cell, table: MeasurementTable, model_doc: dict) -> Residuals:
    if table.xyz is None:
        raise InputError(f"{table.source}: the table has no x_mm, y_mm, z_mm: nothing to report residuals of")
    model = model_from_doc(model_doc)
    after = table.xyz - predict_table(model, table).xyz
    noise = noise_for(model_doc.get("weighting", "iid"))
    before = identify(model.chain, table, cell.tool_points, [], noise=noise).residuals
    found = noise_floor(table, noise)
    floor, source = found.sigma_mm, found.source
    return Residuals(before, after, residual_stats(before), residual_stats(after), floor, source)


# ------------------------------------------------------------------------------------------------ plots
def plot_histograms(res: Residuals, path: Path) -> Path:
    """Paper Fig. 10: residuals after calibration per axis, with the fitted normal density."""
    plt = pyplot()

    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8), sharey=True)
    for a, ax in enumerate(axes):
        r = res.after[:, a] * 1000.0
        mu, sd = float(r.mean()), float(r.std(ddof=1)) if len(r) > 1 else 0.0
        counts, edges, _ = ax.hist(r, bins=max(8, min(40, len(r) // 6)), color="#4a7ebb", alpha=0.75)
        if sd > 0:
            x = np.linspace(edges[0], edges[-1], 200)
            density = np.exp(-0.5 * ((x - mu) / sd) ** 2) / (sd * np.sqrt(2.0 * np.pi))  # the normal pdf
            ax.plot(x, len(r) * (edges[1] - edges[0]) * density, "k-", lw=1.5,
                    label=f"N({mu:.1f}, {sd:.1f}) µm")  # fmt: skip
        for sign in (-1, 1):
            ax.axvline(sign * res.floor_mm * 1000.0, color="#c0504d", ls="--", lw=1.2,
                       label=f"± noise floor {res.floor_mm * 1000:.1f} µm" if sign > 0 else None)  # fmt: skip
        ax.legend(loc="upper right", fontsize=8)
        ax.set_xlabel(f"residual {'xyz'[a]} (µm)")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("measurements")
    fig.suptitle("residuals after calibration, per axis (station frames), with the fitted normal")
    fig.tight_layout()
    return save_png(fig, path, dpi=100)


def pose_order(table: MeasurementTable) -> list[str]:
    return list(dict.fromkeys(table.pose))


def per_pose_rms(table: MeasurementTable, residuals: np.ndarray) -> np.ndarray:
    """RMS residual distance (mm) of every configuration (pose id), in order of first measurement."""
    dist = np.linalg.norm(residuals, axis=1)
    pose = np.array(table.pose)
    return np.array([np.sqrt(np.mean(dist[pose == p] ** 2)) for p in pose_order(table)])


def plot_per_pose(table: MeasurementTable, res: Residuals, path: Path) -> Path:
    """Paper Fig. 11: residual distance per configuration, before and after calibration."""
    plt = pyplot()
    poses = pose_order(table)
    x = np.arange(len(poses))
    fig, axes = plt.subplots(2, 1, figsize=(13, 6), sharex=True)
    for ax, r, label, color in ((axes[0], res.before, "before calibration (nominal robot)", "#c0504d"),
                                (axes[1], res.after, "after calibration", "#4a7ebb")):  # fmt: skip
        ax.bar(x, per_pose_rms(table, r) * 1000.0, color=color)
        # the RMS 3-D distance that tracker noise alone gives: sqrt(3) x the floor of one coordinate
        ax.axhline(np.sqrt(3.0) * res.floor_mm * 1000.0, color="k", ls="--", lw=1.2,
                   label=f"noise floor {np.sqrt(3.0) * res.floor_mm * 1000:.1f} µm ({res.floor_source})")  # fmt: skip
        ax.legend(loc="upper right", fontsize=8)
        ax.set_ylabel("RMS distance (µm)")
        ax.set_title(f"{label}: residual distance per configuration", fontsize=10)
        ax.grid(alpha=0.3, axis="y")
    step = max(1, len(poses) // 40)
    axes[1].set_xticks(x[::step])
    axes[1].set_xticklabels([poses[i].replace("$", r"\$") for i in x[::step]], rotation=90, fontsize=7)
    axes[1].set_xlabel("configuration (pose id)")
    fig.tight_layout()
    return save_png(fig, path, dpi=100)


def plot_parameters(model_doc: dict, path: Path) -> Path | None:
    """Deviations with their 95 % intervals, lengths and angles in two panels."""
    pars = model_doc.get("parameters", {})
    if not pars:
        return None
    plt = pyplot()
    groups = [(u, [(n, p) for n, p in pars.items() if p.get("unit") == u]) for u in ("mm", "deg")]
    groups = [(u, g) for u, g in groups if g]
    fig, axes = plt.subplots(1, len(groups), figsize=(6 * len(groups) + 1, 3.8), squeeze=False)
    for ax, (unit, items) in zip(axes[0], groups, strict=True):
        y = np.arange(len(items))
        ax.errorbar([p["value"] for _, p in items], y, xerr=[p["ci95"] for _, p in items], fmt="o", capsize=3)
        ax.axvline(0.0, color="k", lw=0.8)
        ax.set_yticks(y)
        ax.set_yticklabels([n for n, _ in items])
        ax.invert_yaxis()
        ax.set_xlabel(f"deviation from nominal ({unit}), 95 % interval")
        ax.grid(alpha=0.3)
    fig.suptitle("identified parameters")
    fig.tight_layout()
    return save_png(fig, path, dpi=100)


def plot_plan(plan_doc: dict, cell: Cell, path: Path) -> Path | None:
    """The plan's configurations against the joint limits (and the test pose)."""
    poses = np.asarray(plan_doc.get("poses_deg") or [], dtype=float)
    if poses.ndim != 2 or poses.shape[1] != cell.chain.dof:
        return None
    plt = pyplot()
    n = cell.chain.dof
    fig, ax = plt.subplots(figsize=(9, 3.8))
    lim = np.degrees(cell.chain.limits_array())
    j = np.arange(1, n + 1)
    finite = np.isfinite(lim).all(axis=1)
    ax.bar(j[finite], (lim[finite, 1] - lim[finite, 0]), bottom=lim[finite, 0], width=0.35, color="#ddd",
           label="joint range")  # fmt: skip
    for k, q in enumerate(poses):
        ax.plot(j, q, "o-", lw=1, ms=4, label=f"configuration {k + 1}")
    if plan_doc.get("test_pose_deg") is not None:
        ax.plot(j, plan_doc["test_pose_deg"], "k*--", ms=9, lw=1, label="test pose")
    ax.set_xticks(j)
    ax.set_xticklabels([jt.name for jt in cell.chain.joints])
    ax.set_ylabel("angle (deg)")
    ax.legend(fontsize=7, ncol=2, loc="best")
    ax.grid(alpha=0.3)
    rho = plan_doc.get("rho0_mm")
    ax.set_title("measurement plan" + (f": rho0 = {rho * 1000:.2f} µm at the test pose" if rho is not None else ""))
    fig.tight_layout()
    return save_png(fig, path, dpi=100)


# ------------------------------------------------------------------------------------------------- html
def table_html(header: list[str], rows: list[list], left: int = 1) -> str:
    """A table; the first `left` columns are text (left-aligned). Every cell is escaped."""

    def cls(i: int) -> str:
        return ' class="l"' if i < left else ""

    head = "".join(f"<th{cls(i)}>{esc(h)}</th>" for i, h in enumerate(header))
    body = "".join("<tr>" + "".join(f"<td{cls(i)}>{esc(c)}</td>" for i, c in enumerate(r)) + "</tr>" for r in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def img_html(name: str, alt: str) -> str:
    return f'<p><img src="{esc(name)}" alt="{esc(alt)}"></p>'


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


def table9_rows(res: Residuals) -> list[list[str]]:
    rows = []
    for key, label in TABLE9_ROWS:
        b, a = res.stats_before[key], res.stats_after[key]
        rows.append([label, fmt(1000 * b, 1), fmt(1000 * a, 1), f"{b / a:.1f}" if a > 0 else "-"])
    return rows


def parameter_rows(model_doc: dict) -> list[list[str]]:
    rows = []
    for name, p in model_doc.get("parameters", {}).items():
        value, ci = float(p["value"]), float(p.get("ci95", float("nan")))
        significant = "yes" if abs(value) > ci else "no"
        rows.append([name, p.get("unit", ""), fmt(p.get("nominal"), 1), f"{value:+.4f}", f"±{ci:.4f}", significant])
    return rows


def section_plan(plan_doc: dict | None, cell: Cell, out_dir: Path) -> str:
    if not plan_doc:
        return "<h2>Measurement plan</h2><p class='note'>No plan given.</p>"
    parts = ["<h2>Measurement plan</h2>"]
    rho = plan_doc.get("rho0_mm")
    facts = [("criterion", plan_doc.get("criterion", "-")), ("repeat", plan_doc.get("repeat", "-")),
             ("rho0 at the test pose (µm)", f"{rho * 1000:.3f}" if rho is not None else "-"),
             ("parameters", " ".join(plan_doc.get("params", []))),
             ("test pose (deg)", ", ".join(fmt(v, 2) for v in plan_doc.get("test_pose_deg") or []))]  # fmt: skip
    parts.append(table_html(["", "value"], [list(f) for f in facts], left=2))
    poses = plan_doc.get("poses_deg") or []
    if poses:
        n = len(poses[0])
        parts.append(table_html(["configuration", *[f"q{j + 1} (deg)" for j in range(n)]],
                                [[str(k + 1), *[fmt(v, 2) for v in q]] for k, q in enumerate(poses)]))  # fmt: skip
    if plot_plan(plan_doc, cell, out_dir / "plan.png") is not None:
        parts.append(img_html("plan.png", "measurement plan"))
    return "".join(parts)


def section_stations_points(model_doc: dict) -> str:
    parts = ["<h2>Tracker stations and reference points</h2>"]
    rows = []
    for sid, s in model_doc.get("stations", {}).items():
        t, ct = s.get("translation_mm", [np.nan] * 3), s.get("ci95_translation_mm", [np.nan] * 3)
        cr = s.get("ci95_rotation_deg", [np.nan] * 3)
        rows.append([sid, *[fmt(v, 3) for v in t], *[f"±{fmt(v, 4)}" for v in ct], *[f"±{fmt(v, 5)}" for v in cr]])
    parts.append(table_html(["station", "tx (mm)", "ty (mm)", "tz (mm)", "CI tx", "CI ty", "CI tz",
                             "CI rx (deg)", "CI ry (deg)", "CI rz (deg)"], rows))  # fmt: skip
    parts.append("<p class='note'>Station transforms map the robot base frame into each tracker's frame; "
                 "intervals are 95 %.</p>")  # fmt: skip
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
        parts.append(f"<p>Station {esc(ext.get('station', '?'))} moved after t = {esc(fmt(ext.get('after_t_s'), 1))} s"
                     "; its later transform is identified separately.</p>")  # fmt: skip
    pars = ext.get("parameters") or {}
    if pars:
        rows = [[n, p.get("unit", ""), f"{float(p['value']):+.4g}", f"±{float(p.get('ci95', np.nan)):.3g}"]
                for n, p in pars.items()]  # fmt: skip
        parts.append(table_html(["parameter", "unit", "value", "95 % CI"], rows, left=2))
    return "".join(parts)


def section_diagnosis(verdict_doc: dict | None, images: list[str]) -> str:
    if not verdict_doc and not images:
        return "<h2>Diagnosis</h2><p class='note'>No diagnosis given (run trackcal diagnose).</p>"
    parts = ["<h2>Diagnosis</h2>"]
    if verdict_doc:
        parts.append(f"<p>Cause: <b>{esc(verdict_doc.get('cause', '?'))}</b></p>")
        causes = [c.get("cause", "?") for c in verdict_doc.get("causes", [])]
        if len(causes) > 1:
            parts.append(f"<p>Causes, in the order forward selection added them: {esc(', '.join(causes))}</p>")
        hold = verdict_doc.get("holdout", {})

        def micro(v):  # mm -> µm text
            return fmt(1000 * float(v), 1) if v is not None else "-"

        facts = [
            ("noise floor (µm)", micro(verdict_doc.get("noise_floor_mm"))),
            ("noise floor from", verdict_doc.get("noise_floor_source", "-")),
            ("geometric model RMS (µm)", micro(verdict_doc.get("geometric", {}).get("rms_mm"))),
            ("extended model RMS (µm)", micro(verdict_doc.get("extended", {}).get("rms_mm"))),
            ("held-out RMS, geometric (µm)", micro(hold.get("rms_geometric_mm"))),
            ("held-out RMS, extended (µm)", micro(hold.get("rms_extended_mm"))),
        ]
        facts += [(label, verdict_doc[key]) for label, key in (("noise", "noise_note"),) if verdict_doc.get(key)]
        if hold.get("note"):
            facts.append(("held-out figures", hold["note"]))
        if "test_pose" in verdict_doc:
            facts.append(("TCP difference at the test pose (µm)", micro(verdict_doc["test_pose"]["tcp_difference_mm"])))
        parts.append(table_html(["", "value"], [list(f) for f in facts], left=2))
        rows = []
        for c in verdict_doc.get("candidates", []):
            rows.append([c.get("cause", "?"), str(c.get("n_params", "-")), micro(c.get("holdout_rms_mm")),
                         micro(c.get("rms_mm")), pvalue_text(c.get("f_pvalue")),
                         fmt(c.get("delta_bic"), 0), "yes" if c.get("significant") else "no"])  # fmt: skip
        if rows:
            parts.append(table_html(["candidate", "params", "held-out RMS (µm)", "fit RMS (µm)", "F-test p", "dBIC",
                                     "significant"], rows))  # fmt: skip
    parts += [img_html(name, "diagnosis plot") for name in images]
    return "".join(parts)


def verdict_sentence(model_doc: dict, verdict_doc: dict | None, res: Residuals) -> str:
    """The outcome of the campaign in one sentence."""
    fit = f"{res.stats_after['coord_rms_mm'] * 1000:.1f} µm RMS against a noise floor of {res.floor_mm * 1000:.1f} µm"
    cause = (verdict_doc or {}).get("cause")
    if cause is None:
        quality = model_doc.get("fit", "?")
        return (f"The model leaves {fit}: fit {quality}" + (" (no diagnosis given: run trackcal diagnose)."
                                                             if quality == "poor" else "; no diagnosis given."))
    if cause == "none":
        return f"The geometric calibration fits to the noise floor ({fit}); no non-geometric effect was found."
    geo = 1000 * float(verdict_doc.get("geometric", {}).get("rms_mm", np.nan))
    if cause == "unexplained":
        return (f"The geometric model leaves {geo:.1f} µm against a noise floor of {res.floor_mm * 1000:.1f} µm and no "
                "candidate cause explains it: the residual structure is unexplained.")  # fmt: skip
    ext = 1000 * float(verdict_doc.get("extended", {}).get("rms_mm", np.nan))
    return (f"The robot shows {cause.replace('_', ' ')}: the geometric model leaves {geo:.1f} µm, the model extended "
            f"by {cause} {ext:.1f} µm, against a noise floor of {res.floor_mm * 1000:.1f} µm.")  # fmt: skip


def what_next(model_doc: dict, plan_doc: dict | None, verdict_doc: dict | None, prov: Provenance) -> list[str]:
    """The next steps, as HTML paragraphs (commands in <code>)."""
    cause = (verdict_doc or {}).get("cause")
    steps = []
    if model_doc.get("fit") == "poor" and cause in (None, "unexplained"):
        steps.append("The model does not reach the noise floor, so its intervals cannot be trusted: look at the "
                     "diagnosis plots, the parameters left out and the set-up before compensating.")  # fmt: skip
    ignored = f" ({esc(cause)} has no static compensation and is ignored)" if cause in NO_STATIC_COMPENSATION else ""
    steps.append(f"Correct the robot's joint targets{ignored}: <code>trackcal compensate --model "
                 f"{esc(prov.model_path)} TARGETS.csv --out corrected.csv --krl CALPOS</code> (TARGETS.csv: "
                 "columns name, q1_deg..qn_deg).")  # fmt: skip
    if cause in CAUSE_NEEDS:
        configs = len((plan_doc or {}).get("poses_deg") or []) or 6
        repeat = (plan_doc or {}).get("repeat", 3)
        planned = " ".join((plan_doc or {}).get("params", [])) or "the geometric parameters"
        steps.append(f"The plan was optimised for {esc(planned)} only, not to reveal {esc(cause)}, which needs "
                     f"{esc(CAUSE_NEEDS[cause])}. To pin it down, re-plan with more configurations and measure "
                     f"again: <code>trackcal plan --cell {esc(prov.cell_ref)} --configs {2 * configs} --repeat "
                     f"{repeat} --json plan-2.json</code>, then <code>trackcal run --cell {esc(prov.cell_ref)} "
                     "--plan plan-2.json ...</code>.")  # fmt: skip
    return steps


def section_warnings(warnings: list[str] | None) -> str:
    if warnings is None:
        return ""
    if not warnings:
        return "<h2>Campaign warnings</h2><p>None: every planned measurement was made, no drift, no blocked motion.</p>"
    items = "".join(f"<li>{esc(w)}</li>" for w in warnings)
    return f"<h2>Campaign warnings ({len(warnings)})</h2><ul class='warn'>{items}</ul>"


def diagnosis_images(out_dir: Path, cell: Cell, diagnosis) -> list[str]:
    """The diagnosis plots (campaign.report.diagnosis_plots.plots) of the diagnosis the verdict was made from."""
    return [f"diagnosis/{p.name}" for p in plots(cell, diagnosis, out_dir / "diagnosis")]


def _extra_images(out_dir: Path, extra_images) -> list[str]:
    names = []
    for p in extra_images or []:
        p = Path(p)
        if not p.is_file():
            raise InputError(f"{p}: no such image")
        target = out_dir / "extra" / p.name  # a subdirectory: never overwrites the report's own plots
        target.parent.mkdir(exist_ok=True)
        if p.resolve() != target.resolve():
            shutil.copy2(p, target)
        names.append(f"extra/{p.name}")
    return names


def write_report(analysis: CampaignAnalysis, out_dir: Path, extra_images: list[Path] | None = None) -> Path:
    """Write out_dir/report.html and its PNG plots for `analysis`; returns the HTML path.

    With a verdict and the diagnosis it was made from, the diagnosis plots are drawn; `extra_images` are PNGs
    copied next to the report and shown in the diagnosis section."""
    cell, table, model_doc = analysis.cell, analysis.table, analysis.model
    plan_doc, verdict_doc, prov = analysis.plan, analysis.verdict, analysis.provenance
    out_dir = Path(out_dir)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"{out_dir}: cannot create the report directory ({exc.strerror or exc})") from None
    res = compute_residuals(cell, table, model_doc)
    plot_histograms(res, out_dir / "residuals_xyz.png")
    plot_per_pose(table, res, out_dir / "residuals_per_pose.png")
    par_plot = plot_parameters(model_doc, out_dir / "parameters.png")
    images = diagnosis_images(out_dir, cell, analysis.diagnosis) if verdict_doc and analysis.diagnosis else []
    images += _extra_images(out_dir, extra_images)

    digest = f" (sha256 {analysis.table_sha256[:12]})" if analysis.table_sha256 else ""
    title = f"Calibration report: {prov.session or Path(table.source).name}, cell {cell.name}"
    n_poses = len(pose_order(table))
    sigma = model_doc.get("sigma_mm")
    facts = [
        ("session", prov.session or "none (a report from files)"),
        ("campaign started", prov.campaign_started or "-"),
        ("report written", datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")),
        ("trackcal version", version("trackcal")),
        ("cell", cell.name), ("robot", model_doc.get("robot", {}).get("name", cell.chain.name)),
        ("measurement table", table.source + digest),
        ("measurements", str(len(table))), ("configurations", str(n_poses)),
        ("stations", ", ".join(dict.fromkeys(table.station))),
        ("reference points", ", ".join(dict.fromkeys(table.point))),
        ("weighting", model_doc.get("weighting", "-")), ("iterations", str(model_doc.get("iterations", "-"))),
        ("a-posteriori sigma (µm)", fmt(1000 * sigma, 1) if sigma is not None else
         f"{fmt(1000 * res.stats_after['coord_rms_mm'], 1)} (residual RMS; tracker weighting)"),
        ("variance factor", fmt(model_doc.get("variance_factor"), 3)),
        ("noise floor (µm)", f"{fmt(1000 * res.floor_mm, 1)} ({res.floor_source})"),
        ("model extension", (model_doc.get("extension") or {}).get("cause", "none")),
    ]  # fmt: skip
    body = [
        f"<h1>{esc(title)}</h1>",
        f"<p class='verdict' id='verdict'>{esc(verdict_sentence(model_doc, verdict_doc, res))}</p>",
        table_html(["", ""], [list(f) for f in facts], left=2),
        "".join(f"<p class='note'>{esc(n)}</p>" for n in prov.notes),
        "<h2 id='what-next'>What next</h2><ul>" + "".join(f"<li>{s}</li>" for s in
                                                        what_next(model_doc, plan_doc, verdict_doc, prov)) + "</ul>",
        section_warnings(analysis.warnings),
        section_plan(plan_doc, cell, out_dir),
        "<h2>Residuals before and after calibration (Table 9)</h2>",
        table_html(["residual (µm)", "before", "after", "improvement factor"], table9_rows(res)),
        "<p class='note'>Before: the nominal robot, with the stations and reference points fitted to this table. "
        "After: this table minus the model's prediction. Coordinate-based: every x, y, z; distance-based: the "
        "3-D distance of each measurement. The dashed lines mark the noise floor: what the tracker alone gives.</p>",
        img_html("residuals_xyz.png", "residual histograms per axis"),
        img_html("residuals_per_pose.png", "residual distance per configuration"),
        "<h2>Identified parameters (Table 8)</h2>",
        table_html(["parameter", "unit", "nominal", "deviation", "95 % CI", "significant"], parameter_rows(model_doc)),
        "<p class='note'>Deviations from nominal; significant when the 95 % interval excludes zero.</p>",
        img_html("parameters.png", "identified parameters") if par_plot is not None else "",
        section_stations_points(model_doc),
        section_extension(model_doc),
        section_diagnosis(verdict_doc, images),
    ]  # fmt: skip
    page = ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>{esc(title)}</title><style>{STYLE}</style></head><body>\n"
            + "\n".join(body) + "\n</body></html>\n")  # fmt: skip
    path = out_dir / "report.html"
    write_text(path, page, InputError)
    return path
