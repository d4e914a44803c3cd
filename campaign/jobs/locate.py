"""`locate` on typed options: a tracker station that moved (a new session, another table) placed with the robot
model held fixed, and the model written back with that station, so `predict` works for it.

Only the station's 6 degrees of freedom are fitted: the solver of `identify` with every robot, extension and
tool-point unknown frozen (`identify(..., fixed=LOCATE_ONLY)`, the shop-floor check the solver's docstring
describes). Three non-collinear reflector positions determine a rigid transform (Horn 1987, "Closed-form solution
of absolute orientation using unit quaternions", JOSA A 4(4): 3 points, 9 equations for 6 unknowns), so a locate
takes as few as 3 points: the reference points of one pose of a three-nest tool, or one point at 3 poses.

The protocol "calibrate on session 1, locate the tracker of session 2 on its first K poses, predict the rest" is
one call: `poses=K` locates on the first K poses of the station's rows (in the table's order: the poses measured
first) and the rows of the other poses are predicted (`predict_out`) and, when measured, compared (held-out RMS).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from trackcal.calib.identify.noise import model_noise
from trackcal.calib.identify.solver import Identification, IdentificationError, identify, residual_stats
from trackcal.calib.identify.units import read_measured
from trackcal.calib.io.files import write_json, writing
from trackcal.calib.io.table import MeasurementTable, write_table
from trackcal.calib.model_file import Model, predict_table
from trackcal.calib.model_trust import sealed
from trackcal.campaign.errors import InputError, OptionError
from trackcal.campaign.jobs.identify import fit_quality, sha256_of
from trackcal.campaign.jobs.trusted import trusted_model

LOCATE_ONLY = ("robot", "points")  # the unknowns held: every robot, extension and tool-point unknown
MIN_POINTS = 3  # a rigid transform needs 3 non-collinear points


@dataclass(frozen=True)
class LocateOptions:
    """What `trackcal locate` is asked."""

    model: str  # model.json of the calibrated robot
    table: str  # the measurement table of the new session
    out: str  # model.json to write: the input model plus the located station
    station: str | None = None  # the table's station to locate (default: its only one)
    name: str | None = None  # the located station's name in the model (`--as`; default: the table's id)
    poses: int | None = None  # locate on the first K poses, predict the rest (default: every pose)
    predict_out: str | None = None  # the held-out rows predicted by the new model (needs poses)
    accept_edited: bool = False  # use a model whose digest does not match its content (calib.model_trust)


@dataclass
class PointFit:
    """One located point: its row of the table, pose and point ids, and the residual measured - fitted (mm)."""

    row: int  # file row (header = row 1)
    pose: str
    point: str
    residual: np.ndarray  # (3,) mm, station frame


@dataclass
class Location:
    name: str  # the station's name in the written model
    fit: Identification
    points: list[PointFit]
    quality: dict  # fit_quality: residual RMS over the degrees of freedom against the noise floor
    located_poses: list[str]
    held_out: dict | None  # residual_stats of the measured held-out rows, and their count; None without any
    replaced: bool  # the model had a station of that name, now replaced
    doc: dict  # the model written


def _station_rows(table: MeasurementTable, station: str | None) -> tuple[str, np.ndarray]:
    """(the station to locate, its rows): the table's only station unless `station` names one."""
    ids = list(dict.fromkeys(table.station))
    if station is None:
        if len(ids) > 1:
            raise OptionError(
                "{0}: the table {path} has stations {ids}; say which one to locate",
                "station",
                path=table.source,
                ids=", ".join(ids),
            )
        station = ids[0]
    elif station not in ids:
        raise OptionError(
            "{0} {station}: no such station in {path} (it has {ids})",
            "station",
            station=station,
            path=table.source,
            ids=", ".join(ids),
        )
    return station, np.flatnonzero(np.array(table.station) == station)


def _split(table: MeasurementTable, rows: np.ndarray, poses: int | None) -> tuple[np.ndarray, np.ndarray]:
    """(rows that locate, rows held out): the rows of the first `poses` distinct poses, in table order."""
    order = list(dict.fromkeys(table.pose[i] for i in rows))
    if poses is None:
        return rows, rows[:0]
    if poses < 1:
        raise OptionError("{0} {poses}: locate on at least 1 pose", "poses", poses=poses)
    first = set(order[:poses])
    used = np.array([table.pose[i] in first for i in rows], dtype=bool)
    return rows[used], rows[~used]


def locate_rows(model: Model, rows: MeasurementTable) -> Identification:
    """The station of `rows` (one station) fitted with every robot, extension and tool-point unknown of `model`
    held: `identify` with LOCATE_ONLY. At least MIN_POINTS rows, not collinear."""
    if len(rows) < MIN_POINTS:
        raise IdentificationError(
            f"{rows.source}: station {rows.station[0]!r}: {len(rows)} point(s) to locate it on; at least "
            f"{MIN_POINTS} non-collinear points are needed (reference points x poses)"
        )
    ext, theta = (None, None) if model.cause == "station_shift" else model.extension_for(rows)
    return identify(
        model.chain,
        rows,
        model.points,
        model.params,
        noise=model_noise(model.doc),
        dev0=model.dev,
        extension=ext,
        ext0=theta,
        fixed=LOCATE_ONLY,
    )


def station_doc(fit: Identification, sid: str) -> dict:
    """The model.json entry of a located station (calib.model_file's layout)."""
    st, c = fit.stations[sid], fit.station_ci95(sid)
    return {
        "rotation": st.rotation.tolist(),
        "translation_mm": st.translation.tolist(),
        "ci95_translation_mm": c[:3].tolist(),
        "ci95_rotation_deg": np.degrees(c[3:]).tolist(),
    }


def locate(opts: LocateOptions) -> Location:
    """`trackcal locate`: the station fitted, the model written with it (and the held-out rows predicted)."""
    if opts.predict_out and opts.poses is None:
        raise OptionError(
            "{0} needs {1} K: the rows of the poses after the first K are the ones predicted", "predict_out", "poses"
        )
    model, _ = trusted_model(opts.model, opts.accept_edited)  # the model written is sealed anew: check it first
    table = read_measured(opts.table, model.chain)
    station, rows = _station_rows(table, opts.station)
    name = opts.name or station
    used, rest = _split(table, rows, opts.poses)
    if opts.predict_out and not len(rest):
        raise OptionError(
            "{0} {poses}: the table has no pose after the first {poses} of station {station}; "
            "nothing is left to predict",
            "poses",
            poses=opts.poses,
            station=station,
        )
    sub = table.subset(used)
    sub.station = [name] * len(sub)
    fit = locate_rows(model, sub)
    doc = copy.deepcopy(model.doc)
    replaced = name in doc["stations"]
    doc["stations"][name] = station_doc(fit, name)
    if replaced and (doc.get("test_pose") or {}).get("station") == name:
        del doc["test_pose"]  # its TCP was in the frame of the station now replaced, its figure from the old fit
    quality = fit_quality(sub, fit)
    points = [PointFit(int(i) + 2, table.pose[i], table.point[i], r) for i, r in zip(used, fit.residuals, strict=True)]
    located_poses = list(dict.fromkeys(sub.pose))
    held_out = None
    if len(rest):
        held = table.subset(rest)
        held.station = [name] * len(held)
        new = Model(
            model.chain, model.params, model.dev, {**model.stations, name: fit.stations[name]}, model.points, doc
        )
        pred = predict_table(new, held)
        if opts.predict_out:
            with writing(opts.predict_out, InputError):
                write_table(pred, opts.predict_out)
        if held.xyz is not None:
            held_out = {"rows": len(held), "poses": len(set(held.pose)), **residual_stats(held.xyz - pred.xyz)}
    path, stats = Path(opts.table), residual_stats(fit.residuals)
    doc.setdefault("located", {})[name] = {
        "table": str(path),
        "table_sha256": sha256_of(path),
        "station_in_table": station,
        "poses": located_poses,
        "n_points": len(sub),
        **quality,
        "residuals": {"rms_mm": stats["dist_rms_mm"], "max_mm": stats["dist_max_mm"]},  # 3-D
        "points": [
            {"row": p.row, "pose": p.pose, "point": p.point, "residual_mm": p.residual.tolist()} for p in points
        ],
        "held_out": held_out,
    }
    doc = sealed(doc)
    write_json(opts.out, doc, InputError)
    return Location(name, fit, points, quality, located_poses, held_out, replaced, doc)
