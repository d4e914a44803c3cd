"""Cells: robot + measurement tool + work-cell box + test pose + tracker stations, from YAML.

`--cell NAME` resolves to configs/cells/NAME.yaml (robots and tools likewise); a value with a slash or
a .yaml suffix is taken as a path. Units in the files: mm and degrees.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np
import yaml

from .chain import Chain, ChainError, chain_from_dict, chain_from_urdf, chain_to_dict
from .errors import CalibError
from .rigid import rot_axis

# Joint angles travel to and from the controller at 4 decimals of a degree (KR C2 EKI and RSI: drivers/kuka):
# rounding a planned pose moves each joint by up to half a step.
CONTROLLER_STEP_DEG = 1e-4

# The shipped configs are package data (a wheel installed anywhere resolves `--cell kr270`); TRACKCAL_CONFIGS
# points at another tree with the same layout.
CONFIGS = Path(os.environ.get("TRACKCAL_CONFIGS") or str(resources.files("configs")))


class CellError(CalibError):
    """A configuration that cannot be used; the message names the file."""


@dataclass
class StationPlacement:
    """Nominal tracker placement: the tracker frame in the robot base frame."""

    rotation: np.ndarray  # base <- tracker
    position: np.ndarray  # mm


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
    measurement_tolerance_mm: float | None = None  # None: from the station set-up uncertainty (campaign.engine.runner)
    source: str = ""


def usable_limits_deg(cell: Cell, margin_deg: float | None = None) -> np.ndarray:
    """(n, 2) deg: the robot's joint limits less `margin_deg` on each side (default: the cell's joint_margin_deg,
    the limits every pose of a campaign must keep); +-inf where the robot has none."""
    margin = cell.joint_margin_deg if margin_deg is None else margin_deg
    return np.degrees(cell.chain.limits_array()) + np.array([margin, -margin])


def plan_joint_bounds(cell: Cell) -> np.ndarray:
    """(n, 2) rad, the planner's bounds: the usable joint limits less half a controller step, so that a planned
    pose rounded to the controller's 4 decimals is still inside usable_limits_deg(cell)."""
    return np.radians(usable_limits_deg(cell, cell.joint_margin_deg + CONTROLLER_STEP_DEG / 2))


def resolve(kind: str, ref: str, base_dir: Path | None = None) -> Path:
    p = Path(ref)
    if p.suffix in (".yaml", ".yml", ".urdf") or "/" in ref:
        if not p.is_absolute() and base_dir is not None and not p.exists():
            p = base_dir / p
        return p
    return CONFIGS / kind / f"{ref}.yaml"


def load_yaml(path: Path) -> dict:
    try:
        doc = yaml.safe_load(path.read_text())
    except FileNotFoundError:
        raise CellError(f"{path}: no such file") from None
    except (OSError, yaml.YAMLError) as exc:
        raise CellError(f"{path}: cannot read YAML ({exc})") from None
    if not isinstance(doc, dict):
        raise CellError(f"{path}: expected a mapping at the top level")
    return doc


def load_robot(ref: str, base_dir: Path | None = None) -> tuple[Chain, dict]:
    path = resolve("robots", ref, base_dir)
    try:
        if path.suffix == ".urdf":
            chain = chain_from_urdf(str(path))
            return chain, chain_to_dict(chain)
        doc = load_yaml(path)
        return chain_from_dict(doc, str(path)), doc
    except ChainError as exc:
        raise CellError(str(exc)) from None


def _vec(doc, key, where, n=3) -> np.ndarray:
    try:
        v = np.asarray(doc[key], dtype=float)
    except (KeyError, TypeError, ValueError):
        raise CellError(f"{where}: '{key}' must be a list of {n} numbers") from None
    if v.shape != (n,) or not np.all(np.isfinite(v)):
        raise CellError(f"{where}: '{key}' must be a list of {n} finite numbers")
    return v


def _non_negative(doc: dict, key: str, where: str, default: float) -> float:
    v = doc.get(key, default)
    if isinstance(v, bool) or not isinstance(v, int | float) or not np.isfinite(v) or v < 0:
        raise CellError(f"{where}: '{key}' must be a non-negative number, got {v!r}")
    return float(v)


def load_tool(ref: str, base_dir: Path | None = None) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    path = resolve("tools", ref, base_dir)
    doc = load_yaml(path)
    pts, normals = {}, {}
    if not isinstance(doc.get("points"), dict) or not doc["points"]:
        raise CellError(f"{path}: a tool needs a 'points' mapping id -> {{xyz_mm: [x, y, z]}}")
    for pid, pd in doc["points"].items():
        where = f"{path}: point {pid}"
        if not isinstance(pd, dict):
            raise CellError(f"{where}: expected a mapping with xyz_mm")
        pts[str(pid)] = _vec(pd, "xyz_mm", where)
        n = _vec(pd, "normal", where) if "normal" in pd else np.array([1.0, 0.0, 0.0])
        normals[str(pid)] = n / np.linalg.norm(n)
    return pts, normals


def load_cell(ref: str) -> Cell:
    path = resolve("cells", ref)
    if not path.exists() and path.parent == CONFIGS / "cells":  # a name, not a path: say which names there are
        known = ", ".join(sorted(p.stem for p in path.parent.glob("*.yaml")))
        raise CellError(f"cell {ref!r}: no such cell; the cells are {known} (or give the path of a cell YAML)")
    doc = load_yaml(path)
    where = str(path)
    for key in ("robot", "tool"):
        if key not in doc:
            raise CellError(f"{where}: missing '{key}'")
    chain, robot_doc = load_robot(str(doc["robot"]), path.parent)
    pts, normals = load_tool(str(doc["tool"]), path.parent)
    cell = Cell(name=str(doc.get("name", path.stem)), chain=chain, robot_doc=robot_doc, tool_points=pts,
                tool_normals=normals, source=where)
    if "box_mm" in doc:
        cell.box_min = _vec(doc["box_mm"], "min", f"{where}: box_mm")
        cell.box_max = _vec(doc["box_mm"], "max", f"{where}: box_mm")
        if np.any(cell.box_min >= cell.box_max):
            raise CellError(f"{where}: box_mm min must be below max on every axis")
    if "test_pose_deg" in doc:
        cell.test_pose = np.radians(_vec(doc, "test_pose_deg", where, chain.dof))
    tcp = doc.get("tcp", "centroid")
    if tcp == "centroid":
        cell.tcp = np.mean(list(pts.values()), axis=0)
    else:
        cell.tcp = _vec(doc, "tcp", where)
    for sid, sd in (doc.get("stations") or {}).items():
        sw = f"{where}: station {sid}"
        cell.stations[str(sid)] = StationPlacement(
            rotation=rot_axis(2, np.radians(float(sd.get("yaw_deg", 0.0)))), position=_vec(sd, "position_mm", sw)
        )
    cell.acceptance_deg = float(doc.get("acceptance_deg", 90.0))
    cell.joint_margin_deg = _non_negative(doc, "joint_margin_deg", where, 1.0)
    narrow = [j.name for j, (lo, hi) in zip(chain.joints, plan_joint_bounds(cell), strict=True) if not lo < hi]
    if narrow:
        raise CellError(f"{where}: joint_margin_deg {cell.joint_margin_deg:g} leaves no range for {', '.join(narrow)}")
    if doc.get("measurement_tolerance_mm") is not None:
        cell.measurement_tolerance_mm = _non_negative(doc, "measurement_tolerance_mm", where, 0.0)
        if cell.measurement_tolerance_mm == 0:
            raise CellError(f"{where}: 'measurement_tolerance_mm' must be positive")
    if doc.get("plan_params") is not None:
        if not isinstance(doc["plan_params"], list) or not all(isinstance(p, str) for p in doc["plan_params"]):
            raise CellError(f"{where}: plan_params must be a list of parameter names")
        cell.plan_params = list(doc["plan_params"])
    return cell
