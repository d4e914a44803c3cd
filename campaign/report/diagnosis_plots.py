"""The diagnosis plots: the residuals against the winning cause's signature, every joint angle and time, and the
joint error map's curves with their uncertainty bands."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from trackcal.calib.diagnose import Diagnosis
from trackcal.calib.diagnose.extensions import approach_signs
from trackcal.calib.diagnose.fits import rms
from trackcal.calib.diagnose.joint_map import map_curve
from trackcal.calib.identify.solver import Identification
from trackcal.calib.model.cell import Cell
from trackcal.calib.model.kinematics import Kinematics
from trackcal.calib.model.pinmodel import gravity_torques
from trackcal.campaign.report.figures import save_png, subplots, tight


def main_cause_theta(d: Diagnosis) -> np.ndarray:
    """The extended model's parameters with every cause but the main one zeroed (`Extension.parts`, in
    parameter order)."""
    ext, theta = d.extended.extension, d.extended.ext
    main = [c == d.cause for c, names in ext.parts() for _ in names]
    return np.where(main, theta, 0.0)


def signature(cell: Cell, d: Diagnosis) -> tuple[str, np.ndarray, int | None]:
    """(label, x, joint): what the winning cause's error depends on, per row."""
    q = np.radians(d.table.q_deg)
    ext = d.extended.extension if d.extended is not None else None
    if d.cause == "thermal_drift" or d.cause == "station_shift":
        return "time since campaign start (s)", d.table.t_s, None
    if ext is None or ext.joint_features is None:
        return "time since campaign start (s)", d.table.t_s, None
    # the joint whose extension moves the reflectors most
    offsets = ext.joint_offsets(main_cause_theta(d))
    j = int(np.argmax(offsets.std(axis=0)))
    if d.cause == "joint_compliance":
        return f"gravity torque on joint {j + 1} (N m)", gravity_torques(cell.chain, q)[:, j], j
    if d.cause == "backlash":
        return f"approach direction of joint {j + 1}", approach_signs(q)[:, j], j
    return f"joint {j + 1} angle (deg)", d.table.q_deg[:, j], j


def implied_joint_error(cell: Cell, res: Identification, table, residuals: np.ndarray, j: int) -> np.ndarray:
    """Residuals read as an error of joint j (deg): least squares along the reflector's motion for q_j."""
    kin = Kinematics(cell.chain, res.params)
    jac = kin.jacobian(np.radians(table.q_deg), np.array([res.points[p] for p in table.point]), res.dev)
    rot = np.array([res.stations[s].rotation for s in table.station])
    col = np.einsum("rij,rj->ri", rot, jac.d_q[:, :, j])
    return np.degrees(np.einsum("ri,ri->r", col, residuals) / np.einsum("ri,ri->r", col, col))


def plots(cell: Cell, d: Diagnosis, out_dir: Path) -> list[Path]:
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    label, x, j = signature(cell, d)
    # without an extension the model after is the geometric one: one panel, not two identical ones
    fig, axes = subplots(1, 2 if d.extended is not None else 1, figsize=(11, 4), sharey=True, squeeze=False)
    axes = axes[0]
    after = d.extended or d.geometric
    if j is not None:
        # component + residual: the extension's fitted error of joint j plus what is left, against the signature
        ext = d.extended.extension
        fitted = np.degrees(ext.joint_offsets(main_cause_theta(d))[:, j]) * 1000.0
        left = implied_joint_error(cell, after, d.table, after.residuals, j) * 1000.0
        panels = (
            (axes[0], fitted + left, f"fitted {d.cause} of joint {j + 1} + residual"),
            (axes[1], left, f"extended model residual: RMS {rms(after.residuals) * 1000:.1f} µm"),
        )
        ylabel = f"joint {j + 1} error (mdeg)"
    else:
        panels = (
            (
                axes[0],
                np.linalg.norm(d.geometric.residuals, axis=1) * 1000.0,
                f"geometric model: RMS {rms(d.geometric.residuals) * 1000:.1f} µm",
            ),
        )
        if d.extended is not None:
            panels += (
                (
                    axes[1],
                    np.linalg.norm(after.residuals, axis=1) * 1000.0,
                    f"{d.cause}: RMS {rms(after.residuals) * 1000:.1f} µm",
                ),
            )
        ylabel = "|residual| (µm)"
    for ax, y, title in panels:
        for sid in sorted(set(d.table.station)):
            m = np.array(d.table.station) == sid
            ax.plot(x[m], y[m], ".", label=sid)
        ax.set_xlabel(label)
        ax.set_ylabel(ylabel)
        ax.set_title(title)
        ax.grid(alpha=0.3)
    axes[0].legend()
    fig.suptitle(f"diagnosis: {d.cause} (noise floor {d.noise_floor_mm * 1000:.1f} µm, {d.floor_source})")
    tight(fig)
    written.append(save_png(fig, out_dir / "signature.png", dpi=110))
    # residual structure against every joint angle and time, geometric model
    n = cell.chain.dof
    fig, axes = subplots(2, (n + 2) // 2, figsize=(14, 6))
    norm = np.linalg.norm(d.geometric.residuals, axis=1) * 1000.0
    for k, ax in enumerate(axes.ravel()):
        if k < n:
            ax.plot(d.table.q_deg[:, k], norm, ".", ms=3)
            ax.set_xlabel(f"q{k + 1} (deg)")
        elif k == n:
            ax.plot(d.table.t_s, norm, ".", ms=3)
            ax.set_xlabel("t (s)")
        else:
            ax.axis("off")
            continue
        ax.set_ylabel("|residual| (µm)")
        ax.grid(alpha=0.3)
    fig.suptitle("geometric residuals against joint angles and time")
    tight(fig)
    written.append(save_png(fig, out_dir / "structure.png", dpi=110))
    return written


def error_map_curves(fits: dict[str, Identification], path: Path, joint_names: list[str] | None = None) -> Path:
    """Each mapped joint's fitted error curve (mdeg) with its 95 % band over the arc it was fitted on, one panel
    per joint, one line per fit (e.g. two series, to see where they agree)."""
    joints = sorted({j for res in fits.values() for j in res.extension.meta["arcs"]})
    fig, axes = subplots(len(joints), 1, figsize=(11, 2.4 * len(joints)), squeeze=False)
    for ax, j in zip(axes[:, 0], joints, strict=True):
        arcs = {label: res.extension.meta["arcs"][j] for label, res in fits.items() if j in res.extension.meta["arcs"]}
        ref = min(a.to_doc()["from_deg"] for a in arcs.values())  # every fit drawn on the window ref .. ref + 360
        for label, arc in arcs.items():
            q = arc.start + np.linspace(0.0, arc.length, 1500)
            value, sd = map_curve(fits[label], j, q)
            x = np.mod(np.degrees(q) - ref, 360.0) + ref
            cut = np.flatnonzero(np.diff(x) < 0) + 1  # where the arc wraps past the window's end: break the line
            x, value, sd = (np.insert(v, cut, np.nan) for v in (x, value, sd))
            (line,) = ax.plot(x, np.degrees(value) * 1000.0, lw=1.0, label=label)
            ax.fill_between(
                x,
                np.degrees(value - 1.96 * sd) * 1000.0,
                np.degrees(value + 1.96 * sd) * 1000.0,
                color=line.get_color(),
                alpha=0.25,
                lw=0,
            )
        ax.set_ylabel(f"{joint_names[j] if joint_names else f'joint {j + 1}'}\nerror (mdeg)")
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=8, loc="upper right")
    axes[-1, 0].set_xlabel("joint angle (deg)")
    fig.suptitle("joint error map: fitted curve of each joint, 95 % band")
    tight(fig)
    path.parent.mkdir(parents=True, exist_ok=True)
    return save_png(fig, path, dpi=110)
