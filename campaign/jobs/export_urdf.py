"""`trackcal export-urdf` on typed options: the calibrated geometric robot of a model.json (or the nominal robot of
a cell or a robot description) as a URDF, and beside it one JSON file with what a URDF cannot hold.

    trackcal export-urdf --model model.json --out robot.urdf     # also writes robot.trackcal.json
    trackcal export-urdf --cell kr270 --out kr270.urdf            # the nominal robot and the cell's tool points
    trackcal export-urdf --robot ur10-dh --out ur10.urdf          # a robot description alone

The URDF (calib.model.urdf) is the chain with every identified deviation folded into its geometry
(calib.model.kinematics.calibrated_chain): its forward kinematics to the `flange` link and to each `point_<id>` frame
are the model's geometric prediction (tests/test_urdf.py: 1e-6 mm, through pinocchio). Its XML comment names the
JSON file beside it (`<stem>.trackcal.json`), which holds, in the units of model.json (mm, deg):
  {"format": "trackcal-urdf-sidecar/1", "urdf": file name, "model": the model.json it came from (null for a nominal
   robot), "robot": name, "joints": [names in chain order],
   "extension": the model's extension, exactly as in model.json ({"cause": "none"} without one): the joint error
     map, compliance, backlash, encoder scale, cyclic error, thermal or station-shift terms that `predict` and
     `compensate` add to the geometric model, none of which a URDF can express,
   "parameters": the geometric deviations already folded into the URDF, with their 95 % intervals (for the record),
   "stations": the tracker stations (station <- robot base), "tool_points": the tool points (also frames in the
     URDF), "not_identifiable": as in model.json, when a joint never moved}
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from trackcal.calib.io.files import write_json, write_text
from trackcal.calib.model.cell import load_cell, load_robot
from trackcal.calib.model.kinematics import calibrated_chain
from trackcal.calib.model.urdf import chain_to_urdf
from trackcal.campaign.errors import InputError, OptionError
from trackcal.campaign.jobs.trusted import trusted_model

SIDECAR_FORMAT = "trackcal-urdf-sidecar/1"


@dataclass(frozen=True)
class ExportUrdfOptions:
    out: str  # the URDF to write
    model: str | None = None  # model.json: the calibrated robot
    cell: str | None = None  # or a cell: its nominal robot and tool points
    robot: str | None = None  # or a robot description (configs/robots name, YAML or URDF path)
    accept_edited: bool = False  # use a model whose digest does not match its content (calib.model_trust)


@dataclass
class ExportUrdfOutcome:
    urdf: Path
    sidecar: Path
    joints: int
    cause: str
    warnings: list[str] = field(default_factory=list)  # e.g. a model without a digest


def sidecar_path(urdf: str | Path) -> Path:
    p = Path(urdf)
    return p.with_name(p.stem + ".trackcal.json")


def export_urdf(opts: ExportUrdfOptions) -> ExportUrdfOutcome:
    given = [name for name in ("model", "cell", "robot") if getattr(opts, name)]
    if len(given) != 1:
        raise OptionError("give one of {0}, {1} or {2}" + (" (not several)" if given else ""), "model", "cell", "robot")
    if not opts.out.endswith(".urdf"):
        raise OptionError("{0} {out}: a URDF file name ends in .urdf", "out", out=opts.out)
    side = sidecar_path(opts.out)
    warnings: list[str] = []
    doc: dict = {"format": SIDECAR_FORMAT, "urdf": Path(opts.out).name, "model": None}
    if opts.model:
        model, warnings = trusted_model(opts.model, opts.accept_edited)
        chain = calibrated_chain(model.chain, model.params, model.dev)
        points = model.points
        src = model.doc
        doc["model"] = str(opts.model)
        doc["extension"] = src.get("extension", {"cause": "none"})
        doc["parameters"] = src["parameters"]
        doc["stations"] = src["stations"]
        doc["tool_points"] = src["tool_points"]
        if "not_identifiable" in src:
            doc["not_identifiable"] = src["not_identifiable"]
        what = f"the calibrated geometric robot of {opts.model}"
    else:
        if opts.cell:
            cell = load_cell(opts.cell)
            chain, points = cell.chain, cell.tool_points
        else:
            chain, _ = load_robot(opts.robot)
            points = {}
        doc["extension"] = {"cause": "none"}
        doc["parameters"] = {}
        doc["stations"] = {}
        doc["tool_points"] = {pid: {"xyz_mm": np.asarray(x).tolist()} for pid, x in points.items()}
        what = f"the nominal robot of {opts.cell or opts.robot}"
    doc["robot"] = chain.name
    doc["joints"] = [jt.name for jt in chain.joints]
    comment = (
        f"written by trackcal export-urdf: {what}. What a URDF cannot hold (the model's extension: "
        f"{doc['extension'].get('cause', 'none')}; tracker stations; parameter intervals) is in {side.name} "
        "beside this file."
    )
    write_text(opts.out, chain_to_urdf(chain, points, comment), InputError)
    write_json(side, doc, InputError)
    return ExportUrdfOutcome(Path(opts.out), side, chain.dof, doc["extension"].get("cause", "none"), warnings)
