"""Sessions: a directory with the store, a snapshot of the configuration and the plan.

SESSION/
  session.sqlite     the event store (campaign/session/store.py)
  config/            copies of the cell, robot and tool YAML as they were when the session started
  config/hardware.yaml  a hardware session's copy of its hardware config (resume reads it)
  plan.json          the plan the campaign executes
The measurement table is derived from the stored `measurement` events (`export_table`).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import yaml

from calib.cell import Cell, load_cell, load_yaml, resolve
from calib.table import MeasurementTable, write_table
from campaign.engine.steps import Step, campaign_steps
from campaign.session.store import SessionStore, StoreError

HARDWARE_COPY = "config/hardware.yaml"  # a hardware session's copy of its hardware config


def snapshot_config(cell_ref: str, directory: Path) -> Path:
    """Copy the cell and the robot and tool it names into directory/config; returns the cell copy."""
    cfg = directory / "config"
    cfg.mkdir(parents=True, exist_ok=True)
    cell_path = resolve("cells", cell_ref)
    doc = load_yaml(cell_path)
    for key, kind in (("robot", "robots"), ("tool", "tools")):
        src = resolve(kind, str(doc[key]), cell_path.parent)
        dst = cfg / f"{key}{src.suffix}"
        shutil.copyfile(src, dst)
        doc[key] = dst.name
    out = cfg / "cell.yaml"
    out.write_text(yaml.safe_dump(doc, sort_keys=False))
    return out


def plan_arrays(plan_doc: dict) -> tuple[np.ndarray, int]:
    try:
        poses = np.asarray(plan_doc["poses_deg"], dtype=float)
        repeat = int(plan_doc.get("repeat", 1))
    except (KeyError, TypeError, ValueError) as exc:
        raise StoreError(f"plan: expected poses_deg (list of joint vectors) and repeat ({exc})") from None
    if poses.ndim != 2 or not np.all(np.isfinite(poses)) or repeat < 1:
        raise StoreError("plan: poses_deg must be a list of finite joint vectors and repeat >= 1")
    return poses, repeat


def create_session(directory: Path, cell_ref: str, plan_doc: dict, mode: str, seed: int | None,
                   hardware: dict | None = None, effects: dict[str, float] | None = None,
                   extra: dict[str, str] | None = None) -> SessionStore:  # fmt: skip
    if (directory / "session.sqlite").exists():
        raise StoreError(f"{directory}: already holds a session (use `trackcal resume {directory}`)")
    session_steps(load_cell(cell_ref), plan_doc)  # the whole plan is checked (PlanError) before a session exists
    directory.mkdir(parents=True, exist_ok=True)
    cell_copy = snapshot_config(cell_ref, directory)
    (directory / "plan.json").write_text(json.dumps(plan_doc, indent=2) + "\n")
    meta = {"cell": str(cell_copy.relative_to(directory)), "cell_ref": cell_ref, "mode": mode,
            "seed": "" if seed is None else str(seed), "hardware": json.dumps(hardware or {}),
            "effects": json.dumps(effects or {}), **(extra or {})}  # fmt: skip
    return SessionStore.create(directory, meta)


def session_cell(store: SessionStore) -> Cell:
    return load_cell(str(store.directory / store.meta()["cell"]))


def session_plan(store: SessionStore) -> dict:
    try:
        return json.loads((store.directory / "plan.json").read_text())
    except (OSError, ValueError) as exc:
        raise StoreError(f"{store.directory}: plan.json unreadable ({exc})") from None


def session_steps(cell: Cell, plan_doc: dict) -> list[Step]:
    poses, repeat = plan_arrays(plan_doc)
    if poses.shape[1] != cell.chain.dof:
        raise StoreError(f"plan: poses have {poses.shape[1]} joints, robot {cell.chain.name} has {cell.chain.dof}")
    return list(campaign_steps(cell, poses, repeat))


def measured_keys(store: SessionStore) -> list[tuple[str, str, tuple[float, ...]]]:
    """(station, point, joints) of every stored measurement: what a simulated world needs on resume so that
    each measurement keeps the noise of an uninterrupted run."""
    return [(e.data["station"], e.data["point"], tuple(e.data["q_deg"])) for e in store.events("measurement")]


def export_table(store: SessionStore, source: str = "session") -> MeasurementTable:
    events = store.events("measurement")
    n = len(events)
    if n == 0:
        raise StoreError(f"{store.directory}: the session holds no measurement yet")
    d = [e.data for e in events]
    extra = {
        "drift": ["1" if x["drift"] else "0" for x in d],
        "std_x_mm": [f"{x['std_mm'][0]:.4f}" for x in d],
        "std_y_mm": [f"{x['std_mm'][1]:.4f}" for x in d],
        "std_z_mm": [f"{x['std_mm'][2]:.4f}" for x in d],
        "temp_c": [f"{x['env'][0]:.2f}" for x in d],
        "pressure_hpa": [f"{x['env'][1]:.2f}" for x in d],
        "humidity_pct": [f"{x['env'][2]:.1f}" for x in d],
    }
    return MeasurementTable(
        seq=np.arange(1, n + 1), t_s=np.array([e.t_campaign for e in events]), pose=[x["pose"] for x in d],
        station=[x["station"] for x in d], point=[x["point"] for x in d], q_deg=np.array([x["q_deg"] for x in d]),
        xyz=np.array([x["xyz_mm"] for x in d]), extra=extra, source=source,
    )  # fmt: skip


def write_export(store: SessionStore, path: Path) -> int:
    table = export_table(store, str(path))
    write_table(table, path)
    return len(table)
