"""Real data: calibrate the IPA UR10 on Series B, validate on Series D (months later, tracker moved).

Data: christianlandgraf/ipa-robot-accuracy (MIT), Landgraf et al., "A Hybrid Neural Network Approach for
Increasing the Absolute Accuracy of Industrial Robots", IEEE CASE 2021, pp. 468-474.

1. Import both series (`campaign.importers.ipa_ur10`), one point per pose (the T-Mac centre) or with virtual points.
2. Parameters: the irreducible set of `calib.params`, cut to what one point per pose can identify
   (`calib.subset.identifiable_subset`: the T-Mac centre lies on the wrist_3 axis).
3. Identify on B (robot deviations, station, tool point; i.i.d. weighting), and the reverse on D.
4. Validate on the other series with robot and tool point fixed: `identify(..., fixed=("robot", "points"))`
   re-estimates only its station.
5. Diagnose B (`calib.diagnose.diagnose`, what `trackcal diagnose --weighting iid --params ...` runs), validate
   every joint-type candidate on D the same way, and test the temperature column.
6. Write docs/ur10-real-data.md and plots under docs/img/.

`python -m studies.ur10_ipa.study [--data DIR] [--out docs/ur10-real-data.md]` (several minutes: the diagnosis
cross-validates every candidate on 1495 poses).
"""

from __future__ import annotations

import argparse
import os
from dataclasses import dataclass, field
from pathlib import Path

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
from scipy.spatial.transform import Rotation

from calib.cell import Cell, load_cell
from calib.diagnose import Diagnosis, diagnose, fit_cause
from calib.extensions import JOINT_CAUSES, Extension, build_extension
from calib.identify import Identification, identify, residual_stats
from calib.kinematics import Kinematics
from calib.params import Param, irreducible_params
from calib.rigid import rot_axis
from calib.subset import identifiable_subset
from calib.table import MeasurementTable
from campaign.importers.ipa_ur10 import ANGLES, JOINTS, POINT, read_columns, read_ipa_series, table_covariances

# The data set lives next to the repository (../shared/data); TRACKCAL_IPA_DATA points elsewhere.
DATA = Path(os.environ.get("TRACKCAL_IPA_DATA")
            or Path(__file__).resolve().parents[3] / "shared" / "data" / "ipa-robot-accuracy")  # fmt: skip
SERIES = {"B": "Series_B/measurements_joint_configurations.csv", "D": "Series_D/measurements_iso_cubes.csv"}
TRAFO = "Series_B/Trafo_TM_F_init.txt"
CITATION = ("Landgraf, Ernst, Schleth, Fabritius, Huber, \"A Hybrid Neural Network Approach for Increasing the "
            "Absolute Accuracy of Industrial Robots\", IEEE CASE 2021, pp. 468-474")  # fmt: skip
STATION_ONLY = ("robot", "points")
BASE_LINK = rot_axis(2, np.pi)  # ROS base_link <- DH base: a half turn about z


def rms3(res: np.ndarray) -> float:
    """3-D RMS (mm): the root mean square of the distance errors."""
    return float(np.sqrt(np.mean(np.sum(res**2, axis=1))))


def base_frame(res: Identification) -> np.ndarray:
    """Residuals (N, 3) of a one-station fit turned from the station frame into the robot base frame."""
    (station,) = res.stations.values()
    return res.residuals @ station.rotation  # R_s^T r, row by row


def validate(chain, fit: Identification, table: MeasurementTable, extension: Extension | None = None):
    """`fit`'s robot model and tool points on another table, its station alone re-estimated."""
    return identify(chain, table, fit.points, fit.params, dev0=fit.dev, extension=extension, ext0=fit.ext,
                    fixed=STATION_ONLY)  # fmt: skip


def tmac_rows(table: MeasurementTable) -> np.ndarray:
    return np.flatnonzero(np.array(table.point) == POINT)


def conventions(data: Path, chain, point_mm: np.ndarray) -> dict:
    """Checks of the file conventions on B: commanded goal vs forward kinematics, Euler convention."""

    cols = read_columns(data / SERIES["B"], ["Goal x", "Goal y", "Goal z", *ANGLES, *JOINTS])
    q = np.column_stack([cols[c] for c in JOINTS])  # rad in the file
    r_fl, o_fl = Kinematics(chain, []).end_frames(q)
    tmac = (o_fl + r_fl @ point_mm) @ BASE_LINK.T
    goal = 1000.0 * np.column_stack([cols[c] for c in ("Goal x", "Goal y", "Goal z")])
    trafo = np.loadtxt(data / TRAFO)
    angles = np.column_stack([cols[c] for c in ANGLES])
    spread = {}
    for conv in ("XYZ", "xyz", "ZYX", "zyx"):
        r_meas = Rotation.from_euler(conv, angles, degrees=True).as_matrix()
        # tracker <- base implied by each row: R_meas (T-Mac axes = columns of the Trafo rotation)^-1 R_flange^-1
        implied = Rotation.from_matrix(r_meas @ trafo[:3, :3].T @ np.transpose(r_fl, (0, 2, 1)))
        dev = (implied * implied.mean().inv()).magnitude()
        spread[conv] = float(np.degrees(np.sqrt(np.mean(dev**2))))
    return {"goal_rms_mm": rms3(tmac - goal), "goal_max_mm": float(np.linalg.norm(tmac - goal, axis=1).max()),
            "euler_spread_deg": spread}  # fmt: skip


@dataclass
class CandidateCheck:
    cause: str
    n_params: int
    cv_rms3_mm: float  # diagnose's pose-wise cross-validation on B, 3-D
    d_rms3_mm: float | None  # held out on D, station re-estimated only (joint-type causes)
    significant: bool
    values: dict[str, float] = field(default_factory=dict)  # fitted on all of B, boundary units
    unit: str = ""
    detail: dict = field(default_factory=dict)  # station_shift: station and change time


@dataclass
class Study:
    cell: Cell
    params: list[Param]
    dropped: list[tuple[Param, str]]
    b: MeasurementTable
    d: MeasurementTable
    conv: dict
    fit_b: Identification
    nominal_b: Identification  # nominal chain, Trafo tool point, station only
    nominal_b_free_point: Identification  # nominal chain, station and tool point fitted
    nominal_d: Identification
    after_d: Identification
    fit_d: Identification
    after_b: Identification  # D's model on B, station only
    virtual: list[dict]
    correlation: float
    diagnosis: Diagnosis
    candidates: list[CandidateCheck]
    temperature: dict = field(default_factory=dict)


def temperature_effect(chain, table: MeasurementTable, fit: Identification) -> dict:
    """Does the temperature column explain the residuals?  Correlations of the base-frame residuals with it,
    and the thermal growth of the arm driven by the measured temperature (1 parameter, ppm/K) fitted jointly."""
    temp = np.array(table.extra["temp_c"], dtype=float)
    rb = base_frame(fit)
    corr = {f"{a}": float(np.corrcoef(temp, rb[:, i])[0, 1]) for i, a in enumerate("xyz")}
    corr["norm"] = float(np.corrcoef(temp, np.linalg.norm(rb, axis=1))[0, 1])
    ext = Extension("thermal_drift", ["alpha"], ["ppm/K"], np.array([1e6]), growth=(temp - temp.mean())[:, None],
                    pivot=chain.base[:3, 3].copy())
    res = identify(chain, table, fit.points, fit.params, extension=ext)
    return {"range_c": (float(temp.min()), float(temp.max())), "levels": int(len(np.unique(temp))),
            "corr": corr, "alpha_ppm_k": float(res.ext[0] * 1e6), "alpha_ci95": float(res.ext_ci95()[0] * 1e6),
            "rms3_with": rms3(res.residuals), "rms3_without": rms3(fit.residuals)}  # fmt: skip


def run(data: Path = DATA, virtual: tuple[int, ...] = (2, 3, 6), levers: tuple[float, ...] = (50.0, 200.0)) -> Study:
    cell = load_cell("ur10-ipa")
    chain = cell.chain
    tmac = {POINT: cell.tool_points[POINT]}
    b = read_ipa_series(data / SERIES["B"], station="B")
    d = read_ipa_series(data / SERIES["D"], station="D")
    irr, _ = irreducible_params(chain)
    params, dropped = identifiable_subset(chain, irr, np.radians(b.q_deg), tmac)
    fit_b = identify(chain, b, tmac, params)
    fit_d = identify(chain, d, tmac, identifiable_subset(chain, irr, np.radians(d.q_deg), tmac)[0])
    virt = []
    for k, lever in [(k, 100.0) for k in virtual] + [(2, lev) for lev in levers]:
        bv = read_ipa_series(data / SERIES["B"], station="B", virtual_points=k, lever_mm=lever)
        scale = lever / 100.0  # the tool file's virtual points sit at 100 mm: start from the scaled offsets
        pts = {p: tmac[POINT] + scale * (cell.tool_points[p] - tmac[POINT]) for p in dict.fromkeys(bv.point)}
        fit = identify(chain, bv, pts, irr)  # the virtual points make the whole irreducible set identifiable
        virt.append({"k": k, "lever_mm": lever, "n_params": len(irr), "after_d": validate(chain, fit, d),
                     "fit_b_tmac_rms": rms3(fit.residuals[tmac_rows(bv)]), "fit_b_all_rms": rms3(fit.residuals),
                     "point": fit.points[POINT]})  # fmt: skip
    covs = table_covariances(read_ipa_series(data / SERIES["B"], station="B", virtual_points=1))
    rho = np.array([c[0, 3] / np.sqrt(c[0, 0] * c[3, 3]) for _, c in covs])
    diag = diagnose(chain, b, tmac, params, None)
    checks = []
    for c in diag.candidates:
        check = CandidateCheck(c.cause, c.n_params, np.sqrt(3) * c.holdout_rms_mm, None, c.significant,
                               detail=dict(c.detail))  # fmt: skip
        if c.cause in JOINT_CAUSES:
            cf = fit_cause(chain, b, tmac, params, None, c.cause)
            res, ext = cf.result, cf.extension
            ext_d = build_extension(c.cause, chain, d, names=ext.names)
            check.d_rms3_mm = rms3(validate(chain, res, d, ext_d).residuals)
            check.values = dict(zip(ext.names, (res.ext * ext.to_boundary).tolist(), strict=True))
            check.unit = ext.units[0]
        checks.append(check)
    checks.sort(key=lambda c: c.cv_rms3_mm)
    return Study(
        cell=cell, params=params, dropped=dropped, b=b, d=d, conv=conventions(data, chain, tmac[POINT]),
        fit_b=fit_b, nominal_b=identify(chain, b, tmac, [], fixed=STATION_ONLY),
        nominal_b_free_point=identify(chain, b, tmac, []), nominal_d=identify(chain, d, tmac, [], fixed=STATION_ONLY),
        after_d=validate(chain, fit_b, d), fit_d=fit_d, after_b=validate(chain, fit_d, b), virtual=virt,
        correlation=float(np.median(rho)), diagnosis=diag, candidates=checks,
        temperature=temperature_effect(chain, b, fit_b),
    )  # fmt: skip


def _tmac_base(study: Study, table: MeasurementTable) -> np.ndarray:
    fb = study.fit_b
    return Kinematics(fb.chain, fb.params).points(np.radians(table.q_deg), fb.points[POINT], fb.dev)


NAMES = ["shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3"]


def plots(study: Study, img_dir: Path) -> list[Path]:
    matplotlib.use("Agg")

    img_dir.mkdir(parents=True, exist_ok=True)
    written = []

    def save(fig, name):
        fig.tight_layout()
        path = img_dir / name
        fig.savefig(path, dpi=110)
        plt.close(fig)
        written.append(path)

    d = study.d
    before = np.linalg.norm(study.nominal_d.residuals, axis=1)
    after = np.linalg.norm(study.after_d.residuals, axis=1)
    fig, axes = plt.subplots(2, 3, figsize=(12, 6.5), sharey=True)
    for j, ax in enumerate(axes.ravel()):
        ax.plot(d.q_deg[:, j], before, ".", ms=3, alpha=0.5, label="nominal model")
        ax.plot(d.q_deg[:, j], after, ".", ms=3, alpha=0.6, label="calibrated on B")
        ax.set_xlabel(f"{NAMES[j]} (deg)")
        if j % 3 == 0:
            ax.set_ylabel("3-D error on D (mm)")
    axes[0, 0].legend(loc="upper left", fontsize=8)
    fig.suptitle("UR10, Series D held out: T-Mac position error vs joint angle (station re-fitted only)")
    save(fig, "ur10-d-errors-vs-joints.png")

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    bins = np.linspace(0, max(before.max(), after.max()) * 1.02, 40)
    axes[0].hist(before, bins=bins, alpha=0.6, label=f"nominal, RMS {rms3(study.nominal_d.residuals):.2f} mm")
    axes[0].hist(after, bins=bins, alpha=0.6, label=f"calibrated on B, RMS {rms3(study.after_d.residuals):.2f} mm")
    axes[0].set_xlabel("3-D error (mm)")
    axes[0].set_ylabel("poses")
    axes[0].legend(fontsize=8)
    axes[0].set_title("Series D, held out")
    rb = base_frame(study.after_d)
    for a, name in enumerate("xyz"):
        axes[1].hist(rb[:, a], bins=40, histtype="step", label=f"{name} (base frame)")
    axes[1].set_xlabel("error after calibration (mm)")
    axes[1].legend(fontsize=8)
    axes[1].set_title("per axis, robot base frame")
    save(fig, "ur10-d-error-histogram.png")

    fig = plt.figure(figsize=(6, 5))
    ax = fig.add_subplot(projection="3d")
    pb = _tmac_base(study, d)
    sc = ax.scatter(pb[:, 0], pb[:, 1], pb[:, 2], c=after, s=6, cmap="viridis")
    fig.colorbar(sc, ax=ax, shrink=0.7, label="3-D error after (mm)")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_zlabel("z (mm)")
    ax.set_title("Series D: where the calibrated model errs (base frame)")
    save(fig, "ur10-d-errors-cartesian.png")

    # what the geometric model misses: B's own fit residuals, base frame, against every joint angle
    b = study.b
    rb = base_frame(study.fit_b)
    fig, axes = plt.subplots(3, 6, figsize=(17, 8), sharex="col", sharey=True)
    for a, name in enumerate("xyz"):
        for j in range(6):
            ax = axes[a, j]
            ax.plot(b.q_deg[:, j], rb[:, a], ".", ms=2, alpha=0.5)
            ax.axhline(0.0, color="k", lw=0.5)
            ax.grid(alpha=0.3)
            if a == 2:
                ax.set_xlabel(f"{NAMES[j]} (deg)")
            if j == 0:
                ax.set_ylabel(f"residual {name}, base (mm)")
    fig.suptitle(f"Series B, geometric fit ({rms3(study.fit_b.residuals):.3f} mm RMS 3-D): residuals against the "
                 "joint angles")  # fmt: skip
    save(fig, "ur10-b-residuals-vs-joints.png")

    # ... and against the measurement order (the only time the files keep), with the temperature column
    fig, axes = plt.subplots(2, 1, figsize=(12, 6))
    for ax, res, table, label in ((axes[0], study.fit_b, b, "B, fit"), (axes[1], study.after_d, d, "D, held out")):
        r = base_frame(res)
        rows = np.arange(len(table))
        for a, name in enumerate("xyz"):
            ax.plot(rows, r[:, a], ".", ms=2, alpha=0.5, label=name)
        ax.set_ylabel(f"{label}: residual (mm)")
        ax.grid(alpha=0.3)
        tw = ax.twinx()
        tw.plot(rows, np.array(table.extra["temp_c"], dtype=float), "k-", lw=1.0, label="temperature")
        tw.set_ylabel("temperature (degC)")
        ax.legend(loc="upper left", fontsize=8, ncol=3)
    axes[1].set_xlabel("row (measurement order)")
    fig.suptitle("Residuals (robot base frame) in measurement order, and the temperature column")
    save(fig, "ur10-residuals-vs-order.png")
    return written


def _row(label: str, res: Identification) -> str:
    r = base_frame(res)
    axes = " | ".join(f"{np.sqrt(np.mean(r[:, a] ** 2)):.3f}" for a in range(3))
    return f"| {label} | {axes} | {rms3(r):.3f} | {residual_stats(r)['dist_max_mm']:.3f} |"


def _deg_or_mm(p: Param, v: float) -> str:
    return f"{v:+.4f} mm" if p.is_length else f"{np.degrees(v):+.4f} deg"


def _values_note(study: Study) -> str:
    """What the joint-type candidates' fitted values say, in words, from the fits on all of B."""
    by = {c.cause: c for c in study.candidates}
    off_axis = float(np.hypot(*study.fit_b.points[POINT][:2]))
    notes = []
    if "joint_compliance" in by and {"c2", "c3"} <= set(by["joint_compliance"].values):
        v = by["joint_compliance"].values
        k = [1.0 / abs(np.radians(v[n]) / 1000.0) for n in ("c2", "c3")]
        notes.append(f"the compliances of shoulder and elbow ({v['c2']:+.2f}, {v['c3']:+.2f} deg/kNm, stiffness"
                     f" {k[0] / 1e3:.0f} and {k[1] / 1e3:.0f} kNm/rad) are of the order of a harmonic drive's, and"
                     " yet do not transfer")  # fmt: skip
    if "encoder_scale" in by and by["encoder_scale"].values:
        v = [x for n, x in by["encoder_scale"].values.items() if not n.endswith("6")]
        notes.append(f"encoder scales of {min(v):+.0f} to {max(v):+.0f} ppm are far beyond any encoder error")
    if "cyclic_error" in by and by["cyclic_error"].values:
        v = [abs(x) for n, x in by["cyclic_error"].values.items() if not n.endswith("_6")]
        notes.append(f"cyclic amplitudes up to {max(v):.2f} deg would be centimetres at the probe")
    sixth = [n for c in study.candidates for n in c.values if n.endswith("6")]
    text = "; ".join(notes) + "."
    if sixth:
        text += (f" Parameters of joint 6 ({', '.join(sixth)}) are kept by `diagnose` although wrist_3 moves the"
                 f" T-Mac by its {off_axis:.2f} mm offset from the axis only: their values are meaningless.")
    return text


def report(study: Study, out: Path, images: list[Path]) -> str:
    fb, dg, tmp, cv = study.fit_b, study.diagnosis, study.temperature, study.conv
    b_fit, d_after, d_nom = rms3(fb.residuals), rms3(study.after_d.residuals), rms3(study.nominal_d.residuals)
    rel = [p.relative_to(out.parent).as_posix() if p.is_relative_to(out.parent) else str(p) for p in images]
    yb, yd = _tmac_base(study, study.b)[:, 1], _tmac_base(study, study.d)[:, 1]
    best = study.candidates[0]
    shift = next((c.detail for c in study.candidates if c.cause == "station_shift" and c.detail), None)
    geo_cv = np.sqrt(3) * dg.holdout_geometric_mm
    ry = np.array(study.d.extra["ry_deg"], dtype=float)
    k2 = next(v for v in study.virtual if v["k"] == 2 and v["lever_mm"] == 100.0)
    lines = [
        "# UR10 on real laser-tracker data (IPA series B and D)",
        "",
        "Generated by `python -m studies.ur10_ipa.study`. Data: the public data set "
        "christianlandgraf/ipa-robot-accuracy",
        f"(MIT licence) of {CITATION}. A UR10 carries a Leica T-Mac 6-DoF probe; a Leica laser tracker measures",
        "it. Series B (1495 poses, November 2020) calibrates, Series D (632 poses on ISO 9283-style cubes,",
        "March 2021, tracker set up elsewhere) validates. All errors are 3-D RMS in mm unless said otherwise.",
        "",
        "## Conventions checked on the data",
        "- Robot: `configs/robots/ur10.yaml`, Universal Robots' DH values (UR10, CB3) written as joint rotations",
        "  about z, link translations (a, 0, d) and fixed `link_rpy_deg` rotations; joint values are the ROS",
        "  joint_states one to one. The commanded `Goal x/y/z` agree with our forward kinematics of the T-Mac",
        f"  point at (0, 0, 109) mm to {cv['goal_rms_mm']:.3f} mm RMS (max {cv['goal_max_mm']:.3f}; ROS base_link = DH",
        "  base turned 180 deg about z), which pins the joint conventions and says the cell was programmed with",
        "  these nominal values and that tool point.",
        "- T-Mac point: `Trafo_TM_F_init.txt` read as flange-in-T-Mac puts the T-Mac centre at (0, 0, 109) mm in the",
        f"  flange frame. The measurements put it at {fb.points[POINT][2]:.2f} mm along the flange axis (B fit, 95 % CI"
        f" +-{fb.point_ci95(POINT)[2]:.2f} mm):",
        "  the file's value is an initial one (its name says so). Left at 109 mm, it leaves",
        f"  {rms3(study.nominal_b.residuals):.2f} mm on B with the nominal robot; fitting the station and the point"
        f" gives {rms3(study.nominal_b_free_point.residuals):.2f} mm.",
        "- Orientation: `measurement_rx/ry/rz` are intrinsic X-Y-Z Euler angles (scipy 'XYZ', R = Rx Ry Rz), as the",
        "  data set's own `dataset.py` reads them: the tracker-to-base rotation implied by every row of B is",
        f"  constant to {cv['euler_spread_deg']['XYZ']:.3f} deg RMS with 'XYZ' (T-Mac axes = columns of the Trafo"
        " rotation), against "
        + ", ".join(f"{v:.1f} deg for '{k}'" for k, v in cv["euler_spread_deg"].items() if k != "XYZ") + ".",
        "- Time: the `Timestamp` column was mangled by a spreadsheet (2,02011E+13); `t_s` in the imported tables is",
        "  the row index times a nominal 10 s, not a measured time. The temperature column is quantised to",
        f"  0.125 degC: B {tmp['range_c'][0]:.2f}-{tmp['range_c'][1]:.2f} degC ({tmp['levels']} levels), D"
        f" {min(map(float, study.d.extra['temp_c'])):.2f}-{max(map(float, study.d.extra['temp_c'])):.2f} degC.",
        "",
        "## Identifiable parameters with one point per pose",
        f"The irreducible set of the chain has {len(study.params) + len(study.dropped)} parameters (the three "
        "parallel axes handled by the elimination rules). The T-Mac centre lies on the wrist_3 axis,",
        f"so with its position alone `calib.subset.identifiable_subset` keeps {len(study.params)}:",
        f"{' '.join(p.name for p in study.params)}; dropped:",
        *[f"- `{p.name}`: {why}" for p, why in study.dropped],
        "",
        "## Calibration on B",
        f"B fit ({len(fb.params)} parameters + station + tool point, i.i.d.): {b_fit:.3f} mm RMS 3-D "
        f"(max {residual_stats(fb.residuals)['dist_max_mm']:.3f} mm), {fb.iterations} iterations.",
        f"Nominal robot, station only: {rms3(study.nominal_b.residuals):.3f} mm.",
        "",
        "| parameter | deviation | 95 % CI |",
        "| --- | --- | --- |",
        *[
            f"| {p.name} | {_deg_or_mm(p, v)} | +-{_deg_or_mm(p, c)[1:]} |"
            for p, v, c in zip(fb.params, fb.dev, fb.param_ci95(), strict=True)
        ],  # fmt: skip
        "",
        "## Validation on D (held out, station re-estimated only)",
        "Robot parameters and tool point from B; only D's station is fitted (`identify(..., fixed=(\"robot\",",
        "\"points\"))`, as a shop-floor check after setting the tracker up again would). Per-axis RMS in the robot",
        "base frame, mm:",
        "",
        "| model | x | y | z | 3-D RMS | 3-D max |",
        "| --- | --- | --- | --- | --- | --- |",
        _row("B, nominal (Trafo tool point)", study.nominal_b),
        _row("B, calibrated on B (fit)", fb),
        _row("D, nominal (Trafo tool point)", study.nominal_d),
        _row("D, calibrated on B", study.after_d),
        "",
        f"Held-out gain on D: {d_nom:.3f} -> {d_after:.3f} mm RMS (factor {d_nom / d_after:.2f}). The residual on D",
        f"is {100 * (d_after / b_fit - 1):.0f} % above B's own fit: D reaches where B hardly goes (T-Mac y in the DH"
        f" base: B {yb.min():.0f}..{yb.max():.0f} mm,",
        f"D {yd.min():.0f}..{yd.max():.0f} mm), and four months lie between the series. Neither tracker noise (T-Mac",
        "std columns ~0.01 mm) nor repeatability (UR10 datasheet +-0.1 mm) accounts for it: it is what the",
        "geometric model cannot describe (see the diagnosis below).",
        "",
        "## Reverse direction (calibrate on D, validate on B)",
        f"D fit: {rms3(study.fit_d.residuals):.3f} mm RMS with {len(study.fit_d.params)} parameters; B held out: "
        f"{rms3(study.nominal_b.residuals):.3f} (nominal) -> {rms3(study.after_b.residuals):.3f} mm RMS.",
        f"D's poses keep the probe's orientation almost fixed (tracker ry {ry.mean():.1f} +- {ry.std():.1f} deg), so"
        " the tool point's",
        f"position along the flange axis is hardly observable from D (fitted {study.fit_d.points[POINT][2]:.1f} +-"
        f" {study.fit_d.point_ci95(POINT)[2]:.1f} mm, B says {fb.points[POINT][2]:.1f} mm)",
        "and the model transfers badly to B's varied orientations: calibrate on orientation-rich data.",
        "",
        "## Virtual reference points from the probe's orientation",
        "The paper's enhanced partial-pose idea (several reference points per pose) applied to the T-Mac: K points",
        "at a lever along the probe's axes, computed from the measured position and orientation",
        "(`trackcal import ipa-ur10 --virtual-points K --lever-mm L`). With them the whole irreducible set is",
        "identifiable. Noise model (`campaign.importers.ipa_ur10.pose_covariance`): P_k = p + R v_k, so the "
        "position noise",
        "is common to all points and only lever x angle noise is new; with the file's std columns (position",
        "~0.01 mm, angles ~0.002 deg, 3.5 um at 100 mm) the median correlation of a virtual point's coordinate",
        f"with the T-Mac point's is {study.correlation:.3f}. Six noise sources drive all 3(K+1) coordinates: the",
        "covariance has rank 5 for K = 1 and 6 beyond, so two virtual points carry all the orientation there is",
        "and more only repeat it. The covariance cannot whiten (it is singular) and the std columns are the",
        "scatter within one tracker reading, not its accuracy, so the fits use i.i.d. weights; then the lever",
        "sets how much orientation counts against position.",
        "",
        "| points per pose | lever mm | parameters | B fit, T-Mac | B fit, all points | D held out | D max |",
        "| --- | --- | --- | --- | --- | --- | --- |",
        f"| 1 (T-Mac) | - | {len(study.params)} | {b_fit:.3f} | {b_fit:.3f} | {d_after:.3f} | "
        f"{residual_stats(study.after_d.residuals)['dist_max_mm']:.3f} |",
        *[
            f"| 1 + {v['k']} virtual | {v['lever_mm']:.0f} | {v['n_params']} | {v['fit_b_tmac_rms']:.3f} | "
            f"{v['fit_b_all_rms']:.3f} | {rms3(v['after_d'].residuals):.3f} | "
            f"{residual_stats(v['after_d'].residuals)['dist_max_mm']:.3f} |"
            for v in study.virtual
        ],
        "",
        "Held-out accuracy is measured on the T-Mac point only, the same for every row. With two virtual points at",
        f"100 mm the held-out error on D is {rms3(k2['after_d'].residuals):.3f} mm against {d_after:.3f} "
        f"({100 * (1 - rms3(k2['after_d'].residuals) / d_after):.0f} % better); more points or a longer lever add"
        " nothing, as the noise model's rank says.",
        "",
        "## Diagnosis: what the geometric model gets wrong",
        "`trackcal diagnose` on the imported Series B (`--weighting iid --params "
        + ",".join(p.name for p in study.params) + "`; the same call",
        "`calib.diagnose.diagnose` this study makes). Every candidate cause is fitted jointly with the geometric",
        "model and cross-validated by pose (5 folds of whole poses); the joint-type candidates are also fitted on",
        "all of B and validated on D with D's station alone re-estimated. 3-D RMS in mm (the CLI prints",
        "per-coordinate um, a factor sqrt(3) smaller):",
        "",
        "| model | extra parameters | B cross-validated | D held out | significant on B |",
        "| --- | --- | --- | --- | --- |",
        f"| geometric | - | {geo_cv:.3f} | {d_after:.3f} | - |",
        *[
            f"| {c.cause} | {c.n_params} | {c.cv_rms3_mm:.3f} | "
            f"{'-' if c.d_rms3_mm is None else f'{c.d_rms3_mm:.3f}'} | {'yes' if c.significant else 'no'} |"
            for c in study.candidates
        ],
        "",
        f"Verdict: **{dg.cause}**. The tracker noise floor is {np.sqrt(3) * dg.noise_floor_mm:.3f} mm"
        f" ({dg.floor_source}); the geometric fit leaves {b_fit:.3f}.",
        f"Every candidate is significant on B (F test, BIC, cross-validation), the best, {best.cause}, lowering the",
        f"cross-validated error from {geo_cv:.3f} to {best.cv_rms3_mm:.3f} mm, but none removes half of the excess"
        " over the floor,",
        "which `diagnose` asks before naming a cause. And none carries over to the other series: every joint-type",
        f"candidate predicts D worse than the geometric model ({d_after:.3f} mm): "
        + ", ".join(f"{c.cause} {c.d_rms3_mm:.3f}" for c in study.candidates if c.d_rms3_mm is not None) + ".",
        "B's folds hold out poses among poses like them; D is a different workspace (see above), and there the",
        "candidates' parameters show what they are: "
        + _values_note(study) + " They absorb B-specific structure",
        "together with the geometric parameters over B's joint ranges, and extrapolate badly. The time-based",
        "candidates (thermal_drift, station_shift) run on the row order, the files keeping no clock: a slow",
        "change during B's recording"
        + (f" (best change point after row {int(shift['after_t_s'] / 10) + 1})" if shift else "")
        + " is worth a few percent; it cannot be carried to D, whose rows start again at zero.",
        "",
        "Temperature: the column spans only "
        f"{tmp['range_c'][1] - tmp['range_c'][0]:.2f} degC on B, in {tmp['levels']} quantised levels that wander up"
        " and down over the rows, higher in the second half.",
        "Its correlation with the base-frame residuals: "
        + ", ".join(f"{k} {v:+.2f}" for k, v in tmp["corr"].items()) + ". An arm that grows with the measured",
        f"temperature (one coefficient, fitted with the geometry) comes out at {tmp['alpha_ppm_k']:.0f} +-"
        f" {tmp['alpha_ci95']:.0f} ppm/K and moves the fit",
        f"from {tmp['rms3_without']:.4f} to {tmp['rms3_with']:.4f} mm. Aluminium grows +23 ppm/K: a coefficient of"
        " that sign and size",
        "would change the 1.3 m reach by"
        f" {23e-6 * 1300 * (tmp['range_c'][1] - tmp['range_c'][0]) * 1000:.0f} um over B's range, and the fitted one"
        " is not thermal growth but",
        "the temperature used as one more regressor of B's drift. The temperature explains none of the residual.",
        "",
        "What remains is shown in the last two plots: B's residuals against every joint angle, and both series'",
        "residuals in measurement order with the temperature. The residual depends on the pose, with structure",
        "over tens of degrees of the first three joints that is neither linear in the angle nor in the gravity",
        "torque nor one or two periods per turn, and shows at most a slow drift with the row order. A rigid",
        "chain with constant parameters cannot produce it; the candidates here cannot describe it in a way that",
        "transfers. Describing it needs a richer error model per joint, measured over each joint's whole range",
        "(B and D each cover parts), or a data-driven residual model such as the hybrid neural-network approach",
        "of the CASE 2021 paper these data come from.",
        "",
        "## Against the CASE 2021 paper",
        "The numbers the paper reports for this robot could not be found: the search tools available here hold",
        "the data set's repository (README, `dataset.py`) but not the paper's text or tables, and no secondary",
        "source quoting them. They are therefore not reproduced here rather than guessed; the comparison is left",
        "open.",
        "",
        "## Plots",
        *[f"![{p.stem}]({r})" for p, r in zip(images, rel, strict=True)],
        "",
    ]
    text = "\n".join(lines)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text)
    return text


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="UR10 real-data study (IPA series B and D)")
    ap.add_argument("--data", type=Path, default=DATA, help="ipa-robot-accuracy directory")
    ap.add_argument("--out", type=Path, default=Path("docs/ur10-real-data.md"))
    ap.add_argument("--img", type=Path, default=None, help="plot directory (default: docs/img next to --out)")
    args = ap.parse_args(argv)
    study = run(args.data)
    images = plots(study, args.img or args.out.parent / "img")
    report(study, args.out, images)
    print(f"report written to {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
