"""Sessions: a directory whose database is the record, and the copies beside it that people read.

SESSION/
  session.sqlite     the event store (campaign/session/store.py), which also holds the documents below as they were
                     when the session was created
  session.lock       the lock of the one process writing the session (store.SessionLock)
  config/            cell.yaml, robot.yaml (or .urdf), tool.yaml, and hardware.yaml in a hardware session
  plan.json          the plan the campaign executes
Resume and replay read the stored documents, never the files beside the database: an edited plan.json or cell
cannot change a campaign under way (`changed_copies` names the files that differ from the stored ones). The
measurement table is derived from the stored `measurement` events (`export_table`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from trackcal.calib.io.files import write_text
from trackcal.calib.io.table import MeasurementTable, write_table
from trackcal.calib.model.cell import Cell, StoredFiles, load_cell, load_yaml, resolve
from trackcal.campaign.engine.documents import MeasurementDoc, measurement
from trackcal.campaign.session.store import SessionStore, StoreError

PLAN_DOC = "plan.json"
CELL_DOC = "config/cell.yaml"
HARDWARE_COPY = "config/hardware.yaml"  # a hardware session's config
# meta: "1" in a session whose blocks open on the pose their closing drift revisit is approached from
# (calib.doe.order); a session made before that walks the order it was made with
APPROACHED = "approached_revisits"


@dataclass(frozen=True)
class SessionFiles:
    """The files of a session folder, by what they hold: the one place that spells their names."""

    directory: Path

    @property
    def plan(self) -> Path:
        return self.directory / PLAN_DOC

    @property
    def cell(self) -> Path:
        return self.directory / CELL_DOC

    @property
    def hardware(self) -> Path:
        return self.directory / HARDWARE_COPY

    @property
    def robot_log(self) -> Path:
        """What the robot driver's native library printed by itself (drivers/families.py: native_output)."""
        return self.directory / "robot-native.log"

    @property
    def table(self) -> Path:
        """The measurement table exported at the end of the campaign."""
        return self.directory / "table.csv"

    @property
    def model(self) -> Path:
        """The model to use (extended by the diagnosed cause when there is one)."""
        return self.directory / "model.json"

    @property
    def geometric_model(self) -> Path:
        """The purely geometric model, beside model.json when that one is extended by a cause."""
        return self.directory / "model-geometric.json"

    @property
    def verdict(self) -> Path:
        return self.directory / "verdict.json"

    @property
    def report(self) -> Path:
        """The report's folder (report.html and its figures)."""
        return self.directory / "report"


def config_documents(cell_ref: str, nominal: str) -> dict[str, str]:
    """The cell and the robot and tool it names, as texts under their session names (config/...); the cell's
    robot and tool point at their neighbours, and the copy of the cell names its `nominal` robot (the loaded
    cell's: its robot file's path, once copied, would say nothing)."""
    cell_path = resolve("cells", cell_ref)
    doc = load_yaml(cell_path)
    doc.setdefault("nominal", nominal)
    docs = {}
    for key, kind in (("robot", "robots"), ("tool", "tools")):
        src = resolve(kind, str(doc[key]), cell_path.parent)
        name = f"config/{key}{src.suffix}"
        docs[name] = src.read_text()
        doc[key] = Path(name).name
    doc.setdefault("name", cell_path.stem)  # the copy keeps the cell's name (not "cell", its file's)
    docs[CELL_DOC] = yaml.safe_dump(doc, sort_keys=False)
    return docs


def stored_config(store: SessionStore) -> dict[str, str]:
    """The session's stored cell, robot and tool documents (config/..., as config_documents made them)."""
    return {
        name: text for name, text in store.documents().items() if name.startswith("config/") and name != HARDWARE_COPY
    }


def changed_copies(store: SessionStore) -> list[str]:
    """The documents whose file beside the database is missing or differs from the stored copy."""
    changed = []
    for name, text in store.documents().items():
        try:
            same = (store.directory / name).read_bytes() == text.encode()
        except OSError:
            same = False
        if not same:
            changed.append(name)
    return changed


def create_session(
    directory: Path,
    cell_ref: str,
    nominal: str,
    plan_doc: dict,
    mode: str,
    seed: int | None,
    hardware: tuple[str, str] | None = None,
    effects: dict[str, float] | None = None,
    extra: dict[str, str] | None = None,
    approached: bool = True,
    config: dict[str, str] | None = None,
) -> SessionStore:
    """A new session holding its lock, with the cell (`nominal`: its loaded Cell's), robot, tool, plan and
    (`hardware`: text, source path) the hardware config stored in it, and which campaign order it walks
    (`approached`: calib.doe.order); `config`: the cell's documents when they come from another session (its
    stored_config), else config_documents(cell_ref). The caller has checked the cell and the plan
    (campaign/jobs/campaign.py): a cell or plan that cannot run makes no session."""
    config = config if config is not None else config_documents(cell_ref, nominal)
    documents = {**config, PLAN_DOC: json.dumps(plan_doc, indent=2) + "\n"}
    meta = {
        "mode": mode,
        "seed": "" if seed is None else str(seed),
        "effects": json.dumps(effects or {}),
        APPROACHED: "1" if approached else "0",
        **(extra or {}),
    }
    if hardware is not None:
        documents[HARDWARE_COPY], meta["hardware_source"] = hardware
    store = SessionStore.create(directory, meta, documents)
    for name, text in documents.items():
        path = store.directory / name
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            write_text(path, text)
        except OSError as exc:
            store.close()
            raise StoreError(f"{path}: cannot write ({exc.strerror})") from None
    return store


def session_cell(store: SessionStore) -> Cell:
    """The cell the session was created with, from its stored documents (never the files beside the database)."""
    return load_cell(CELL_DOC, StoredFiles(stored_config(store)))


def session_plan(store: SessionStore) -> dict:
    return json.loads(store.documents()[PLAN_DOC])


def session_approached(store: SessionStore) -> bool:
    """Does the session walk the order whose drift revisits are approached alike (calib.doe.order)?"""
    return store.meta().get(APPROACHED) == "1"


def session_hardware(store: SessionStore) -> str:
    """The hardware config a hardware session was created with (its text)."""
    return store.documents()[HARDWARE_COPY]


class SessionLog:
    """The session store as a subscriber of the engine's documents (campaign/engine/engine.py): each document of
    the record is committed (SessionStore.append) before this returns, so before the engine goes on. The event
    kinds are the documents' names, but `start` is stored as campaign_started and a successful `stop` as
    campaign_done; `progress` and any other `stop` are not stored (the error that stopped the run is)."""

    KINDS = {"start": "campaign_started"}

    def __init__(self, store: SessionStore):
        self.store = store

    def __call__(self, doc) -> None:
        if doc.name == "progress":
            return
        if doc.name == "stop":
            if doc.data["exit_status"] == "success":
                self.store.append("campaign_done", {}, doc.step, doc.t)
            return
        self.store.append(self.KINDS.get(doc.name, doc.name), doc.data, doc.step, doc.t)


def measured_keys(store: SessionStore) -> list[tuple[str, str, tuple[float, ...]]]:
    """(station, point, joints) of every stored measurement: what a simulated world needs on resume so that
    each measurement keeps the noise of an uninterrupted run."""
    return [(m["station"], m["point"], tuple(m["q_deg"])) for m in stored_measurements(store)]


def stored_measurements(store: SessionStore) -> list[MeasurementDoc]:
    """The data of every stored measurement, in order (engine/documents.py MeasurementDoc)."""
    return [measurement(e.data) for e in store.events("measurement")]


def campaign_warnings(store: SessionStore) -> list[str]:
    """Every warning of the campaign in order (skipped points, drift checks, blocked motion, resumes), each with
    the campaign time it was raised at."""
    return [f"t = {e.t_campaign:.0f} s: {e.data['message']}" for e in store.events("warning")]


def export_table(store: SessionStore, source: str = "session") -> MeasurementTable:
    events = store.events("measurement")
    n = len(events)
    if n == 0:
        raise StoreError(f"{store.directory}: the session holds no measurement yet")
    d = [measurement(e.data) for e in events]
    extra = {
        "drift": ["1" if x["drift"] else "0" for x in d],
        "std_x_mm": [f"{x['std_mm'][0]:.4f}" for x in d],
        "std_y_mm": [f"{x['std_mm'][1]:.4f}" for x in d],
        "std_z_mm": [f"{x['std_mm'][2]:.4f}" for x in d],
        "temp_c": [f"{x['env'][0]:.2f}" for x in d],
        "pressure_hpa": [f"{x['env'][1]:.2f}" for x in d],
        "humidity_pct": [f"{x['env'][2]:.1f}" for x in d],
    }
    if any("approach" in x for x in d):  # ISO 9283 with its multi-directional test (7.2): the side each came from
        extra["approach"] = [x.get("approach", "none") for x in d]
    return MeasurementTable(
        seq=np.arange(1, n + 1),
        t_s=np.array([e.t_campaign for e in events]),
        pose=[x["pose"] for x in d],
        station=[x["station"] for x in d],
        point=[x["point"] for x in d],
        q_deg=np.array([x["q_deg"] for x in d]),
        xyz=np.array([x["xyz_mm"] for x in d]),
        extra=extra,
        source=source,
    )


def write_export(store: SessionStore, path: Path) -> int:
    table = export_table(store, str(path))
    write_table(table, path)
    return len(table)
