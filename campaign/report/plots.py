"""The report's plots, each drawn from what the analysis holds (PNG, off-screen): the residuals per axis (paper
Fig. 10) and per configuration (Fig. 11), the identified parameters, the plan's configurations."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from trackcal.calib.io.table import MeasurementTable
from trackcal.calib.model.cell import Cell
from trackcal.campaign.report.figures import save_png, subplots, tight
from trackcal.campaign.report.residuals import Residuals, per_pose_rms, pose_order


def plot_histograms(res: Residuals, path: Path) -> Path:
    """Paper Fig. 10: residuals after calibration per axis, with the fitted normal density."""
    fig, axes = subplots(1, 3, figsize=(13, 3.8), sharey=True)
    for a, ax in enumerate(axes):
        r = res.after[:, a] * 1000.0
        mu, sd = float(r.mean()), float(r.std(ddof=1)) if len(r) > 1 else 0.0
        counts, edges, _ = ax.hist(r, bins=max(8, min(40, len(r) // 6)), color="#4a7ebb", alpha=0.75)
        if sd > 0:
            x = np.linspace(edges[0], edges[-1], 200)
            density = np.exp(-0.5 * ((x - mu) / sd) ** 2) / (sd * np.sqrt(2.0 * np.pi))  # the normal pdf
            ax.plot(x, len(r) * (edges[1] - edges[0]) * density, "k-", lw=1.5, label=f"N({mu:.1f}, {sd:.1f}) µm")
        for sign in (-1, 1):
            ax.axvline(
                sign * res.floor_mm * 1000.0,
                color="#c0504d",
                ls="--",
                lw=1.2,
                label=f"± noise floor {res.floor_mm * 1000:.1f} µm (per coordinate)" if sign > 0 else None,
            )
        ax.set_ylim(0.0, 1.35 * max(float(counts.max()), 1.0))  # head room: the legend covers no bar
        ax.legend(loc="upper center", fontsize=7, framealpha=0.95)
        ax.set_xlabel(f"residual {'xyz'[a]} (µm)")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("measurements")
    fig.suptitle("residuals after calibration, per axis (station frames), with the fitted normal")
    tight(fig)
    return save_png(fig, path, dpi=100)


def plot_per_pose(table: MeasurementTable, res: Residuals, path: Path) -> Path:
    """Paper Fig. 11: residual distance per configuration, before and after calibration."""
    poses = pose_order(table)
    x = np.arange(len(poses))
    fig, axes = subplots(2, 1, figsize=(13, 6), sharex=True)
    for ax, r, label, color in (
        (axes[0], res.before, "before calibration (nominal robot)", "#c0504d"),
        (axes[1], res.after, "after calibration", "#4a7ebb"),
    ):
        ax.bar(x, per_pose_rms(table, r) * 1000.0, color=color, label="RMS distance")
        # the RMS 3-D distance that tracker noise alone gives: sqrt(3) x the floor of one coordinate
        rms_pose = per_pose_rms(table, r) * 1000.0
        floor3 = np.sqrt(3.0) * res.floor_mm * 1000.0
        floor_label = f"noise floor of a 3-D distance: √3 × {res.floor_mm * 1000:.1f} = {floor3:.1f} µm"
        ax.axhline(floor3, color="k", ls="--", lw=1.2, label=floor_label)
        ax.set_ylim(0.0, 1.3 * max(float(rms_pose.max()), floor3))  # head room: the legend covers no bar
        ax.legend(loc="upper center", fontsize=8, ncol=2, framealpha=0.95)
        ax.set_ylabel("RMS distance (µm)")
        ax.set_title(f"{label}: residual distance per configuration", fontsize=10)
        ax.grid(alpha=0.3, axis="y")
    step = max(1, len(poses) // 40)
    axes[1].set_xticks(x[::step])
    axes[1].set_xticklabels([poses[i].replace("$", r"\$") for i in x[::step]], rotation=90, fontsize=7)
    axes[1].set_xlabel("configuration (pose id)")
    tight(fig)
    return save_png(fig, path, dpi=100)


def plot_parameters(model_doc: dict, path: Path) -> Path | None:
    """Deviations with their 95 % intervals, lengths and angles in two panels."""
    pars = model_doc.get("parameters", {})
    if not pars:
        return None
    groups = [(u, [(n, p) for n, p in pars.items() if p.get("unit") == u]) for u in ("mm", "deg")]
    groups = [(u, g) for u, g in groups if g]
    fig, axes = subplots(1, len(groups), figsize=(6 * len(groups) + 1, 3.8), squeeze=False)
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
    tight(fig)
    return save_png(fig, path, dpi=100)


def plot_plan(plan_doc: dict, cell: Cell, path: Path) -> Path | None:
    """The plan's configurations against the joint limits (and the test pose)."""
    poses = np.asarray(plan_doc.get("poses_deg") or [], dtype=float)
    if poses.ndim != 2 or poses.shape[1] != cell.chain.dof:
        return None
    n = cell.chain.dof
    fig, ax = subplots(figsize=(9, 3.8))
    lim = np.degrees(cell.chain.limits_array())
    j = np.arange(1, n + 1)
    finite = np.isfinite(lim).all(axis=1)
    ax.bar(
        j[finite],
        (lim[finite, 1] - lim[finite, 0]),
        bottom=lim[finite, 0],
        width=0.35,
        color="#ddd",
        label="joint range",
    )
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
    tight(fig)
    return save_png(fig, path, dpi=100)
