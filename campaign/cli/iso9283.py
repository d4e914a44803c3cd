"""`trackcal iso9283 plan | compare`: the ISO 9283 acceptance test (campaign.jobs.iso9283 on typed options)."""

from __future__ import annotations

import math
import sys
from pathlib import Path

from rich.table import Table

from trackcal.calib.decision_rule import RULES
from trackcal.campaign.cli.console import console
from trackcal.campaign.errors import OptionError
from trackcal.campaign.jobs.iso9283 import STANDARD_VELOCITIES, CompareOptions, PlanOptions, compare, make_plan
from trackcal.campaign.report.iso9283 import Item, write_iso_pdf, write_iso_report
from trackcal.campaign.report.iso9283_conformity import Verdict, parse_tolerances, verdicts
from trackcal.campaign.report.iso9283_departures import grouped


def _centre(text: str | None) -> tuple[float, float, float] | None:
    if text is None:
        return None
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 3:
        raise OptionError("{0}: expected X,Y,Z in mm, got {text!r}", "centre_mm", text=text)
    return values


def _velocities(text: str | None) -> tuple[float, ...]:
    if text is None:
        return STANDARD_VELOCITIES
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise OptionError(
            "{0}: expected percentages of the rated velocity, e.g. 100,50,10, got {text!r}", "velocities", text=text
        ) from None
    return values


def _field_check(text: str | None) -> tuple[str, str, float] | None:
    if text is None:
        return None
    parts = text.split(",")
    try:
        return parts[0].strip(), parts[1].strip(), float(parts[2]) if len(parts) == 3 else math.nan
    except (ValueError, IndexError):
        raise OptionError(
            "{0}: expected POINT,POINT,LENGTH_MM, e.g. P1,P3,188.012, got {text!r}", "field_check", text=text
        ) from None


def cmd_plan(args) -> int:
    opts = PlanOptions(
        cell=args.cell,
        json=args.json,
        model=args.model,
        side_mm=args.side,
        centre_mm=_centre(args.centre),
        cycles=args.cycles,
        seed=args.seed,
        vap_cycles=args.vap_cycles,
        orientation=args.orientation,
        load=args.load,
        accept_edited=args.accept_edited,
        accept_poor=args.accept_poor,
        velocities=_velocities(args.velocities),
        warm_up_cycles=args.warm_up_cycles,
        drift_hours=args.drift,
        drift_groups=args.drift_groups,
        field_check=_field_check(args.field_check),
    )
    warnings: list[str] = []
    doc = make_plan(opts, warnings)
    for warning in warnings:
        print(f"warning: {warning}", file=sys.stderr)
    iso = doc["iso9283"]
    console.print(
        f"ISO 9283 cube: side {iso['cube_side_mm']:.1f} mm about "
        f"({', '.join(f'{v:.1f}' for v in iso['cube_centre_mm'])}) mm; point {iso['point']} measured from "
        f"station {iso['station']}; {doc['repeat']} cycles of {' '.join(iso['cycle_order'])} at each of "
        f"{', '.join(f'{v:g}' for v in iso['velocities'])} % of the rated velocity",
        soft_wrap=True,
    )
    for name, q in zip(iso["pose_names"], doc["poses_deg"], strict=True):
        console.print(f"  {name}  " + "  ".join(f"{v:9.4f}" for v in q))
    if iso.get("field_check"):
        fc = iso["field_check"]
        console.print(
            f"field check: the length {'-'.join(fc['points'])} ({fc['length_mm']:g} mm certified) measured "
            "with the robot at P1, before the test"
        )
    if iso.get("drift"):
        drift = iso["drift"]
        console.print(
            f"drift test (ISO 9283:1998, 7.6): {drift['groups']} groups of {drift['cycles']} cycles over "
            f"{drift['hours']:g} h, P1 measured, at {iso['velocities'][0]:g} % of the rated velocity"
        )
    if iso["warm_up_cycles"]:
        console.print(
            f"warm-up (ISO 9283:1998, 6.2): {iso['warm_up_cycles']} cycles of the poses at "
            f"{iso['velocities'][0]:g} %, nothing measured, before the test"
        )
    if iso.get("points"):
        console.print(f"orientation: points {', '.join(iso['points'])} measured in turn, each over all the cycles")
    if iso.get("vap"):
        vap = iso["vap"]
        console.print(
            f"multi-directional test (vAP): {vap['cycles']} cycles of {', '.join(vap['poses'])}, each "
            f"approached from {vap['approach_mm']:.1f} mm away along x, y and z ("
            + "; ".join(f"{p} from {' '.join(a)}" for p, a in zip(vap["poses"], vap["approaches"], strict=True))
            + ")",
            soft_wrap=True,
        )
    if iso["compensated_with"]:
        comp = iso["compensated_with"]
        figure = comp.get("test_pose") or {}
        stated = (
            ""
            if figure.get("sigma_mm") is None
            else f"; its stated TCP uncertainty at the cell's test pose: ±{figure['sigma_mm'] * 1000:.1f} µm 1-sigma "
            "(predicted from its covariance; the test measures what the robot attains)"
        )
        console.print(f"joint targets compensated with {comp['model']}{stated}", soft_wrap=True)
    console.print(f"plan written to {args.json}")
    return 0


def _um(fig) -> str:
    return "-" if fig is None else f"{fig.value * 1000:.1f} ± {fig.u95 * 1000:.1f}"


def _mdeg(fig) -> str:
    return "-" if fig is None else f"{fig.value * 1000:.1f} ± {fig.u95 * 1000:.1f}"


def _conformity(found: list[Verdict], rule: str) -> None:
    table = Table(title=f"conformity, {rule} acceptance (µm; ± U, k = 2)")
    for col in ("test", "figure", "value ± U", "tolerance", "verdict"):
        table.add_column(col, justify="right" if col in ("value ± U", "tolerance") else "left", overflow="fold")
    for v in found:
        u = f"{v.u95_mm * 1000:.1f}" if math.isfinite(v.u95_mm) else "not stated"
        table.add_row(
            f"{v.session} ({'compensated' if v.compensated else 'nominal'})",
            v.figure,
            f"{v.value_mm * 1000:.1f} ± {u}",
            f"{v.limit_mm * 1000:g}",
            v.verdict,
        )
    console.print(table)
    console.print("decision rule: " + RULES[rule], soft_wrap=True)


def _compare_options(args, tolerances: dict[str, float]) -> CompareOptions:
    """compare's options from the command line (the tolerances already parsed)."""
    return CompareOptions(
        sessions=args.sessions,
        model=args.model,
        json=args.json,
        accept_edited=args.accept_edited,
        tolerances=tolerances,
        decision_rule=args.decision_rule,
        certificate=bool(args.report or args.pdf),
        accept_expired=args.accept_expired_certificate,
    )


def _notes(tests) -> None:
    """Each test's notes, the sessions' field checks and every departure from the standard's conditions."""
    for t in tests:
        for note in t.notes:
            console.print(f"note: {t.session}: {note}")
    for check in dict.fromkeys(t.conditions["field check"] for t in tests if "field check" in t.conditions):
        console.print(f"field check: {check}", soft_wrap=True)
    for departure, who in grouped(tests).items():
        console.print(f"departure from ISO 9283:1998: {departure} ({', '.join(who)})", soft_wrap=True)


def cmd_compare(args) -> int:
    tolerances = parse_tolerances(args.tolerance)  # a mistake ends here, before any session is read
    warnings: list[str] = []
    tests, drift_list = compare(_compare_options(args, tolerances), warnings)
    for warning in warnings:
        print(f"warning: {warning}", file=sys.stderr)
    table = Table(title="ISO 9283:1998 pose characteristics (µm; ± U of each figure's uncertainty budget, about 95 %)")
    table.add_column("pose")
    for t in tests:
        label = t.label
        table.add_column(f"AP_P {label}", justify="right", overflow="fold")
        table.add_column(f"RP_l {label}", justify="right", overflow="fold")
    for i, name in enumerate(p.name for p in (tests[0].poses if tests else [])):
        row = [name]
        for t in tests:
            row += [_um(t.poses[i].ap), _um(t.poses[i].rp)]
        table.add_row(*row)
    row = ["AD_P / RD (P2-P4)"]
    for t in tests:
        row += [_um(t.ad), _um(t.rd)]
    table.add_row(*row)
    if tests:  # a drift test alone (7.6) has its own lines below
        console.print(table)
    vap_poses = list(dict.fromkeys(name for t in tests for name in t.vap))
    if vap_poses:
        vt = Table(title="ISO 9283:1998, 7.2 multi-directional pose accuracy variation vAP_P (µm; ± U, k = 2)")
        vt.add_column("pose")
        measured = [t for t in tests if t.vap]  # the multi-directional test runs at the first velocity only
        for t in measured:
            vt.add_column(f"vAP_P {t.label}", justify="right", overflow="fold")
        for name in vap_poses:
            vt.add_row(name, *[_um(t.vap.get(name)) for t in measured])
        console.print(vt)
    if any(p.orientation for t in tests for p in t.poses):
        ot = Table(
            title="ISO 9283:1998, 7.2 orientation AP and RP about the base x (a), y (b), z (c) "
            "axes (millidegrees; ± U, k = 2)"
        )
        ot.add_column("pose, axis")
        for t in tests:
            label = t.label
            ot.add_column(f"AP {label}", justify="right", overflow="fold")
            ot.add_column(f"RP {label}", justify="right", overflow="fold")
        for i, name in enumerate(p.name for p in tests[0].poses):
            for axis in "abc":
                row = [f"{name} {axis}"]
                for t in tests:
                    o = t.poses[i].orientation
                    row += [_mdeg(o.get(f"AP_{axis}")), _mdeg(o.get(f"RP_{axis}"))]
                ot.add_row(*row, end_section=axis == "c")
        console.print(ot)
    for d in drift_list:
        console.print(
            f"drift ({d['targets']} targets, {d['first']} -> {d['last']}; ISO 9283:1998, 7.6), µm: "
            + "; ".join(f"{p['pose']} dAP {_um(p['dAP'])}, dRP {_um(p['dRP'])}" for p in d["poses"]),
            soft_wrap=True,
        )
        for g in d.get("groups", []):  # a drift test's groups (7.6)
            console.print(
                f"  group {g['group']} at {g['t_h']:.2f} h: P1 AP_P {g['AP_P_mm'] * 1000:.1f} µm, "
                f"RP_l {g['RP_l_mm'] * 1000:.1f} µm over {g['cycles']} cycles"
            )
    _notes(tests)
    if args.json:
        console.print(f"figures written to {args.json}")
    conformity = None
    if tolerances:
        conformity = (args.decision_rule, tolerances, verdicts(tests, tolerances, args.decision_rule))
        _conformity(conformity[2], args.decision_rule)
    item = Item(args.customer, args.report_id, args.authorised_by)
    if args.report:
        path = write_iso_report(tests, drift_list, args.model, Path(args.report), conformity, item)
        console.print(f"report written to {path}")
    if args.pdf:
        path = write_iso_pdf(tests, drift_list, args.model, Path(args.pdf), conformity, item)
        console.print(f"PDF written to {path}")
    return 0
