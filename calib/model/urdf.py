"""A chain written as a URDF (the ROS robot description): `trackcal export-urdf`.

Links `base_link`, `<joint>_link` per joint and `flange` (the frame the tool points are given in, reached by the fixed
joint `trackcal_flange`), and one fixed frame `point_<id>` per tool point given. Joint j's `<origin>` is the
transform from the previous joint's frame (the base for the first) to its own, the chain's link translation and
fixed rotation; its `<axis>` is the signed coordinate axis it turns about. Lengths in metres (URDF), written with 17
significant digits so that every double survives the round trip; rotations as URDF roll-pitch-yaw,
R = Rz(yaw) Ry(pitch) Rx(roll), pitch taken by atan2 so that a rotation near pitch = +-90 deg (a DH flange) still
comes back to 1e-15 (tests/test_urdf.py). A joint without limits is written as revolute with +-720 deg (a
`continuous` joint is a unit circle in pinocchio, not an angle).
"""

from __future__ import annotations

from xml.sax.saxutils import escape, quoteattr

import numpy as np

from trackcal.calib.model.chain import FLANGE_JOINT, Chain
from trackcal.calib.model.rigid import rpy_of

NO_LIMIT_RAD = 4 * np.pi


def _num(v: float) -> str:
    return repr(float(v) + 0.0)  # + 0.0: no "-0.0"


def _origin(translation_mm: np.ndarray, r: np.ndarray) -> str:
    xyz = " ".join(_num(v / 1000.0) for v in translation_mm)
    rpy = " ".join(_num(v) for v in rpy_of(r))
    return f'<origin xyz="{xyz}" rpy="{rpy}"/>'


def chain_to_urdf(chain: Chain, points: dict[str, np.ndarray] | None = None, comment: str = "") -> str:
    """The URDF text of `chain` (nominal geometry: fold deviations in first, calib.model.kinematics.calibrated_chain),
    with a fixed frame per tool point (mm, in the flange frame) and `comment` as the XML comment at its top."""
    body = [f"<robot name={quoteattr(chain.name)}>", '  <link name="base_link"/>']
    parent, translation, rotation = "base_link", chain.base[:3, 3], chain.base[:3, :3]
    for jt in chain.joints:
        child = f"{jt.name}_link"
        axis = " ".join(_num(jt.sign * v) for v in np.eye(3)[jt.axis])
        lo, hi = jt.limits if jt.limits is not None else (-NO_LIMIT_RAD, NO_LIMIT_RAD)
        link = [f"  <link name={quoteattr(child)}>"]
        if jt.mass_kg > 0:
            link += [
                "    <inertial>",
                f'      <mass value="{_num(jt.mass_kg)}"/>',
                f"      {_origin(jt.com, np.eye(3))}",
                '      <inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/>',
                "    </inertial>",
            ]
        body += [
            f'  <joint name={quoteattr(jt.name)} type="revolute">',
            f"    <parent link={quoteattr(parent)}/>",
            f"    <child link={quoteattr(child)}/>",
            f"    {_origin(translation, rotation)}",
            f'    <axis xyz="{axis}"/>',
            f'    <limit lower="{_num(lo)}" upper="{_num(hi)}" effort="0" velocity="0"/>',
            "  </joint>",
            *link,
            "  </link>",
        ]
        parent, translation, rotation = child, jt.translation, jt.rotation
    body += [
        f'  <joint name="{FLANGE_JOINT}" type="fixed">',
        f"    <parent link={quoteattr(parent)}/>",
        '    <child link="flange"/>',
        f"    {_origin(translation, rotation)}",
        "  </joint>",
        '  <link name="flange"/>',
    ]
    for pid, xyz in (points or {}).items():
        link = f"point_{pid}"
        body += [
            f'  <joint name={quoteattr(link + "_joint")} type="fixed">',
            '    <parent link="flange"/>',
            f"    <child link={quoteattr(link)}/>",
            f"    {_origin(np.asarray(xyz, float), np.eye(3))}",
            "  </joint>",
            f"  <link name={quoteattr(link)}/>",
        ]
    body.append("</robot>")
    note = escape(comment).replace("--", "- -")  # "--" may not appear inside an XML comment
    return "\n".join(['<?xml version="1.0"?>', f"<!-- {note} -->", *body]) + "\n"
