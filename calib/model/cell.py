"""Cells: robot + measurement tool + work-cell box + test pose + tracker stations, from YAML.

`--cell NAME` resolves to configs/cells/NAME.yaml (robots and tools likewise); a value with a slash or
a .yaml suffix is taken as a path. Units in the files: mm and degrees.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np

from trackcal.calib.errors import CalibError
from trackcal.calib.io import fields
from trackcal.calib.io.files import read_json, read_yaml
from trackcal.calib.model.chain import Chain, ChainError, chain_from_dict, chain_from_urdf, chain_to_dict
from trackcal.calib.model.instruments import Instrument, assumed, instrument_from_doc
from trackcal.calib.model.params import complete_params
from trackcal.calib.model.rigid import rot_axis

# Joint angles travel to and from the controller at 4 decimals of a degree (KR C2 EKI and RSI: drivers/kuka):
# rounding a planned pose moves each joint by up to half a step.
CONTROLLER_STEP_DEG = 1e-4

# The shipped configs are package data (a wheel installed anywhere resolves `--cell kr270`); TRACKCAL_CONFIGS
# points at another tree with the same layout.
CONFIGS = Path(os.environ.get("TRACKCAL_CONFIGS") or str(resources.files("trackcal.configs")))


class CellError(CalibError):
    """A configuration that cannot be used; the message names the file."""


@dataclass
class StationPlacement:
    """Nominal tracker placement: the tracker frame in the robot base frame."""

    rotation: np.ndarray  # base <- tracker
    position: np.ndarray  # mm


# The share of a plan's measurements a campaign may skip (a point the tracker could not see from a station) and still
# deliver what the plan promised: the test-pose error rho0 of a plan scales as 1/sqrt(N) when measurements are lost
# evenly (paper eq. 41: the covariance is the inverse of a sum over the measurements), so losing a share s multiplies
# it by 1/sqrt(1 - s); at most 10 % worse: s <= 1 - 1/1.1^2 = 0.17.
MAX_SKIPPED_SHARE = round(1.0 - 1.0 / 1.1**2, 2)

# The largest correction `compensate` writes (cell key `max_correction: {mm: .., deg: ..}`); a target that needs more
# is refused, its nominal kept. An uncalibrated robot misses its targets by about a millimetre: 1.31 mm at most on the
# paper's KR-270 (Wu, Klimchik et al., RCIM 2015, Table 9, before calibration), 1-2 mm being what makers state for
# the absolute accuracy of uncalibrated arms. A model that moves the TCP by 5-10 times that, 10 mm, does not describe
# that robot (or its mastering was lost: master it again before calibrating). Corrected at the shortest lever that
# matters, the wrist centre to the TCP (KR-270: about 0.2 m to the flange plus the tool's 0.28 m), 10 mm turn a wrist
# joint by 1.2 deg: a joint correction above 2 deg is a target near a singularity or a wrong model.
MAX_CORRECTION_MM = 10.0
MAX_CORRECTION_DEG = 2.0


@dataclass
class Cell:
    name: str
    chain: Chain
    robot_doc: dict
    tool_points: dict[str, np.ndarray]
    tool_normals: dict[str, np.ndarray]
    box_min: np.ndarray | None = None
    box_max: np.ndarray | None = None
    test_pose: np.ndarray | None = None  # rad
    tcp: np.ndarray | None = None  # last joint frame, mm
    stations: dict[str, StationPlacement] = field(default_factory=dict)
    acceptance_deg: float = 90.0
    plan_params: list[str] | None = None  # parameters the planner targets (paper section 7.2: nine)
    joint_margin_deg: float = 1.0  # plans keep this far inside every joint limit
    measurement_tolerance_mm: float | None = None  # None: from the station set-up (campaign/engine/expected.py)
    max_skipped_share: float = MAX_SKIPPED_SHARE  # a campaign that skipped more of its planned measurements failed
    repeatability_mm: float = 0.0  # the robot's ISO 9283 pose repeatability RP (datasheet); 0: not stated
    max_correction_mm: float = MAX_CORRECTION_MM  # compensate: the largest TCP correction it writes
    max_correction_deg: float = MAX_CORRECTION_DEG  # compensate: the largest joint correction it writes
    tracker: Instrument = field(default_factory=assumed)  # the cell's `tracker:` (calib.model.instruments)
    source: str = ""
    nominal: str = ""  # which nominal robot: `nominal_of` (model.json records it, the report prints it)


def usable_limits_deg(cell: Cell, margin_deg: float | None = None) -> np.ndarray:
    """(n, 2) deg: the robot's joint limits less `margin_deg` on each side (default: the cell's joint_margin_deg,
    the limits every pose of a campaign must keep); +-inf where the robot has none."""
    margin = cell.joint_margin_deg if margin_deg is None else margin_deg
    return np.degrees(cell.chain.limits_array()) + np.array([margin, -margin])


def plan_joint_bounds(cell: Cell) -> np.ndarray:
    """(n, 2) rad, the planner's bounds: the usable joint limits less half a controller step, so that a planned
    pose rounded to the controller's 4 decimals is still inside usable_limits_deg(cell)."""
    return np.radians(usable_limits_deg(cell, cell.joint_margin_deg + CONTROLLER_STEP_DEG / 2))


class Files:
    """Where a cell's files are read: the disk. A session reads its cell from the copies it stores (StoredFiles)."""

    def exists(self, path: Path) -> bool:
        return path.exists()

    def read(self, path: Path) -> str | None:
        """The file's text; None: read it from the disk where it is used."""
        return None


DISK = Files()


class StoredFiles(Files):
    """A cell's files as texts by their relative paths (a session's stored documents: config/cell.yaml, ...)."""

    def __init__(self, texts: Mapping[str, str]) -> None:
        self.texts = texts

    def exists(self, path: Path) -> bool:
        return path.as_posix() in self.texts

    def read(self, path: Path) -> str:
        if not self.exists(path):
            raise CellError(f"{path}: not stored")
        return self.texts[path.as_posix()]


def resolve(kind: str, ref: str, base_dir: Path | None = None, files: Files = DISK) -> Path:
    p = Path(ref)
    if p.suffix in (".yaml", ".yml", ".urdf") or "/" in ref:
        if not p.is_absolute() and base_dir is not None and not files.exists(p):
            p = base_dir / p
        return p
    return CONFIGS / kind / f"{ref}.yaml"


def load_yaml(path: Path, files: Files = DISK) -> dict:
    return read_yaml(path, CellError, files.read(path))


def load_robot(ref: str, base_dir: Path | None = None, files: Files = DISK) -> tuple[Chain, dict]:
    path = resolve("robots", ref, base_dir, files)
    try:
        if path.suffix == ".urdf":
            chain = chain_from_urdf(str(path), xml=files.read(path))
            return chain, chain_to_dict(chain)
        doc = load_yaml(path, files)
        return chain_from_dict(doc, str(path)), doc
    except ChainError as exc:
        raise CellError(str(exc)) from None


def nominal_of(ref: str, robot_doc: dict, base_dir: Path | None = None) -> str:
    """Which nominal robot a cell's `robot:` is, in words: the robot config's own `nominal` (trackcal factory-robot
    writes the factory calibration it came from), the calibrated model a URDF was exported from (the
    `<stem>.trackcal.json` beside it that trackcal export-urdf writes names it), else the robot config's file."""
    if isinstance(robot_doc.get("nominal"), str) and robot_doc["nominal"].strip():
        return robot_doc["nominal"].strip()
    path = resolve("robots", ref, base_dir)
    shown = f"configs/robots/{path.name}" if path.parent == CONFIGS / "robots" else str(path)
    if path.suffix == ".urdf":
        side = path.with_name(path.stem + ".trackcal.json")
        model = read_json(side, CellError).get("model") if side.is_file() else None
        return f"the calibrated model {model} (exported as {shown})" if model else f"the URDF {shown}"
    return f"the robot config {shown}"


def _non_negative(doc: dict, key: str, where: str, default: float) -> float:
    v = fields.number(doc.get(key, default), f"{where}: {key}", CellError)
    if v < 0:
        raise CellError(f"{where}: {key}: must be a non-negative number, got {v:g}")
    return v


def max_correction(doc: dict, where: str) -> tuple[float, float]:
    """The cell's `max_correction: {mm, deg}` (each optional, positive; defaults MAX_CORRECTION_MM, _DEG)."""
    entry = fields.mapping(doc.get("max_correction") or {}, f"{where}: max_correction (mm, deg)", CellError)
    unknown = sorted(set(map(str, entry)) - {"mm", "deg"})
    if unknown:
        raise CellError(f"{where}: max_correction.{unknown[0]}: unknown key (mm and deg are known)")
    out = []
    for key, default in (("mm", MAX_CORRECTION_MM), ("deg", MAX_CORRECTION_DEG)):
        v = fields.number(entry.get(key, default), f"{where}: max_correction.{key}", CellError)
        if not v > 0:
            raise CellError(f"{where}: max_correction.{key}: must be a positive number, got {v:g}")
        out.append(v)
    return out[0], out[1]


def load_tool(
    ref: str, base_dir: Path | None = None, files: Files = DISK
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    path = resolve("tools", ref, base_dir, files)
    doc = load_yaml(path, files)
    pts, normals = {}, {}
    points = fields.mapping(doc.get("points"), f"{path}: points", CellError)
    if not points:
        raise CellError(f"{path}: points: a tool needs at least one point id -> {{xyz_mm: [x, y, z]}}")
    for pid, pd in points.items():
        where = f"{path}: points.{pid}"
        pd = fields.mapping(pd, where, CellError)
        pts[str(pid)] = fields.vector(pd.get("xyz_mm"), f"{where}.xyz_mm", CellError)
        n = fields.vector(pd.get("normal", [1.0, 0.0, 0.0]), f"{where}.normal", CellError)
        if not np.linalg.norm(n) > 0:
            raise CellError(f"{where}.normal: a direction cannot be zero")
        normals[str(pid)] = n / np.linalg.norm(n)
    return pts, normals


def robot_cell(path: Path) -> Cell:
    """A robot file standing for a cell: the robot alone, no tool, box, stations or test pose. Enough to identify
    from a table, whose reference points then start where the measurements put them (calib.identify.points)."""
    chain, robot_doc = load_robot(str(path))
    return Cell(
        name=chain.name,
        chain=chain,
        robot_doc=robot_doc,
        tool_points={},
        tool_normals={},
        source=str(path),
        nominal=nominal_of(str(path), robot_doc),
    )


def load_cell(ref: str, files: Files = DISK) -> Cell:
    """The cell `ref` names (a name in configs/cells or a path), its robot and tool beside it; `files`: where they
    are read (a session's stored copies: StoredFiles)."""
    path = resolve("cells", ref, files=files)
    if not files.exists(path) and path.parent == CONFIGS / "cells":  # a name, not a path: say which names there are
        known = ", ".join(sorted(p.stem for p in path.parent.glob("*.yaml")))
        raise CellError(f"cell {ref!r}: no such cell; the cells are {known} (or give the path of a cell YAML)")
    if path.suffix == ".urdf":
        return robot_cell(path)
    doc = load_yaml(path, files)
    where = str(path)
    if "robot" not in doc and ("joints" in doc or "dh" in doc):
        return robot_cell(path)
    for key in ("robot", "tool"):
        if key not in doc:
            raise CellError(f"{where}: {key}: missing")
    robot_ref = fields.text(doc["robot"], f"{where}: robot", CellError)
    chain, robot_doc = load_robot(robot_ref, path.parent, files)
    pts, normals = load_tool(fields.text(doc["tool"], f"{where}: tool", CellError), path.parent, files)
    name = fields.text(doc.get("name", path.stem), f"{where}: name", CellError)
    # `nominal:` in the cell says it in words (a session's copy of its cell records it: its robot file is a
    # temporary copy whose path would say nothing)
    nominal = (
        fields.text(doc["nominal"], f"{where}: nominal", CellError)
        if "nominal" in doc
        else nominal_of(robot_ref, robot_doc, path.parent)
    )
    cell = Cell(
        name=name,
        chain=chain,
        robot_doc=robot_doc,
        tool_points=pts,
        tool_normals=normals,
        source=where,
        nominal=nominal,
    )
    _read_placement(cell, doc, where)
    _read_limits(cell, doc, where)
    return cell


def _read_placement(cell: Cell, doc: dict, where: str) -> None:
    """load_cell's box, test pose, TCP and tracker stations, into `cell`."""
    if "box_mm" in doc:
        box = fields.mapping(doc["box_mm"], f"{where}: box_mm", CellError)
        cell.box_min = fields.vector(box.get("min"), f"{where}: box_mm.min", CellError)
        cell.box_max = fields.vector(box.get("max"), f"{where}: box_mm.max", CellError)
        if np.any(cell.box_min >= cell.box_max):
            raise CellError(f"{where}: box_mm: min must be below max on every axis")
    if "test_pose_deg" in doc:
        q0 = fields.vector(doc["test_pose_deg"], f"{where}: test_pose_deg", CellError, cell.chain.dof)
        cell.test_pose = np.radians(q0)
    tcp = doc.get("tcp", "centroid")
    if tcp == "centroid":
        cell.tcp = np.mean(list(cell.tool_points.values()), axis=0)
    else:
        cell.tcp = fields.vector(tcp, f"{where}: tcp (centroid or [x, y, z] mm)", CellError)
    stations = fields.mapping(doc.get("stations") or {}, f"{where}: stations (id -> position_mm, yaw_deg)", CellError)
    for sid, sd in stations.items():
        sw = f"{where}: stations.{sid}"
        sd = fields.mapping(sd, sw, CellError)
        yaw = fields.number(sd.get("yaw_deg", 0.0), f"{sw}.yaw_deg", CellError)
        position = fields.vector(sd.get("position_mm"), f"{sw}.position_mm", CellError)
        cell.stations[str(sid)] = StationPlacement(rotation=rot_axis(2, np.radians(yaw)), position=position)


def _read_limits(cell: Cell, doc: dict, where: str) -> None:
    """load_cell's acceptance angle, margins, tolerances, correction bounds, tracker and planned parameters, into
    `cell`."""
    cell.acceptance_deg = fields.number(doc.get("acceptance_deg", 90.0), f"{where}: acceptance_deg", CellError)
    if not 0 < cell.acceptance_deg <= 180:
        raise CellError(f"{where}: acceptance_deg: {cell.acceptance_deg:g} is not an angle in (0, 180] deg")
    cell.joint_margin_deg = _non_negative(doc, "joint_margin_deg", where, 1.0)
    narrow = [j.name for j, (lo, hi) in zip(cell.chain.joints, plan_joint_bounds(cell), strict=True) if not lo < hi]
    if narrow:
        raise CellError(f"{where}: joint_margin_deg {cell.joint_margin_deg:g} leaves no range for {', '.join(narrow)}")
    if doc.get("measurement_tolerance_mm") is not None:
        cell.measurement_tolerance_mm = _non_negative(doc, "measurement_tolerance_mm", where, 0.0)
        if cell.measurement_tolerance_mm == 0:
            raise CellError(f"{where}: measurement_tolerance_mm: must be positive")
    cell.max_skipped_share = _non_negative(doc, "max_skipped_share", where, MAX_SKIPPED_SHARE)
    cell.repeatability_mm = _non_negative(doc, "repeatability_mm", where, 0.0)
    cell.max_correction_mm, cell.max_correction_deg = max_correction(doc, where)
    cell.tracker = instrument_from_doc(doc.get("tracker"), f"{where}: tracker")
    if cell.max_skipped_share > 1:
        raise CellError(
            f"{where}: max_skipped_share: a share of the planned measurements, 0..1, got {cell.max_skipped_share:g}"
        )
    if doc.get("plan_params") is not None:
        names = fields.sequence(doc["plan_params"], f"{where}: plan_params", CellError)
        cell.plan_params = [fields.text(n, f"{where}: plan_params[{k}]", CellError) for k, n in enumerate(names)]
        known = {p.name for p in complete_params(cell.chain)}
        for k, name in enumerate(cell.plan_params):
            if name not in known:
                raise CellError(
                    f"{where}: plan_params[{k}]: {name!r} is no parameter of robot {cell.chain.name} "
                    f"(e.g. {', '.join(sorted(known)[:4])})"
                )
