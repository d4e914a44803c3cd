"""Real data: calibrate the IPA UR10 on Series B, validate on Series D (months later, tracker moved).

Data: christianlandgraf/ipa-robot-accuracy (MIT), Landgraf et al., "A Hybrid Neural Network Approach for
Increasing the Absolute Accuracy of Industrial Robots", IEEE CASE 2021, pp. 468-474.

1. Import both series (`campaign.importers.ipa_ur10`), one point per pose (the T-Mac centre) or with virtual points.
2. Parameters: the irreducible set of `calib.model.params`, cut to what one point per pose can identify
   (`calib.model.subset.identifiable_subset`: the T-Mac centre lies on the wrist_3 axis).
3. Identify on B (robot deviations, station, tool point; i.i.d. weighting), and the reverse on D.
4. Validate on the other series with robot and tool point fixed: `identify(..., fixed=("robot", "points"))`
   re-estimates only its station.
5. Diagnose B (`calib.diagnose.diagnose`, what `trackcal diagnose --weighting iid --params ...` runs),
   validate every joint-type candidate on D the same way, and test the temperature column.
6. Write docs/ur10-real-data.md and plots under docs/img/.

`python -m studies.ur10_ipa.study [--data DIR] [--out docs/ur10-real-data.md]` (several minutes: the diagnosis
cross-validates every candidate on 1495 poses).
"""

from __future__ import annotations

import argparse
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from string import Template

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
from scipy.spatial.transform import Rotation

from trackcal.calib.diagnose import Diagnosis, diagnose
from trackcal.calib.diagnose.extensions import JOINT_CAUSES
from trackcal.calib.diagnose.fits import fit_cause
from trackcal.calib.identify.solver import Identification, identify, residual_stats
from trackcal.calib.io.table import MeasurementTable
from trackcal.calib.model.cell import Cell, load_cell
from trackcal.calib.model.extension import Extension
from trackcal.calib.model.kinematics import Kinematics
from trackcal.calib.model.params import Param, irreducible_params
from trackcal.calib.model.rigid import rot_axis
from trackcal.calib.model.subset import identifiable_subset
from trackcal.campaign.importers.ipa_ur10 import ANGLES, JOINTS, POINT, read_columns, read_ipa_series, table_covariances
from trackcal.campaign.report.diagnosis_plots import error_map_curves

from .error_map_check import STATION_ONLY, MapCheck, error_map_check, on_other_series
from .orientation import orientation_check

# The data set lives next to the repository (../shared/data); TRACKCAL_IPA_DATA points elsewhere.
DATA = Path(
    os.environ.get("TRACKCAL_IPA_DATA")
    or Path(__file__).resolve().parents[3] / "shared" / "data" / "ipa-robot-accuracy"
)
SERIES = {"B": "Series_B/measurements_joint_configurations.csv", "D": "Series_D/measurements_iso_cubes.csv"}
TRAFO = "Series_B/Trafo_TM_F_init.txt"
CITATION = (
    'Landgraf, Ernst, Schleth, Fabritius, Huber, "A Hybrid Neural Network Approach for Increasing the '
    'Absolute Accuracy of Industrial Robots", IEEE CASE 2021, pp. 468-474'
)
TEMPLATE = Path(__file__).with_name("report.md")
BASE_LINK = rot_axis(2, np.pi)  # ROS base_link <- DH base: a half turn about z


def rms3(res: np.ndarray) -> float:
    """3-D RMS (mm): the root mean square of the distance errors."""
    return float(np.sqrt(np.mean(np.sum(res**2, axis=1))))


def base_frame(res: Identification) -> np.ndarray:
    """Residuals (N, 3) of a one-station fit turned from the station frame into the robot base frame."""
    (station,) = res.stations.values()
    return res.residuals @ station.rotation  # R_s^T r, row by row


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
    return {
        "goal_rms_mm": rms3(tmac - goal),
        "goal_max_mm": float(np.linalg.norm(tmac - goal, axis=1).max()),
        "euler_spread_deg": spread,
    }


@dataclass
class CandidateCheck:
    cause: str
    n_params: int
    cv_rms3_mm: float | None  # diagnose's cross-validation on B, 3-D (None: not cross-validated)
    d_rms3_mm: float | None  # held out on D, station re-estimated only (joint-type causes)
    significant: bool
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
    diagnosis_d: Identification | None = None  # diagnose's chosen model on D, D's station alone re-estimated
    error_map: MapCheck | None = None
    orientation: dict = field(default_factory=dict)  # model -> RMS angular residual (mrad), see .orientation


def temperature_effect(chain, table: MeasurementTable, fit: Identification) -> dict:
    """Does the temperature column explain the residuals?  Correlations of the base-frame residuals with it,
    and the thermal growth of every length driven by the measured temperature (1 parameter, ppm/K) fitted jointly,
    about the first joint (the base column fixed) or the base origin (the whole robot), the lower residual
    chosen (as calib.extensions.THERMAL_FORMS)."""
    temp = np.array(table.extra["temp_c"], dtype=float)
    rb = base_frame(fit)
    corr = {f"{a}": float(np.corrcoef(temp, rb[:, i])[0, 1]) for i, a in enumerate("xyz")}
    corr["norm"] = float(np.corrcoef(temp, np.linalg.norm(rb, axis=1))[0, 1])
    fits = {}
    for form, pivot in (("base column fixed", chain.base[:3, 3].copy()), ("whole robot", np.zeros(3))):
        ext = Extension(
            "thermal_drift", ["alpha"], ["ppm/K"], np.array([1e6]), growth=(temp - temp.mean())[:, None], pivot=pivot
        )
        fits[form] = identify(chain, table, fit.points, fit.params, extension=ext)
    form = min(fits, key=lambda f: rms3(fits[f].residuals))
    res = fits[form]
    return {
        "range_c": (float(temp.min()), float(temp.max())),
        "levels": int(len(np.unique(temp))),
        "corr": corr,
        "alpha_ppm_k": float(res.ext[0] * 1e6),
        "alpha_ci95": float(res.ext_ci95()[0] * 1e6),
        "form": form,
        "rms3_with": rms3(res.residuals),
        "rms3_without": rms3(fit.residuals),
    }


def run(data: Path = DATA, virtual: tuple[int, ...] = (2, 3, 6), levers: tuple[float, ...] = (50.0, 200.0)) -> Study:
    cell = load_cell("ur10-ipa")
    chain = cell.chain
    tmac = {POINT: cell.tool_points[POINT]}
    b = read_ipa_series(data / SERIES["B"], station="B")
    d = read_ipa_series(data / SERIES["D"], station="D")
    irr, _ = irreducible_params(chain)
    params, dropped = identifiable_subset(chain, irr, np.radians(b.q_deg), tmac)
    fit_b = identify(chain, b, tmac, params)
    params_d = identifiable_subset(chain, irr, np.radians(d.q_deg), tmac)[0]
    fit_d = identify(chain, d, tmac, params_d)
    virt = []
    for k, lever in [(k, 100.0) for k in virtual] + [(2, lev) for lev in levers]:
        bv = read_ipa_series(data / SERIES["B"], station="B", virtual_points=k, lever_mm=lever)
        scale = lever / 100.0  # the tool file's virtual points sit at 100 mm: start from the scaled offsets
        pts = {p: tmac[POINT] + scale * (cell.tool_points[p] - tmac[POINT]) for p in dict.fromkeys(bv.point)}
        fit = identify(chain, bv, pts, irr)  # the virtual points make the whole irreducible set identifiable
        virt.append(
            {
                "k": k,
                "lever_mm": lever,
                "n_params": len(irr),
                "after_d": on_other_series(chain, fit, d),
                "fit_b_tmac_rms": rms3(fit.residuals[tmac_rows(bv)]),
                "fit_b_all_rms": rms3(fit.residuals),
                "point": fit.points[POINT],
            }
        )
    covs = table_covariances(read_ipa_series(data / SERIES["B"], station="B", virtual_points=1))
    rho = np.array([c[0, 3] / np.sqrt(c[0, 0] * c[3, 3]) for _, c in covs])
    diag = diagnose(chain, b, tmac, params, None)
    checks = []
    for c in (c for c in diag.candidates if c.step == 1):  # each cause against the geometric model
        cv = None if c.holdout_rms_mm is None else np.sqrt(3) * c.holdout_rms_mm
        check = CandidateCheck(c.cause, c.n_params, cv, None, c.significant, detail=dict(c.detail))
        if c.cause in JOINT_CAUSES:
            cf = fit_cause(chain, b, tmac, params, None, c.cause)
            check.d_rms3_mm = rms3(on_other_series(chain, cf.result, d).residuals)
        checks.append(check)
    checks.sort(key=lambda c: (c.cv_rms3_mm is None, c.cv_rms3_mm or 0.0))
    # diagnose's chosen model on D (the geometric one when it names no cause); a station shift within B moves only
    # B's station, and D's station is re-estimated anyway: the robot-side causes carry over
    chosen = diag.extended if diag.extended is not None else diag.geometric
    diagnosis_d = on_other_series(chain, chosen, d)
    nominal_b, after_d = identify(chain, b, tmac, [], fixed=STATION_ONLY), on_other_series(chain, fit_b, d)
    nominal_d = on_other_series(chain, nominal_b, d)
    m = error_map_check(chain, b, d, tmac, params, params_d)
    series = {
        "nominal": (nominal_b, nominal_d),
        "geometric": (fit_b, after_d),
        "map": (m.fit_b.identification, m.after_d),
    }
    return Study(
        cell=cell,
        params=params,
        dropped=dropped,
        b=b,
        d=d,
        conv=conventions(data, chain, tmac[POINT]),
        fit_b=fit_b,
        nominal_b=nominal_b,
        nominal_b_free_point=identify(chain, b, tmac, []),
        nominal_d=nominal_d,
        after_d=after_d,
        fit_d=fit_d,
        after_b=on_other_series(chain, fit_d, b),
        virtual=virt,
        correlation=float(np.median(rho)),
        diagnosis=diag,
        candidates=checks,
        temperature=temperature_effect(chain, b, fit_b),
        diagnosis_d=diagnosis_d,
        error_map=m,
        orientation=orientation_check(series, b, d, m.holdout_fits, *m.holdout_tables),
    )


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
    fig.suptitle(
        f"Series B, geometric fit ({rms3(study.fit_b.residuals):.3f} mm RMS 3-D): residuals against the joint angles"
    )
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
    if study.error_map is not None:
        m = study.error_map
        written.append(
            error_map_curves(
                {"fitted on B": m.fit_b.identification, "fitted on D": m.fit_d.identification},
                img_dir / "ur10-joint-error-map.png",
                NAMES,
            )
        )
    return written


def _row(label: str, res: Identification) -> str:
    r = base_frame(res)
    axes = " | ".join(f"{np.sqrt(np.mean(r[:, a] ** 2)):.3f}" for a in range(3))
    return f"| {label} | {axes} | {rms3(r):.3f} | {residual_stats(r)['dist_max_mm']:.3f} |"


def _deg_or_mm(p: Param, v: float) -> str:
    return f"{v:+.4f} mm" if p.is_length else f"{np.degrees(v):+.4f} deg"


def _table(header: list[str], rows: list[list[str]]) -> str:
    return "\n".join(
        [
            "| " + " | ".join(header) + " |",
            "| " + " | ".join("---" for _ in header) + " |",
            *["| " + " | ".join(r) + " |" for r in rows],
        ]
    )


def _range(x: np.ndarray) -> str:
    return f"{x.min():.0f}..{x.max():.0f}"


def values(study: Study, out: Path, images: list[Path]) -> dict[str, str]:
    """The template's placeholders, every one computed from the study."""
    fb, dg, tmp, cv, m = study.fit_b, study.diagnosis, study.temperature, study.conv, study.error_map
    rel = [p.relative_to(out.parent).as_posix() if p.is_relative_to(out.parent) else str(p) for p in images]
    yb, yd = _tmac_base(study, study.b)[:, 1], _tmac_base(study, study.d)[:, 1]
    ry = np.array(study.d.extra["ry_deg"], dtype=float)
    temp_d = np.array(study.d.extra["temp_c"], dtype=float)
    d_geo, d_nom = rms3(study.after_d.residuals), rms3(study.nominal_d.residuals)
    geo_cv = np.sqrt(3) * dg.holdout_geometric_mm
    s3 = float(np.sqrt(3))

    def mm(x: float | None) -> str:
        return "-" if x is None else f"{x:.3f}"

    candidates = _table(
        ["model", "extra parameters", "B cross-validated", "D held out", "significant on B"],
        [["geometric", "-", mm(geo_cv), mm(d_geo), "-"]]
        + [
            [c.cause, str(c.n_params), mm(c.cv_rms3_mm), mm(c.d_rms3_mm), "yes" if c.significant else "no"]
            for c in study.candidates
        ],
    )
    virtual = _table(
        ["points per pose", "lever mm", "parameters", "B fit, T-Mac", "B fit, all points", "D held out"],
        [["1 (T-Mac)", "-", str(len(study.params)), mm(rms3(fb.residuals)), mm(rms3(fb.residuals)), mm(d_geo)]]
        + [
            [
                f"1 + {v['k']} virtual",
                f"{v['lever_mm']:.0f}",
                str(v["n_params"]),
                mm(v["fit_b_tmac_rms"]),
                mm(v["fit_b_all_rms"]),
                mm(rms3(v["after_d"].residuals)),
            ]
            for v in study.virtual
        ],
    )
    fit_b, fit_d = m.fit_b, m.fit_d
    arcs = _table(
        ["joint", "B: fitted arc (deg)", "D: fitted arc (deg)"],
        [
            [NAMES[j]]
            + [
                f"{f.arcs[j].to_doc()['from_deg']:.1f} .. {f.arcs[j].to_doc()['to_deg']:.1f}"
                if j in f.arcs
                else "not mapped"
                for f in (fit_b, fit_d)
            ]
            for j in range(study.cell.chain.dof)
        ],
    )
    agreement = _table(
        ["joint", "angles both measured (deg)", "correlation of the curves"],
        [
            [
                NAMES[a["joint"] - 1],
                f"{a['overlap_deg']:.0f}",
                "-" if a["correlation"] is None else f"{a['correlation']:.2f}",
            ]
            for a in m.agreement
        ],
    )
    orient = study.orientation
    orientation = _table(
        ["model", "B held out", "D, mount from B", "D, mount from D"],
        [
            [label, *(f"{orient[k][c]:.2f}" for c in ("b_held", "d", "d_own_mount"))]
            for k, label in (
                ("nominal", "nominal robot"),
                ("geometric", "geometric (DH) calibration"),
                ("map", "geometric + gravity compliance + joint error map"),
            )
        ],
    )
    return {
        "orientation_table": orientation,
        "mount_shift": f"{orient['map']['mount_shift']:.2f}",
        "or_d_geometric": f"{orient['geometric']['d']:.2f}",
        "or_d_map": f"{orient['map']['d']:.2f}",
        "or_d_own_geometric": f"{orient['geometric']['d_own_mount']:.2f}",
        "or_d_own_map": f"{orient['map']['d_own_mount']:.2f}",
        "citation": CITATION,
        "b_poses": str(len(study.b)),
        "d_poses": str(len(study.d)),
        "d_nominal": mm(d_nom),
        "d_geometric": mm(d_geo),
        "d_compliance": mm(rms3(m.compliance_d.residuals)),
        "d_map": mm(rms3(m.after_d.residuals)),
        "verdict": dg.cause,
        "diagnose_causes": " + ".join(c["cause"] for c in dg.causes) or "none",
        "d_diagnose": mm(rms3(study.diagnosis_d.residuals)),
        "holdout_poses": str(m.holdout_b["poses"]),
        "holdout_geometric": mm(m.holdout_b["geometric_mm"]),
        "holdout_map": mm(m.holdout_b["map_mm"]),
        "goal_rms": mm(cv["goal_rms_mm"]),
        "goal_max": mm(cv["goal_max_mm"]),
        "point_z": f"{fb.points[POINT][2]:.2f}",
        "point_z_ci": f"{fb.point_ci95(POINT)[2]:.2f}",
        "nominal_b": mm(rms3(study.nominal_b.residuals)),
        "nominal_b_free_point": mm(rms3(study.nominal_b_free_point.residuals)),
        "euler_xyz": f"{cv['euler_spread_deg']['XYZ']:.3f}",
        "euler_others": ", ".join(f"{v:.1f} deg for '{k}'" for k, v in cv["euler_spread_deg"].items() if k != "XYZ"),
        "temp_b_range": f"{tmp['range_c'][0]:.2f}-{tmp['range_c'][1]:.2f}",
        "temp_levels": str(tmp["levels"]),
        "temp_d_range": f"{temp_d.min():.2f}-{temp_d.max():.2f}",
        "n_irreducible": str(len(study.params) + len(study.dropped)),
        "n_params": str(len(study.params)),
        "param_names": " ".join(p.name for p in study.params),
        "param_list": ",".join(p.name for p in study.params),
        "dropped": "\n".join(f"- `{p.name}`: {why}" for p, why in study.dropped),
        "b_fit": mm(rms3(fb.residuals)),
        "b_fit_max": mm(residual_stats(fb.residuals)["dist_max_mm"]),
        "b_iterations": str(fb.iterations),
        "parameter_table": _table(
            ["parameter", "deviation", "95 % CI"],
            [
                [p.name, _deg_or_mm(p, v), "+-" + _deg_or_mm(p, c)[1:]]
                for p, v, c in zip(fb.params, fb.dev, fb.param_ci95(), strict=True)
            ],
        ),
        "validation_table": "\n".join(
            [
                "| model | x | y | z | 3-D RMS | 3-D max |",
                "| --- | --- | --- | --- | --- | --- |",
                _row("B, nominal (Trafo tool point)", study.nominal_b),
                _row("B, calibrated on B (fit)", fb),
                _row("D, nominal (Trafo tool point)", study.nominal_d),
                _row("D, calibrated on B", study.after_d),
            ]
        ),
        "d_gain": f"{d_nom / d_geo:.2f}",
        "yb_range": _range(yb),
        "yd_range": _range(yd),
        "d_fit": mm(rms3(study.fit_d.residuals)),
        "d_n_params": str(len(study.fit_d.params)),
        "b_after": mm(rms3(study.after_b.residuals)),
        "d_ry": f"{ry.mean():.1f} +- {ry.std():.1f}",
        "d_point_z": f"{study.fit_d.points[POINT][2]:.1f} +- {study.fit_d.point_ci95(POINT)[2]:.1f}",
        "virtual_correlation": f"{study.correlation:.3f}",
        "virtual_table": virtual,
        "candidate_table": candidates,
        "noise_floor": mm(s3 * dg.noise_floor_mm),
        "floor_source": dg.floor_source,
        "cv_folds": "5",
        "b_order": str(max(fit_b.orders.values())),
        "b_tau_mdeg": f"{1000 * np.degrees(fit_b.tau_rad):.2f}",
        "b_edf": f"{fit_b.effective_params:.0f}",
        "b_cv_without": mm(s3 * fit_b.cv_rms_without_mm),
        "b_cv": mm(s3 * fit_b.cv_rms_mm),
        "b_map_fit": mm(rms3(fit_b.identification.residuals)),
        "b_map_seconds": f"{m.fit_seconds:.1f}",
        "b_not_identifiable": "; ".join(f"{NAMES[j]}: {why}" for j, why in fit_b.not_identifiable.items()) or "none",
        "d_order": str(max(fit_d.orders.values())),
        "d_cv_without": mm(s3 * fit_d.cv_rms_without_mm),
        "d_cv": mm(s3 * fit_d.cv_rms_mm),
        "arc_table": arcs,
        "agreement_table": agreement,
        "temp_b_span": f"{tmp['range_c'][1] - tmp['range_c'][0]:.2f}",
        "temp_corr": ", ".join(f"{k} {v:+.2f}" for k, v in tmp["corr"].items()),
        "temp_alpha": f"{tmp['alpha_ppm_k']:.0f} +- {tmp['alpha_ci95']:.0f}",
        "temp_form": tmp["form"],
        "temp_without": f"{tmp['rms3_without']:.4f}",
        "temp_with": f"{tmp['rms3_with']:.4f}",
        "plots": "\n".join(f"![{p.stem}]({r})" for p, r in zip(images, rel, strict=True)),
    }


def report(study: Study, out: Path, images: list[Path]) -> str:
    """The template filled with the study's numbers, written to `out` (atomically)."""
    text = Template(TEMPLATE.read_text()).substitute(values(study, out, images))
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp")
    tmp.write_text(text)
    tmp.replace(out)
    return text


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="UR10 real-data study (IPA series B and D)")
    ap.add_argument("--data", type=Path, default=DATA, help="ipa-robot-accuracy directory")
    ap.add_argument(
        "--out",
        type=Path,
        default=Path("build/ur10-study/ur10-real-data.md"),
        help="report (default under build/, untracked; --out docs/ur10-real-data.md updates the docs)",
    )
    ap.add_argument("--img", type=Path, default=None, help="plot directory (default: img next to --out)")
    args = ap.parse_args(argv)
    missing = [name for name in SERIES.values() if not (args.data / name).is_file()]
    if missing:  # one line saying where it looked, not a traceback
        print(
            f"error: the IPA data set is not at {args.data.resolve()} (no {missing[0]}): set TRACKCAL_IPA_DATA "
            "to its directory, or give --data",
            file=sys.stderr,
        )
        return 2
    study = run(args.data)
    images = plots(study, args.img or args.out.parent / "img")
    report(study, args.out, images)
    print(f"report written to {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
