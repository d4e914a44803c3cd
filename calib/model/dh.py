"""Denavit-Hartenberg tables, as datasheets and controller manuals print them, turned into trackcal's chain.

Standard DH (Denavit & Hartenberg 1955; the convention of Universal Robots' DH page and most textbooks): link i is
    A_i = Rz(theta_i) . Tz(d_i) . Tx(a_i) . Rx(alpha_i),   theta_i = sign_i * q_i + theta_offset_i,
joint i turning about z of frame i-1; the frame after the last row is the flange.
Modified DH (Craig 1986, "Introduction to Robotics", section 3.4): row i holds a_{i-1}, alpha_{i-1}, d_i, theta_i,
    A_i = Rx(alpha_{i-1}) . Tx(a_{i-1}) . Rz(theta_i) . Tz(d_i),
joint i turning about z of frame i; the frame after the last row is the last joint's frame (datasheets usually put
the flange distance in the last d).

trackcal's chain (calib.model.chain) turns joint j about an axis of its own frame and then applies the link
translation t_j and a fixed rotation R_j. Since Rz(s q + o) = Rz(s q) . Rz(o), a standard row becomes
    axis z, sign s, t = Rz(o) (a, 0, d), R = Rz(o) Rx(alpha)
(Tx(a) and Rx(alpha) commute), and a modified row i with the next row's a_i, alpha_i becomes the same with
t = Rz(o) (a_i, 0, d_i), R = Rz(o) Rx(alpha_i); its first row's Rx(alpha_0) Tx(a_0) joins the base transform. The
chain's forward kinematics are the table's exactly (tests/test_dh.py: 1e-9 mm).

YAML (configs/robots/*-dh.yaml), lengths in mm and angles in deg:
    dh:
      convention: standard            # or modified
      rows:
        - {a_mm: 0, alpha_deg: 90, d_mm: 127.3, theta_offset_deg: 0, sign: 1, name: J1, limits_deg: [-360, 360]}
        ...
      flange: {translation_mm: [0, 0, 0], rpy_deg: [0, 0, 0]}   # optional: DH frame n -> the tool points' frame
`theta_offset_deg` (default 0) and `sign` (+1 or -1, default +1) say how the controller's joint value q maps to the
table's theta; `name`, `limits_deg` (in q), `mass_kg` and `com_mm` are as in a `joints` entry.
"""

from __future__ import annotations

import numpy as np

from trackcal.calib.io import fields
from trackcal.calib.model.rigid import homogeneous, rot_axis, rpy_matrix

CONVENTIONS = ("standard", "modified")
ROW_KEYS = {"a_mm", "alpha_deg", "d_mm", "theta_offset_deg", "sign", "name", "limits_deg", "mass_kg", "com_mm"}
# The physical range of a table's values: the largest industrial arms reach under 5 m (FANUC M-2000iA/2300: 3.7 m;
# KUKA KR 1000 titan: 3.2 m), so no link length or offset of an arm is 20 m; an angle is within one turn.
MAX_LENGTH_MM = 20_000.0
MAX_ANGLE_DEG = 360.0


def _length(row: dict, key: str, where: str, error: type[Exception]) -> float:
    v = fields.yaml_number(row.get(key, 0.0), where, error)
    return fields.bounded(v, MAX_LENGTH_MM, "mm", where, error, "no arm's link is that long")


def _angle(row: dict, key: str, where: str, error: type[Exception]) -> float:
    v = fields.yaml_number(row.get(key, 0.0), where, error)
    return np.radians(fields.bounded(v, MAX_ANGLE_DEG, "deg", where, error, "one turn"))


def standard_dh(a: float, alpha: float, d: float, theta: float) -> np.ndarray:
    """4x4 Rz(theta) Tz(d) Tx(a) Rx(alpha) (mm, rad): one link of a standard DH table."""
    rz = rot_axis(2, theta)
    return homogeneous(rz @ rot_axis(0, alpha), rz @ np.array([a, 0.0, d]))


def modified_dh(a: float, alpha: float, d: float, theta: float) -> np.ndarray:
    """4x4 Rx(alpha) Tx(a) Rz(theta) Tz(d) (mm, rad): one link of a modified (Craig) DH table."""
    rx = rot_axis(0, alpha)
    return homogeneous(rx @ rot_axis(2, theta), np.array([a, 0.0, 0.0]) + rx @ np.array([0.0, 0.0, d]))


def dh_forward(rows: list[dict], convention: str, q: np.ndarray) -> np.ndarray:
    """4x4 flange (standard) or last-joint (modified) frame of a DH table (rows as in the YAML, numbers already
    checked) at joint values q (rad): the table's own product, for checks."""
    link = standard_dh if convention == "standard" else modified_dh
    t = np.eye(4)
    for row, qj in zip(rows, q, strict=True):
        theta = row.get("sign", 1) * qj + np.radians(row.get("theta_offset_deg", 0.0))
        t = t @ link(row.get("a_mm", 0.0), np.radians(row.get("alpha_deg", 0.0)), row.get("d_mm", 0.0), theta)
    return t


def dh_joints(doc: dict, where: str, error: type[Exception]) -> tuple[np.ndarray, list[dict]]:
    """(the 4x4 transform the table adds to the base, one dict per joint with name, sign, translation (mm),
    rotation, and the row's limits_deg / mass_kg / com_mm when given) from the `dh` block of a robot YAML; every
    mistake is `error` naming the key."""
    doc = fields.mapping(doc, where, error)
    convention = doc.get("convention", "standard")
    if convention not in CONVENTIONS:
        raise error(f"{where}.convention: expected standard or modified, got {convention!r}")
    rows = fields.sequence(doc.get("rows"), f"{where}.rows", error)
    if not rows:
        raise error(f"{where}.rows: the table has no rows")
    parsed = []
    for k, row in enumerate(rows):
        rw = f"{where}.rows[{k}]"
        row = fields.mapping(row, rw, error)
        unknown = sorted(set(row) - ROW_KEYS)
        if unknown:
            raise error(f"{rw}: unknown key {unknown[0]!r} (a row has {', '.join(sorted(ROW_KEYS))})")
        sign = fields.yaml_number(row.get("sign", 1), f"{rw}.sign", error)
        if sign not in (1.0, -1.0):
            raise error(f"{rw}.sign: expected 1 or -1, got {row['sign']!r}")
        parsed.append(
            {
                "a": _length(row, "a_mm", f"{rw}.a_mm", error),
                "alpha": _angle(row, "alpha_deg", f"{rw}.alpha_deg", error),
                "d": _length(row, "d_mm", f"{rw}.d_mm", error),
                "offset": _angle(row, "theta_offset_deg", f"{rw}.theta_offset_deg", error),
                "sign": sign,
                "extra": {key: row[key] for key in ("name", "limits_deg", "mass_kg", "com_mm") if key in row},
            }
        )
    flange_doc = fields.mapping(doc.get("flange") or {}, f"{where}.flange", error)
    flange = homogeneous(
        rpy_matrix(*np.radians(fields.vector(flange_doc.get("rpy_deg", [0, 0, 0]), f"{where}.flange.rpy_deg", error))),
        np.array(
            [
                fields.bounded(
                    v, MAX_LENGTH_MM, "mm", f"{where}.flange.translation_mm[{k}]", error, "no tool is that long"
                )
                for k, v in enumerate(
                    fields.vector(flange_doc.get("translation_mm", [0, 0, 0]), f"{where}.flange.translation_mm", error)
                )
            ]
        ),
    )
    base = np.eye(4)
    links = []  # the fixed transform that follows each joint's rotation
    if convention == "standard":
        for r in parsed:
            links.append(standard_dh(r["a"], r["alpha"], r["d"], r["offset"]))
    else:
        base = homogeneous(rot_axis(0, parsed[0]["alpha"]), np.array([parsed[0]["a"], 0.0, 0.0]))
        for i, r in enumerate(parsed):
            nxt = parsed[i + 1] if i + 1 < len(parsed) else {"a": 0.0, "alpha": 0.0}
            links.append(
                homogeneous(rot_axis(2, r["offset"]), np.array([0.0, 0.0, r["d"]]))
                @ homogeneous(rot_axis(0, nxt["alpha"]), np.array([nxt["a"], 0.0, 0.0]))
            )
    links[-1] = links[-1] @ flange
    joints = [
        {"sign": r["sign"], "translation": link[:3, 3].copy(), "rotation": link[:3, :3].copy(), **r["extra"]}
        for r, link in zip(parsed, links, strict=True)
    ]
    return base, joints
