"""What the page shows, folded from the session's events: the same fold for the snapshot a page gets when it
(re)connects (every event the session holds) and for each event after it, so a reload or a dropped link shows
what the session says, never what a page remembered.

An event here is (id, step, t_campaign, kind, data) as the store holds it (campaign/session/store.py KINDS).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trackcal.calib.model.cell import Cell
from trackcal.campaign.engine.documents import measurement
from trackcal.campaign.engine.expected import expected_position
from trackcal.campaign.engine.steps import Step, StepKind


@dataclass(frozen=True)
class StoredEvent:
    id: int
    step: int
    t: float
    kind: str
    data: dict


def plan_view(cell: Cell, steps: list[Step]) -> dict:
    """What does not change during a campaign: the stations (position, mm, in the cell frame), the reference
    points (in the last joint frame) and every planned measurement with where the nominal model expects it in
    its station's frame (the plot's plan)."""
    expected = expected_position(cell)
    planned = []
    for i, s in enumerate(steps):
        if s.kind == StepKind.MEASURE:
            e = expected(s)
            planned.append(
                {
                    "step": i,
                    "station": s.station,
                    "point": s.point,
                    "pose": s.pose,
                    "xyz": None if e is None else [round(v, 2) for v in e],
                }
            )
    return {
        "cell": cell.name,
        "stations": {sid: [round(float(v), 1) for v in st.position] for sid, st in cell.stations.items()},
        "points": {pid: [round(float(v), 1) for v in np.asarray(p)] for pid, p in sorted(cell.tool_points.items())},
        "steps": len(steps),
        "planned": planned,
    }


class PageState:
    """The fold. `view` is the JSON the page renders; `apply` folds one event and returns the keys of `view`
    it changed and the measured points it added (what a page already showing the view needs)."""

    KEYS = ("run", "step", "progress", "prompt", "answer", "cell", "warnings", "fits")

    def __init__(self, steps: list[Step], plan: dict) -> None:
        self.steps = steps
        self.expected = {p["step"]: p["xyz"] for p in plan["planned"]}
        self.measures = [i for i, s in enumerate(steps) if s.kind == StepKind.MEASURE]
        self.done: set[int] = set()
        self.measured_steps: set[int] = set()
        self.t_first: float | None = None
        self.done_at_start = 0
        self.view: dict = {
            "run": {"status": "waiting", "reason": ""},
            "step": {"index": None, "of": len(steps), "label": ""},
            "progress": {
                "measured": 0,
                "skipped": 0,
                "planned": len(self.measures),
                "station": "",
                "point": "",
                "pose": "",
                "t": 0.0,
                "time_left_s": None,
            },
            "prompt": None,
            "answer": None,
            "cell": {"door_closed": None, "estop_ok": None, "moving": False, "locked": None, "meteo": None},
            "warnings": [],
            "fits": [],  # the station_fit documents (engine/station_fit.py), one per station block, in block order
        }
        self.points: list[dict] = []

    def fold(self, events) -> PageState:
        for e in events:
            self.apply(e)
        return self

    def apply(self, e: StoredEvent) -> tuple[set[str], list[dict]]:
        v, changed, added = self.view, set(), []
        if e.kind == "campaign_started":
            v["run"] = {"status": "running", "reason": ""}
            self.t_first, self.done_at_start = e.t, len(self.done)
            changed.add("run")
        elif e.kind == "campaign_done":
            v["run"] = {"status": "success", "reason": ""}
            v["prompt"] = None
            v["step"] = {**v["step"], "index": None, "label": "complete"}
            changed |= {"run", "prompt", "step"}
        elif e.kind == "error":
            v["run"] = {"status": "stopped", "reason": e.data.get("message", "")}
            v["cell"] = {**v["cell"], "moving": False}
            changed |= {"run", "cell"}
        elif e.kind == "step_started" and 0 <= e.step < len(self.steps):
            s = self.steps[e.step]
            v["step"] = {"index": e.step, "of": len(self.steps), "label": s.label}
            v["progress"] = {
                **v["progress"],
                "station": s.station or v["progress"]["station"],
                "point": s.point or v["progress"]["point"],
                "pose": s.pose or v["progress"]["pose"],
            }
            changed |= {"step", "progress"}
            if s.kind in (StepKind.MOVE, StepKind.SETTLE):
                v["cell"] = {**v["cell"], "moving": True}
                changed.add("cell")
        elif e.kind in ("step_done", "measurement"):
            if e.kind == "measurement":
                self.measured_steps.add(e.step)
                exp, m = self.expected.get(e.step), measurement(e.data)
                dev = None if exp is None else round(float(np.linalg.norm(np.subtract(m["xyz_mm"], exp))), 3)
                point = {
                    "id": e.id,
                    "step": e.step,
                    "station": m["station"],
                    "point": m["point"],
                    "pose": m["pose"],
                    "xyz": [round(x, 3) for x in m["xyz_mm"]],
                    "dev_mm": dev,
                }
                self.points.append(point)
                added.append(point)
                v["cell"] = {**v["cell"], "locked": True, "meteo": e.data.get("env") or v["cell"]["meteo"]}
                changed.add("cell")
            self.done.add(e.step)
            if e.kind == "step_done" and 0 <= e.step < len(self.steps) and v["cell"]["moving"]:
                v["cell"] = {**v["cell"], "moving": False}
                changed.add("cell")
            v["progress"] = self._progress(e.t)
            changed.add("progress")
        elif e.kind == "prompt":
            v["prompt"] = {
                "id": e.id,
                "kind": e.data.get("kind", ""),
                "target": e.data.get("target", ""),
                "text": e.data.get("text", ""),
                "station": v["progress"]["station"],
            }
            changed.add("prompt")
        elif e.kind == "operator":
            v["prompt"] = None
            v["answer"] = {"answer": e.data.get("answer", ""), "t": e.t, "id": e.id}
            changed |= {"prompt", "answer"}
        elif e.kind == "warning":
            v["warnings"] = [*v["warnings"], {"id": e.id, "t": round(e.t, 1), "message": e.data.get("message", "")}]
            changed.add("warnings")
        elif e.kind == "station_fit":
            fits = [f for f in v["fits"] if f["block"] != e.data.get("block")] + [{**e.data, "id": e.id}]
            v["fits"] = sorted(fits, key=lambda f: f["block"])
            changed.add("fits")
        elif e.kind == "call":
            changed |= self._call(e.data)
        return changed, added

    def _call(self, d: dict) -> set[str]:
        """The cell's state as the engine's own device calls saw it."""
        cell = dict(self.view["cell"])
        dev, op, result, error = d.get("device"), d.get("op"), d.get("result"), d.get("error")
        if dev == "cellio" and op == "door_closed" and error is None:
            cell["door_closed"] = bool(result)
        elif dev == "meteo" and op == "read" and isinstance(result, dict):
            cell["meteo"] = [result.get("temperature_c"), result.get("pressure_hpa"), result.get("humidity_pct")]
        elif dev == "tracker" and op in ("measure", "find_reflector"):
            if error is not None and error.get("type") == "TargetNotVisible":
                cell["locked"] = False
        elif dev == "tracker" and op == "status" and isinstance(result, dict):
            cell["locked"] = bool(result.get("reflector_locked"))
        if cell == self.view["cell"]:
            return set()
        self.view["cell"] = cell
        return {"cell"}

    def _progress(self, t: float) -> dict:
        done_measures = sum(1 for k in self.measures if k in self.done)
        measured = len(self.measured_steps)
        left = len(self.steps) - len(self.done)
        this_run = len(self.done) - self.done_at_start
        rate = None if self.t_first is None or this_run <= 0 else (t - self.t_first) / this_run
        return {
            **self.view["progress"],
            "measured": measured,
            "skipped": max(0, done_measures - measured),
            "t": round(t, 1),
            "time_left_s": None if rate is None else round(rate * left, 0),
        }
