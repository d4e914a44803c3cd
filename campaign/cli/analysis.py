"""`trackcal identify | diagnose | predict | simulate`: options in, one job (campaign.jobs), its result printed."""

from __future__ import annotations

import sys

import numpy as np
from rich.table import Table

from trackcal.calib.identify.noise import model_instrument
from trackcal.campaign.cli.console import console, print_table
from trackcal.campaign.jobs.identify import (
    IdentifyOptions,
    PredictOptions,
    convergence_warning,
    identify_table,
    predict,
)


def print_identification(doc: dict, truth: dict[str, float] | None = None) -> None:
    """A model document's parameters, residuals, significance, stations and fit (`truth`: the twin's)."""
    t = Table(
        title=f"Identified parameters ({doc['n_measurements']} measurements, {doc['iterations']} iterations, "
        f"{doc['weighting']} weighting)"
    )
    for col in ("parameter", "unit", "nominal", "deviation", "95 % CI"):
        t.add_column(col, justify="right")
    if truth is not None:
        t.add_column("truth (twin)", justify="right")
        t.add_column("inside CI", justify="center")
    for name, p in doc["parameters"].items():
        row = [name, p["unit"], f"{p['nominal']:.1f}", f"{p['value']:+.4f}", f"±{p['ci95']:.4f}"]
        if truth is not None:
            tv = truth.get(name, 0.0)
            row += [f"{tv:+.4f}", "yes" if abs(tv - p["value"]) <= p["ci95"] else "NO"]
        t.add_row(*row)
    if doc.get("nominal"):
        console.print(f"nominal robot: {doc['nominal']}", markup=False, highlight=False)
    print_table(t)
    r = doc["residuals"]
    rt = Table(title="Residuals (paper Table 9 style), mm")
    for col in ("", "before", "after", "factor"):
        rt.add_column(col, justify="right")
    for key, label in (
        ("coord_max_mm", "coordinate max"),
        ("coord_rms_mm", "coordinate RMS"),
        ("dist_max_mm", "distance max"),
        ("dist_rms_mm", "distance RMS"),
    ):
        b, a = r["before"][key], r["after"][key]
        rt.add_row(label, f"{b:.4f}", f"{a:.4f}", f"{b / a:.1f}" if a > 0 else "-")
    print_table(rt)
    if "significance_mm" in doc:
        sig = sorted(doc["significance_mm"].items(), key=lambda kv: -kv[1])
        console.print(
            "TCP error at the test pose when one parameter is left at nominal (section 7.3): "
            + ", ".join(f"{k} {v * 1000:.0f} µm" for k, v in sig)
        )
    if "test_pose" in doc:
        console.print(tcp_at_test_pose_line(doc["test_pose"]), markup=False, highlight=False, soft_wrap=True)
    for sid, s in doc["stations"].items():
        ci = s["ci95_translation_mm"]
        console.print(f"station {sid}: translation ±({ci[0]:.3f}, {ci[1]:.3f}, {ci[2]:.3f}) mm (95 %)")
    print_extension(doc["extension"])
    console.print(f"tracker {model_instrument(doc).describe()}")
    console.print(
        f"weighting {doc['weighting']}; residual RMS {doc['residual_rms_mm'] * 1000:.1f} µm per coordinate, "
        f"{doc['fit_ratio']:.1f}x the noise floor {doc['noise_floor_mm'] * 1000:.1f} µm "
        f"({doc['noise_floor_source']}): fit {doc['fit']}"
    )


def tcp_at_test_pose_line(tp: dict) -> str:
    """model.json's `test_pose` in one line: the TCP there and its 1-sigma uncertainty (calib.tcp_figure)."""
    x, y, z = tp["tcp_mm"]
    return (
        f"TCP at the test pose: ({x:.3f}, {y:.3f}, {z:.3f}) mm in station {tp['station']}'s frame, "
        f"±{tp['sigma_mm'] * 1000:.1f} µm (1σ 3-D, full covariance: robot, stations, points); the calibration "
        f"moves it {tp['correction_mm'] * 1000:.0f} µm from the nominal robot's"
    )


def print_extension(ext: dict) -> None:
    """The model's extension: its cause and its parameters with 95 % intervals."""
    cause = ext.get("cause", "none")
    if cause == "none":
        console.print("model extension: none (purely geometric)")
        return
    if cause == "station_shift":
        console.print(
            f"model extension: station_shift: station {ext['station']} moved after t = "
            f"{ext['after_t_s']:.1f} s; its later transform is identified as a separate station"
        )
        return
    t = Table(title=f"Model extension: {' + '.join(ext.get('causes') or [cause])}")
    for col in ("parameter", "unit", "value", "95 % CI"):
        t.add_column(col, justify="right")
    for name, p in ext.get("parameters", {}).items():
        t.add_row(name, p["unit"], f"{p['value']:+.4g}", f"±{p['ci95']:.3g}")
    print_table(t)


def cmd_identify(args) -> int:
    outcome = identify_table(
        IdentifyOptions(
            data=args.data,
            cell=args.cell,
            out=args.out,
            params=args.params,
            weighting=args.weighting,
            extend=args.extend,
            json=args.json,
        )
    )
    print_identification(outcome.doc)
    if outcome.chosen is not None:
        console.print(
            f"--extend auto: diagnose chose {outcome.chosen}"
            + (" (the model stays geometric)" if outcome.chosen == "none" else "")
        )
    unusable = (
        None
        if outcome.doc.get("usable", True)
        else (f"the model is UNUSABLE: {outcome.doc['unusable_why']} (compensate refuses it without --accept-poor)")
    )
    warnings = [
        w
        for w in (unusable, outcome.still, outcome.warning, outcome.determination, convergence_warning(outcome.doc))
        if w
    ]
    if warnings:  # one line on stderr, whatever the fit's troubles (scripts read the first line)
        print(f"warning: {'; and '.join(warnings)}", file=sys.stderr)
    console.print(f"model written to {args.out}" + (" (marked unusable)" if unusable else ""))
    return 0


def cmd_predict(args) -> int:
    done = predict(PredictOptions(model=args.model, rows=args.rows, out=args.out, accept_edited=args.accept_edited))
    for warning in [*done.model_warnings, *([done.warning] if done.warning else [])]:
        print(f"warning: {warning}", file=sys.stderr)
    console.print(f"{len(done.table)} predictions written to {args.out}")
    return 0


MAX_POINT_ROWS = 20  # locate prints the largest residuals of a long table, all of them in the model file


def cmd_locate(args) -> int:
    from trackcal.campaign.jobs.locate import LocateOptions, locate  # lazy: identify's start-up skips it (issue 41)

    done = locate(
        LocateOptions(
            model=args.model,
            table=args.table,
            out=args.out,
            station=args.station,
            name=getattr(args, "as"),
            poses=args.poses,
            predict_out=args.predict_out,
            accept_edited=args.accept_edited,
        )
    )
    q, fit = done.quality, done.fit
    t = Table(
        title=f"Station {done.name} located on {len(done.points)} points of {len(done.located_poses)} pose(s) "
        f"(robot, extension and tool points held from {args.model})"
    )
    for col in ("row", "pose", "point", "dx µm", "dy µm", "dz µm", "|r| µm", "x floor"):
        t.add_column(col, justify="right")
    floor3 = q["noise_floor_mm"] * 3**0.5  # the noise floor of a 3-D distance
    shown = sorted(done.points, key=lambda p: -float(np.linalg.norm(p.residual)))[:MAX_POINT_ROWS]
    for p in sorted(shown, key=lambda p: p.row):
        d = float(np.linalg.norm(p.residual))
        t.add_row(
            str(p.row),
            p.pose,
            p.point,
            *(f"{v * 1000:+.1f}" for v in p.residual),
            f"{d * 1000:.1f}",
            f"{d / floor3:.1f}",
        )
    print_table(t)
    if len(done.points) > len(shown):
        console.print(
            f"(the {len(shown)} largest residuals of {len(done.points)}; every point's is in {args.out}, "
            f"located.{done.name}.points)"
        )
    res = done.doc["located"][done.name]["residuals"]
    console.print(
        f"residual RMS {res['rms_mm'] * 1000:.1f} µm, max {res['max_mm'] * 1000:.1f} µm (3-D); per "
        f"coordinate over the {fit.dof} degrees of freedom (3 per point less the station's 6) "
        f"{q['residual_rms_mm'] * 1000:.1f} µm, {q['fit_ratio']:.1f}x the noise floor "
        f"{q['noise_floor_mm'] * 1000:.1f} µm ({q['noise_floor_source']}): fit {q['fit']}"
    )
    c = done.doc["stations"][done.name]
    ct, cr = c["ci95_translation_mm"], c["ci95_rotation_deg"]
    console.print(
        f"station {done.name}: translation ±({ct[0]:.3f}, {ct[1]:.3f}, {ct[2]:.3f}) mm, rotation "
        f"±({cr[0]:.4f}, {cr[1]:.4f}, {cr[2]:.4f}) deg (95 %)"
    )
    if done.held_out is not None:
        h = done.held_out
        console.print(
            f"held out: {h['rows']} rows of {h['poses']} poses not used to locate: RMS "
            f"{h['dist_rms_mm']:.4f} mm (3-D), max {h['dist_max_mm']:.4f} mm"
        )
    if args.predict_out:
        console.print(f"predictions of the held-out rows written to {args.predict_out}")
    if q["fit"] == "poor":
        own = done.doc.get("fit_ratio")
        print(
            f"warning: the points fit the station at {q['fit_ratio']:.1f}x the noise floor "
            + (f"(the model fits its own table at {own:.1f}x)" if own is not None else "")
            + ": the model does not describe this session to the noise (a robot that changed, points swapped, "
            "or what the model already missed)",
            file=sys.stderr,
        )
    console.print(("station replaced" if done.replaced else "model with the station written") + f" in {args.out}")
    return 0


def cmd_simulate(args) -> int:
    from trackcal.campaign.jobs.simulate import (  # lazy: the twin and the plans, which identify's start-up skips
        SimulateOptions,
        parse_effects,
        simulate,
    )

    _, _, table = simulate(
        SimulateOptions(
            cell=args.cell,
            out=args.out,
            poses=args.poses,
            seed=args.seed,
            repeat=args.repeat,
            noise_free=args.noise_free,
            effects=parse_effects(args.effect),
            truth=args.truth,
        )
    )
    console.print(
        f"{len(table)} simulated measurements written to {args.out}"
        + (f"; the twin's truth to {args.truth}" if args.truth else "")
    )
    return 0


def um(mm: float | None, digits: int = 1) -> str:
    """mm as µm for the console; "-" for a figure that cannot be computed (the JSON holds null and says why)."""
    return "-" if mm is None else f"{mm * 1000:.{digits}f}"
