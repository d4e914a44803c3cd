"""`trackcal factory-robot`: a robot config whose nominal is the controller's own (factory) calibration, for the cell
to calibrate further. The robot config of the cell names its controller (`controller`, configs/robots); that family
(drivers/families.py) reads the table: the deltas of the controller's calibration file added to the cell robot's
published DH table, or the calibrated table the controller sends (from the address the hardware file names, the only
peer contacted). The chain is the table exactly (calib.model.dh_chain: its lengths, joint offsets and axis tilts as
calibrated; calib.model.params generates the parameters of tilted axes), written as a robot YAML whose `nominal` says
where it came from (identify records it in model.json, the report prints it)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from trackcal.calib.io.files import write_text
from trackcal.calib.model.cell import load_cell
from trackcal.calib.model.chain import ChainError, chain_to_dict
from trackcal.calib.model.dh_chain import dh_chain, dh_of_chain
from trackcal.campaign.cells.hardware import load_hardware
from trackcal.campaign.errors import InputError, OptionError
from trackcal.drivers.families import families


@dataclass(frozen=True)
class FactoryRobot:
    path: Path
    source: str  # which nominal: where the table came from
    max_length_change_mm: float  # against the published table
    max_rotation_change_deg: float  # the largest link rotation against the published table


def factory_robot(cell_ref: str, out: str, conf: str | None = None, hardware: str | None = None) -> FactoryRobot:
    if (conf is None) == (hardware is None):
        raise OptionError("give exactly one of {0} FILE or {1} FILE", "conf", "hardware")
    cell = load_cell(cell_ref)
    name = cell.robot_doc.get("controller")
    family = families().get(str(name)) if name else None
    if family is None or family.factory_table is None:
        raise InputError(
            f"cell {cell.name}: robot {cell.chain.name} names no controller whose calibration trackcal "
            "reads (configs/robots: controller)"
        )
    try:
        nominal = dh_of_chain(cell.chain)
    except ChainError as exc:
        raise InputError(f"cell {cell.name}: {exc}") from None
    if conf is not None:
        theta, a, d, alpha, source, is_delta = family.factory_table(conf=conf)
    else:
        hw = load_hardware(hardware)
        if hw.robot["protocol"] != family.name:
            raise InputError(f"{hardware}: its robot is a {hw.family.title}, cell {cell.name}'s a {family.title}")
        theta, a, d, alpha, source, is_delta = family.factory_table(host=hw.robot["host"])
    table = [np.asarray(v, dtype=float) for v in (theta, a, d, alpha)]
    if is_delta:
        table = [n + t for n, t in zip(nominal, table, strict=True)]
    chain = dh_chain(*table, name=f"{cell.chain.name}-factory", template=cell.chain)
    published = dh_chain(*nominal, name=cell.chain.name, template=cell.chain)
    turned = max(
        float(np.degrees(np.arccos(np.clip((np.trace(j.rotation.T @ e.rotation) - 1) / 2, -1, 1))))
        for j, e in zip(chain.joints, published.joints, strict=True)
    )
    change = float(max(np.abs(table[1] - nominal[1]).max(), np.abs(table[2] - nominal[2]).max()))
    doc = chain_to_dict(chain)
    doc["controller"] = family.name
    how = f"its deltas added to robot {cell.chain.name}'s table" if is_delta else "the controller's calibrated table"
    doc["nominal"] = f"the factory calibration of {source} ({how}; trackcal factory-robot)"
    text = (
        f"# {cell.chain.name} with the factory calibration of {source} as its nominal (trackcal factory-robot):\n"
        f"# the calibrated DH table exactly: link lengths changed by up to {change:.4f} mm, link rotations by up "
        f"to {turned:.4f} deg against the published table\n" + yaml.safe_dump(doc, sort_keys=False)
    )
    path = Path(out)
    write_text(path, text, InputError)
    return FactoryRobot(path, source, change, turned)
