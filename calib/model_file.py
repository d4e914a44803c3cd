"""model.json: everything `predict` needs, in boundary units (mm, deg).

{"format": "trackcal-model/1", "robot": <configs/robots schema>, "extension": {"cause": "none"},
 (an extension: {"cause", "parameters": {name: {value, ci95, unit}}, "parts": [{"cause", "parameters": [names]}]
  when it carries several causes, "arcs": {"joint_<j>": {"from_deg", "to_deg"}} for the joint error map,
  "forms": {cause: form} for what thermal_warmup ({"tau_s", "tau_ci95_s"}) and payload_compliance ({"com_mm",
  "final_load_kg"}) need beyond the rows (calib.diagnose.extensions)},
 "parameters": {name: {"value": deviation, "ci95": half-width, "unit": "mm"|"deg", "nominal": value}},
 "stations": {id: {"rotation": 3x3 station<-base, "translation_mm": [..], "ci95_translation_mm": [..],
                   "ci95_rotation_deg": [..]}},
 "tool_points": {id: {"xyz_mm": [..], "ci95_mm": [..]}},
 "covariance_order": [names], "covariance": matrix of the parameters (mm, deg),
 "extension_covariance": {"order": [the extension's names], "matrix", "with_parameters": (covariance_order x order)}
 in the extension's boundary units (with an extension only; a model written before has none),
 "residuals": {"before": {...}, "after": {...}}, "sigma_mm", "dof", "iterations", "weighting",
 "converged": the solver's stopping test was met, "message": why it stopped,
 "extension" also holds "valid": {"joints": {"joint_<j>": {"from_deg", "to_deg"}}, "time_s": {"from", "to"}}, the
 ranges of the rows it was fitted on (outside them it is held; predict warns, compensate refuses unless asked),
 "not_identifiable": the warning line naming the joints that never moved in the table and the parameters left at
 nominal because of them (only then),
 "measured": {"joints": {"joint_<j>": {"from_deg", "to_deg"}}, "volume": {"radius_mm", "height_mm"}}: where the table
 measured (calib.measured_space; a model written before it was recorded has none: "unknown" to the filter),
 "test_pose": {"joints_deg", "station", "tcp_mm", "sigma_mm", "sigma_xyz_mm", "correction_mm", "note"}: the TCP at
 the cell's test pose and its 1-sigma 3-D uncertainty from the full covariance (calib.tcp_figure; with a test pose
 only), ...}
A model written before "converged" and "message" were recorded still loads (`Model.converged` is then None).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from trackcal.calib.diagnose.changepoint import relabel_shift
from trackcal.calib.diagnose.extensions import CAUSES, build_parts
from trackcal.calib.diagnose.joint_map import Arc, range_warning
from trackcal.calib.errors import CalibError
from trackcal.calib.identify.noise import WEIGHTINGS
from trackcal.calib.identify.solver import Identification, Station, predict_points
from trackcal.calib.io import fields
from trackcal.calib.io.files import read_json
from trackcal.calib.io.table import MeasurementTable
from trackcal.calib.measured_space import MeasuredSpace, space_of
from trackcal.calib.model.chain import Chain, ChainError, chain_from_dict, chain_to_dict
from trackcal.calib.model.extension import FORMS, UNIT_FACTORS, Extension, Ranges
from trackcal.calib.model.params import Param, param_by_name
from trackcal.calib.tcp_figure import figure_at_test_pose

FORMAT = "trackcal-model/1"


class ModelError(CalibError):
    """A model file that cannot be used."""


def nominal_value(chain: Chain, p: Param) -> float:
    return float(chain.joints[p.joint].translation[p.axis]) if p.kind == "p" else 0.0


def to_boundary(p: Param, v: float) -> float:
    return float(v) if p.is_length else float(np.degrees(v))


def extension_doc(res: Identification, shift: dict | None = None, ranges: Ranges | None = None) -> dict:
    """{"cause": ..., "parameters": {name: {value, ci95, unit}}} in boundary units; station_shift adds
    {"station", "after_t_s"} (the moved station's later transform is the station "<id>~shift"), also next to
    the parameters of other causes; `ranges` (the joint angles and times of the rows it was fitted on) adds
    "valid": {"joints": {"joint_<j>": {"from_deg", "to_deg"}}, "time_s": {"from", "to"}}, where it holds: outside
    them the extension is held at its value at the nearest fitted point (`Ranges`)."""
    ext = res.extension
    if ext is None:
        return (
            {"cause": "none"}
            if shift is None
            else {"cause": "station_shift", "causes": ["station_shift"], **shift, "parameters": {}}
        )
    ci = res.ext_ci95()
    doc = {
        "cause": ext.cause,
        "causes": fitted_causes(ext, shift),
        "parameters": {
            n: {"value": float(v * f), "ci95": float(c * f), "unit": u}
            for n, v, c, f, u in zip(ext.names, res.ext, ci, ext.to_boundary, ext.units, strict=True)
        },
    }
    if len(ext.parts()) > 1:
        doc["parts"] = [{"cause": c, "parameters": list(names)} for c, names in ext.parts()]
    if ext.meta.get(FORMS):
        doc["forms"] = {c: dict(f) for c, f in ext.meta[FORMS].items()}
    if "arcs" in ext.meta:
        doc["arcs"] = {f"joint_{j + 1}": arc.to_doc() for j, arc in sorted(ext.meta["arcs"].items())}
    if ranges is not None:
        doc["valid"] = ranges.to_doc()
    return doc if shift is None else {**doc, **shift}


def fitted_causes(ext: Extension, shift: dict | None = None) -> list[str]:
    """Every cause a fitted extension carries, the main one (`ext.cause`) first, then the others in their order
    (station_shift, which has no parameters of its own, last): what model.json's `causes` lists (DESIGN.md: a
    verdict may name several causes, `cause` being the main one)."""
    names = [c for c, _ in ext.parts()]
    out = [ext.cause] + [c for c in dict.fromkeys(names) if c != ext.cause]
    return out + (["station_shift"] if shift is not None and "station_shift" not in out else [])


def identification_to_doc(
    res: Identification,
    extra: dict | None = None,
    shift: dict | None = None,
    test_pose: np.ndarray | None = None,
    ranges: Ranges | None = None,
) -> dict:
    """model.json of an identification; `test_pose` (rad): the cell's, for the `test_pose` entry (calib.tcp_figure);
    `ranges`: those of the rows it was fitted on (`extension_doc`)."""
    ci = res.param_ci95()
    unit = np.array([1.0 if p.is_length else np.degrees(1.0) for p in res.params])
    cov = res.param_cov() * np.outer(unit, unit)
    doc = {
        "format": FORMAT,
        "robot": chain_to_dict(res.chain),
        "extension": extension_doc(res, shift, ranges),
        "parameters": {
            p.name: {
                "value": to_boundary(p, v),
                "ci95": to_boundary(p, c),
                "unit": "mm" if p.is_length else "deg",
                "nominal": nominal_value(res.chain, p),
            }
            for p, v, c in zip(res.params, res.dev, ci, strict=True)
        },
        "stations": {},
        "tool_points": {},
        "covariance_order": [p.name for p in res.params],
        "covariance": cov.tolist(),
        "sigma_mm": res.sigma_mm if res.noise is None else None,
        "variance_factor": res.variance_factor,
        "dof": res.dof,
        "iterations": res.iterations,
        "converged": bool(res.converged),
        "message": res.message,
        "weighting": "iid" if res.noise is None else "tracker",
    }
    for sid, st in res.stations.items():
        c = res.station_ci95(sid)
        doc["stations"][sid] = {
            "rotation": st.rotation.tolist(),
            "translation_mm": st.translation.tolist(),
            "ci95_translation_mm": c[:3].tolist(),
            "ci95_rotation_deg": np.degrees(c[3:]).tolist(),
        }
    for pid, x in res.points.items():
        doc["tool_points"][pid] = {"xyz_mm": x.tolist(), "ci95_mm": res.point_ci95(pid).tolist()}
    if res.extension is not None and len(res.ext):
        doc["extension_covariance"] = extension_covariance(res, unit)
    if test_pose is not None:
        doc["test_pose"] = figure_at_test_pose(res, test_pose).to_doc()
    doc.update(extra or {})
    return doc


def extension_covariance(res: Identification, unit: np.ndarray) -> dict:
    """model.json's "extension_covariance": the covariance of the extension's parameters (the fit's, as for the
    geometric ones: its J^T W J inverse scaled by the residual variance) in their boundary units, "order" their
    names, and "with_parameters" their covariance with the geometric parameters (covariance_order's rows; `unit`
    their factors to boundary units)."""
    k, e = len(res.params), len(res.ext)
    f = np.asarray(res.extension.to_boundary, dtype=float)  # type: ignore[union-attr]
    return {
        "order": list(res.extension.names),  # type: ignore[union-attr]
        "matrix": (res.cov[k : k + e, k : k + e] * np.outer(f, f)).tolist(),
        "with_parameters": (res.cov[:k, k : k + e] * np.outer(unit, f)).tolist(),
    }


@dataclass
class Model:
    chain: Chain
    params: list[Param]
    dev: np.ndarray  # mm, rad
    stations: dict[str, Station]
    points: dict[str, np.ndarray]
    doc: dict

    @property
    def converged(self) -> bool | None:
        """The fit met the solver's stopping test; None for a model written before this was recorded."""
        return self.doc.get("converged")

    @property
    def message(self) -> str | None:
        """Why the solver stopped; None for a model written before this was recorded."""
        return self.doc.get("message")

    @property
    def cause(self) -> str:
        return self.doc.get("extension", {}).get("cause", "none")

    @property
    def causes(self) -> list[str]:
        """Every cause the extension carries, the main one first (a model written before `causes` was recorded:
        those of its parts, else its one cause); [] for a purely geometric model."""
        info = self.doc.get("extension", {})
        if "causes" in info:
            return list(info["causes"])
        if self.cause in ("none", "unexplained"):
            return []
        names = [self.cause] + [c for c, _ in self.parts() if c != self.cause]
        return list(dict.fromkeys(names)) + (
            ["station_shift"] if "after_t_s" in info and "station_shift" not in names else []
        )

    def extension_values(self) -> tuple[list[str], np.ndarray]:
        """Extension parameter names and values in internal units (rad, N m, s)."""
        pars = self.doc.get("extension", {}).get("parameters", {})
        names = list(pars)
        return names, np.array([pars[n]["value"] / UNIT_FACTORS[pars[n]["unit"]] for n in names])

    def parts(self) -> list[tuple[str, list[str]]]:
        """(cause, parameter names) of every cause the extension carries ([] for none and station_shift)."""
        info = self.doc.get("extension", {})
        if self.cause in ("none", "unexplained", "station_shift"):
            return []
        if "parts" in info:
            return [(p["cause"], list(p["parameters"])) for p in info["parts"]]
        return [(self.cause, list(info.get("parameters", {})))]

    def arcs(self) -> dict[int, Arc]:
        """The joint error map's fitted arcs (joint index from 0), empty without a map."""
        arcs = self.doc.get("extension", {}).get("arcs", {})
        return {int(k.split("_")[1]) - 1: Arc.from_doc(v) for k, v in arcs.items()}

    def forms(self) -> dict:
        """{cause: form} of the causes whose features need more than the rows (`build_extension`'s `form`)."""
        forms = self.doc.get("extension", {}).get("forms", {})
        if not isinstance(forms, dict) or not all(isinstance(f, dict) for f in forms.values()):
            raise ModelError("extension.forms: expected {cause: {...}}")
        return forms

    def ranges(self) -> Ranges | None:
        """The joint angles and times the extension was fitted on (None: no extension, or a model written before
        they were recorded: its extension is then evaluated at the rows' own angles and times, as it was)."""
        valid = self.doc.get("extension", {}).get("valid")
        return None if valid is None or not self.parts() else Ranges.from_doc(valid, self.chain.dof)

    def extension_for(self, rows: MeasurementTable) -> tuple[Extension | None, np.ndarray | None]:
        """(extension features for `rows`, parameter values) as identified, held outside the ranges it was fitted
        on; (None, None) without one."""
        parts = self.parts()
        if not parts:
            return None, None
        _, theta = self.extension_values()
        return build_parts(parts, self.chain, rows, self.arcs(), self.cause, self.ranges(), self.forms()), theta

    def measured(self) -> MeasuredSpace | None:
        """Where the model was measured (its table's joint ranges and reflector volume), None for a model written
        before it was recorded."""
        return space_of(self.doc, self.chain.dof)

    def outside(self, q: np.ndarray) -> np.ndarray:
        """(N,) bool: rows whose joint angles q (N, n) rad leave the ranges the extension was fitted on."""
        ranges = self.ranges()
        return np.zeros(len(q), dtype=bool) if ranges is None else ranges.outside(q).any(axis=1)

    def range_warning(self, q: np.ndarray) -> str | None:
        """One line when joint angles q (N, n) rad leave the ranges the extension was fitted on (naming the rows and
        joints) or the joint error map's fitted arcs, else None."""
        arcs, ranges = self.arcs(), self.ranges()
        lines = [
            w
            for w in [
                outside_warning(q, ranges) if ranges is not None else None,
                range_warning(q, arcs) if arcs else None,
            ]
            if w
        ]
        return "; ".join(lines) if lines else None


def outside_warning(q: np.ndarray, ranges: Ranges) -> str | None:
    """One line naming the rows (1-based, the first ten) whose angles q (N, n) rad leave `ranges`, and per joint how
    many and the fitted range; None when none does."""
    out = ranges.outside(q)
    rows = np.flatnonzero(out.any(axis=1))
    if len(rows) == 0:
        return None
    named = ", ".join(str(r + 1) for r in rows[:10]) + (f" and {len(rows) - 10} more" if len(rows) > 10 else "")
    per_joint = ", ".join(
        f"joint {j + 1}: {int(out[:, j].sum())} (fitted {np.degrees(lo):.1f} .. {np.degrees(hi):.1f} deg)"
        for j, (lo, hi) in enumerate(ranges.joints_rad)
        if out[:, j].any()
    )
    return (
        f"rows {named} of {len(q)} leave the joint ranges the model's extension was fitted on ({per_joint}); "
        "the extension is held there at its value at the nearest fitted angle"
    )


def _extension_values(ext: dict, where: str) -> None:
    """The typed values of an extension (its parameters and the arcs of a joint error map), each named in one
    line when wrong: a JSON number with a known unit, an arc `joint_N` from a number of degrees to another."""
    pars = fields.mapping(ext.get("parameters", {}), f"{where}.parameters", ModelError)
    for name, par in pars.items():
        par = fields.mapping(par, f"{where}.parameters.{name}", ModelError)
        fields.json_number(par.get("value"), f"{where}.parameters.{name}.value", ModelError)
        if par.get("unit") not in UNIT_FACTORS:
            raise ModelError(
                f"{where}.parameters.{name}.unit: expected one of {', '.join(UNIT_FACTORS)}, got {par.get('unit')!r}"
            )
    for key, arc in fields.mapping(ext.get("arcs", {}), f"{where}.arcs", ModelError).items():
        if not re.fullmatch(r"joint_[1-9][0-9]?", str(key)):
            raise ModelError(f"{where}.arcs: {key!r} is not joint_N (N the joint, from 1)")
        arc = fields.mapping(arc, f"{where}.arcs.{key}", ModelError)
        for end in ("from_deg", "to_deg"):
            fields.json_number(arc.get(end), f"{where}.arcs.{key}.{end}", ModelError)


def load_model(path: str | Path) -> Model:
    return model_from_doc(read_json(path, ModelError), str(path))


def parameter_value(pars: dict, p: Param, path: str) -> float:
    """A parameter's deviation in calib units (mm, rad), its 95 % half-width checked on the way: every reader of
    the model (predict, compensate, the report's figures) takes them as given."""
    where = f"{path}: parameters.{p.name}"
    entry = fields.mapping(pars[p.name], where, ModelError)
    value = fields.json_number(entry.get("value"), f"{where}.value", ModelError)
    if fields.json_number(entry.get("ci95"), f"{where}.ci95", ModelError) < 0:
        raise ModelError(f"{where}.ci95: a half-width cannot be negative, got {entry['ci95']!r}")
    return value * (1.0 if p.is_length else np.pi / 180.0)


def _half_widths(entry: dict, keys: tuple[str, ...], where: str) -> None:
    """Each of `keys` the entry has (they are optional: a model written by hand may state none) is three
    non-negative numbers: the report, locate and the ISO 9283 budget read them as given (a fuzzed model.json whose
    station half-widths were null made the report fail with a traceback)."""
    for key in (k for k in keys if k in entry):
        if np.any(fields.vector(entry[key], f"{where}.{key}", ModelError) < 0):
            raise ModelError(f"{where}.{key}: a half-width cannot be negative, got {entry[key]!r}")


def model_from_doc(doc: dict, source: str = "model") -> Model:
    """A Model from a model.json document; every missing, mistyped or non-finite field is a ModelError naming
    `source` and the key."""
    path = source
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise ModelError(f"{path}: not a trackcal model (expected format {FORMAT!r})")
    for key in ("robot", "parameters", "stations", "tool_points"):
        if key not in doc:
            raise ModelError(f"{path}: {key}: missing")
    if "converged" in doc and not isinstance(doc["converged"], bool):
        raise ModelError(f"{path}: converged: expected true or false, got {doc['converged']!r}")
    if "message" in doc and not isinstance(doc["message"], str):
        raise ModelError(f"{path}: message: expected a string, got {doc['message']!r}")
    order = doc.get("covariance_order", [])
    if not isinstance(order, list) or not all(isinstance(n, str) for n in order):
        # found by test_cli_fuzz: a null covariance_order made the report's diagnosis fail with a traceback
        raise ModelError(f"{path}: covariance_order: expected the list of the covariance's parameter names")
    if "weighting" in doc and doc["weighting"] not in WEIGHTINGS:
        raise ModelError(f"{path}: weighting: expected one of {', '.join(WEIGHTINGS)}, got {doc['weighting']!r}")
    try:
        chain = chain_from_dict(doc["robot"], f"{path}: robot")
    except ChainError as exc:
        raise ModelError(str(exc)) from None
    pars = fields.mapping(doc["parameters"], f"{path}: parameters", ModelError)
    try:
        params = [param_by_name(chain, n) for n in pars]
    except ChainError as exc:
        raise ModelError(f"{path}: parameters: {exc}") from None
    dev = np.array([parameter_value(pars, p, path) for p in params])
    stations = {}
    for sid, st in fields.mapping(doc["stations"], f"{path}: stations", ModelError).items():
        where = f"{path}: stations.{sid}"
        st = fields.mapping(st, where, ModelError)
        stations[sid] = Station(
            fields.matrix(st.get("rotation"), f"{where}.rotation", ModelError, (3, 3)),
            fields.vector(st.get("translation_mm"), f"{where}.translation_mm", ModelError),
        )
        _half_widths(st, ("ci95_translation_mm", "ci95_rotation_deg"), where)
    points = {}
    for pid, pt in fields.mapping(doc["tool_points"], f"{path}: tool_points", ModelError).items():
        where = f"{path}: tool_points.{pid}"
        points[pid] = fields.vector(fields.mapping(pt, where, ModelError).get("xyz_mm"), f"{where}.xyz_mm", ModelError)
        _half_widths(pt, ("ci95_mm",), where)
    ext = fields.mapping(doc.get("extension", {"cause": "none"}), f"{path}: extension", ModelError)
    if ext.get("cause", "none") not in ("none", *CAUSES):
        raise ModelError(f"{path}: extension.cause: {ext.get('cause')!r} is not none or one of {', '.join(CAUSES)}")
    _extension_values(ext, f"{path}: extension")
    if "causes" in ext:
        causes = ext["causes"]
        if (
            not isinstance(causes, list)
            or not all(c in CAUSES for c in causes)
            or (causes and causes[0] != ext.get("cause"))
        ):
            raise ModelError(
                f"{path}: extension.causes: expected a list of causes from {', '.join(CAUSES)} "
                f"beginning with extension.cause, got {causes!r}"
            )
    model = Model(chain, params, dev, stations, points, doc)
    try:
        model.measured()
    except CalibError as exc:
        raise ModelError(f"{path}: {exc}") from None
    try:
        model.parts(), model.arcs(), model.extension_values(), model.ranges(), model.forms()  # readable
    except (KeyError, TypeError, ValueError, IndexError, AttributeError, CalibError) as exc:
        raise ModelError(f"{path}: extension: incomplete or malformed ({exc})") from None
    return model


def predict_table(model: Model, rows: MeasurementTable) -> MeasurementTable:
    """`rows` with x, y, z set to the reflector centre the model predicts in each row's station frame."""
    if rows.n_joints != model.chain.dof:
        raise ModelError(
            f"{rows.source}: {rows.n_joints} joint columns, the model's robot has {model.chain.dof} joints"
        )
    ext, theta, labelled = None, None, rows
    info = model.doc["extension"]
    if "after_t_s" in info:  # a moved station, alone or with other causes
        labelled = relabel_shift(rows, info["station"], float(info["after_t_s"]))
    if model.cause != "station_shift":
        ext, theta = model.extension_for(rows)
    xyz = predict_points(model.chain, model.params, model.dev, model.stations, model.points, labelled, ext, theta)
    out = rows.subset(np.arange(len(rows)))
    out.xyz = xyz
    return out
