"""Serial chains of revolute joints: description, YAML and URDF sources.

A chain is T(q) = T_base . prod_j [ R_{e_j}(s_j (q_j + dq_j)) . Trans(t_j) . R_err,j . R_nom,j ]
with, per joint j, the axis e_j (x, y or z of the joint's frame, sign s_j), the nominal link translation
t_j expressed in the frame right after the joint rotation, and an optional fixed nominal rotation
R_nom,j from that frame to the next joint's frame. Lengths in mm, angles in rad inside `calib`.
"""

from __future__ import annotations

import os
import re
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from trackcal.calib.errors import CalibError
from trackcal.calib.io import fields
from trackcal.calib.model.dh import dh_joints
from trackcal.calib.model.rigid import AXIS_INDEX, AXIS_NAME, homogeneous, rpy_matrix, rpy_of, turning

# The fixed joint of a URDF written by trackcal (calib.model.urdf) that leads from the last joint to the flange, the
# frame of the tool points: chain_from_urdf takes the last link from it, so a written URDF reads back exactly.
FLANGE_JOINT = "trackcal_flange"
# A URDF with more joints (movable and fixed) is refused before pinocchio reads it: a serial arm has 6 or 7, its URDF
# with tool, sensor and point frames a few dozen; pinocchio's parser recurses once per joint and took the process down
# (a segmentation fault, no error) on a 5000-joint chain.
MAX_URDF_JOINTS = 100
_URDF_JOINT = re.compile(rb"<joint[\s>/]")


class ChainError(CalibError):
    """A chain description that cannot be used (bad axis, non-aligned axes, bad numbers)."""


@dataclass(frozen=True)
class Joint:
    name: str
    axis: int  # 0, 1, 2 = x, y, z of the joint's frame
    sign: float  # +1 or -1
    translation: np.ndarray  # nominal link translation (mm), frame after the joint rotation
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))  # fixed R_nom to the next frame
    limits: tuple[float, float] | None = None  # rad
    mass_kg: float = 0.0  # body moved by this joint (for gravity work)
    com: np.ndarray = field(default_factory=lambda: np.zeros(3))  # mm, frame after the joint rotation


@dataclass(frozen=True)
class Chain:
    name: str
    base: np.ndarray  # 4x4 nominal base transform (robot base frame -> first joint frame), mm
    joints: tuple[Joint, ...]

    @property
    def dof(self) -> int:
        return len(self.joints)

    def limits_array(self) -> np.ndarray:
        """(n, 2) joint limits in rad; +-inf where none is given."""
        out = np.tile([-np.inf, np.inf], (self.dof, 1))
        for j, joint in enumerate(self.joints):
            if joint.limits is not None:
                out[j] = joint.limits
        return out


def _parse_axis(text: str, where: str) -> tuple[int, float]:
    t = str(text).strip().lower()
    sign = 1.0
    if t[:1] in "+-":
        sign = -1.0 if t[0] == "-" else 1.0
        t = t[1:]
    if t not in AXIS_INDEX:
        raise ChainError(f"{where}: axis must be x, y or z (optionally signed), got {text!r}")
    return AXIS_INDEX[t], sign


def _limits(jd: dict, where: str) -> tuple[float, float] | None:
    if jd.get("limits_deg") is None:
        return None
    lo, hi = fields.vector(jd["limits_deg"], f"{where}.limits_deg", ChainError, 2)
    if not lo < hi:
        raise ChainError(f"{where}.limits_deg: must be [min, max] with min < max")
    return np.radians(lo), np.radians(hi)


def _joint(jd: dict, k: int, where: str, axis: int, sign: float, translation, rotation) -> Joint:
    """A joint with the name, limits and mass model of its YAML entry `jd` (a `joints` entry or a DH row)."""
    return Joint(
        name=fields.text(jd.get("name", f"A{k + 1}"), f"{where}.name", ChainError),
        axis=axis,
        sign=sign,
        translation=translation,
        rotation=rotation,
        limits=_limits(jd, where),
        mass_kg=fields.number(jd.get("mass_kg", 0.0), f"{where}.mass_kg", ChainError),
        com=fields.vector(jd.get("com_mm", [0, 0, 0]), f"{where}.com_mm", ChainError),
    )


def chain_from_dict(doc: dict, source: str = "robot") -> Chain:
    """Build a chain from the YAML schema of configs/robots/*.yaml (units mm and deg): a `joints` list, or a `dh`
    table (calib.model.dh: standard or modified DH with theta offsets and joint signs)."""
    if not isinstance(doc, dict) or ("joints" not in doc and "dh" not in doc):
        raise ChainError(f"{source}: a robot needs a 'joints' list or a 'dh' table")
    if "joints" in doc and "dh" in doc:
        raise ChainError(f"{source}: give either 'joints' or 'dh', not both")
    base_doc = fields.mapping(doc.get("base") or {}, f"{source}: base", ChainError)

    def vec3(d: dict, key: str, where: str) -> np.ndarray:
        return fields.vector(d.get(key, [0, 0, 0]), f"{where}.{key}", ChainError)

    base = homogeneous(
        rpy_matrix(*np.radians(vec3(base_doc, "rpy_deg", f"{source}: base"))),
        vec3(base_doc, "translation_mm", f"{source}: base"),
    )
    joints = []
    if "dh" in doc:
        dh_base, rows = dh_joints(doc["dh"], f"{source}: dh", ChainError)
        base = base @ dh_base
        for k, jd in enumerate(rows):
            joints.append(_joint(jd, k, f"{source}: dh.rows[{k}]", 2, jd["sign"], jd["translation"], jd["rotation"]))
    else:
        for k, jd in enumerate(fields.sequence(doc["joints"], f"{source}: joints", ChainError)):
            where = f"{source}: joints[{k}]"
            if not isinstance(jd, dict) or "axis" not in jd:
                raise ChainError(f"{where}: needs at least 'axis'")
            axis, sign = _parse_axis(jd["axis"], where)
            rotation = rpy_matrix(*np.radians(vec3(jd, "link_rpy_deg", where)))
            joints.append(_joint(jd, k, where, axis, sign, vec3(jd, "link_mm", where), rotation))
    if not joints:
        raise ChainError(f"{source}: joints: the chain has no joints")
    name = fields.text(doc.get("name", source), f"{source}: name", ChainError)
    return Chain(name=name, base=base, joints=tuple(joints))


def _urdf_model(path: str, xml: str | None = None):
    """pinocchio's model of a URDF file (`xml`: its text when the caller holds it, `path` then only names it). Its
    parser (urdfdom) reports problems on the C stdout/stderr, which no Python redirection reaches: file descriptors
    1 and 2 point at a temporary file during the load, and its first line goes into the one-line error."""
    import pinocchio as pin  # lazy: pinocchio costs ~0.5 s at start-up and only URDF robots need it

    if xml is None and not Path(path).is_file():
        raise ChainError(f"{path}: no such file")
    try:
        n = len(_URDF_JOINT.findall(Path(path).read_bytes() if xml is None else xml.encode()))
    except OSError as exc:
        raise ChainError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if n > MAX_URDF_JOINTS:
        raise ChainError(
            f"{path}: {n} joints, more than the {MAX_URDF_JOINTS} a robot's URDF has (a serial arm: 6 or "
            "7, with its tool and sensor frames a few dozen)"
        )
    with tempfile.TemporaryFile() as sink:
        sys.stdout.flush()
        sys.stderr.flush()
        saved = [os.dup(1), os.dup(2)]
        try:
            os.dup2(sink.fileno(), 1)
            os.dup2(sink.fileno(), 2)
            try:
                return pin.buildModelFromUrdf(str(path)) if xml is None else pin.buildModelFromXML(xml)
            except Exception as exc:  # pinocchio raises ValueError / RuntimeError with its own text
                failure = str(exc)
        finally:
            for fd, copy in ((1, saved[0]), (2, saved[1])):
                os.dup2(copy, fd)
                os.close(copy)
        sink.seek(0)
        said = next((line.strip() for line in sink.read().decode(errors="replace").splitlines() if line.strip()), "")
    detail = said.removeprefix("Error:").strip() or failure
    raise ChainError(f"{path}: not a valid URDF ({detail})")


def chain_from_urdf(path: str, tip_joint: str | None = None, xml: str | None = None) -> Chain:
    """Load a serial chain of revolute joints from a URDF through pinocchio (metres -> mm).

    Joint i's placement in its parent joint frame becomes the link block of joint i-1 (translation
    and fixed rotation); the first placement is the base transform; the last joint's link block is the placement of
    the fixed joint FLANGE_JOINT when the URDF has one on the last joint (a URDF trackcal wrote), else none.
    Inertias give the mass model. `xml`: the URDF's text when the caller holds it (`path` then names it).
    """
    model = _urdf_model(path, xml)
    names = list(model.names)[1:]
    if not names:
        raise ChainError(f"{path}: the URDF has no movable joints")
    if tip_joint is not None and tip_joint not in names:
        raise ChainError(f"{path}: no joint {tip_joint!r} (joints: {', '.join(names)})")
    last = len(names) if tip_joint is None else names.index(tip_joint) + 1
    axes = []
    for i in range(1, last + 1):
        jm = model.joints[i]
        short = jm.shortname()
        if short in ("JointModelRX", "JointModelRY", "JointModelRZ"):
            axes.append((AXIS_INDEX[short[-1].lower()], 1.0, None))
        elif short == "JointModelRevoluteUnaligned":
            a = np.asarray(jm.extract().axis, dtype=float)
            k = int(np.argmax(np.abs(a)))
            if abs(abs(a[k]) - 1.0) > 1e-12:  # an axis in any direction: z of a frame turned onto it
                axes.append((2, 1.0, turning(np.eye(3)[2], a)))
            else:
                axes.append((k, float(np.sign(a[k])), None))
        else:
            raise ChainError(f"{path}: joint {names[i - 1]} is {short}; only revolute joints are supported")
        if model.parents[i] != i - 1:
            raise ChainError(f"{path}: joint {names[i - 1]} is not in a serial chain")
    # (rotation, translation mm) from each joint's frame to the next: the URDF's placements, then the flange
    steps = [
        (np.asarray(model.jointPlacements[i].rotation), 1000.0 * np.asarray(model.jointPlacements[i].translation))
        for i in range(1, last + 1)
    ]
    if model.existFrame(FLANGE_JOINT) and model.frames[model.getFrameId(FLANGE_JOINT)].parentJoint == last:
        flange = model.frames[model.getFrameId(FLANGE_JOINT)].placement
        steps.append((np.asarray(flange.rotation), 1000.0 * np.asarray(flange.translation)))
    steps += [(np.eye(3), np.zeros(3))] * (last + 1 - len(steps))
    # a joint about an unaligned axis a turns about z of its frame turned by C (C z = a): the step into it ends
    # with C, the step out of it starts with C^T, and its mass model is seen in the turned frame
    turn = [np.eye(3) if ax[2] is None else ax[2] for ax in axes] + [np.eye(3)]
    steps = [(r @ turn[i], t) for i, (r, t) in enumerate(steps)]
    steps = [steps[0]] + [(turn[i].T @ r, turn[i].T @ t) for i, (r, t) in enumerate(steps[1:])]
    base = homogeneous(*steps[0])
    joints = []
    for j in range(last):
        lo, hi = model.lowerPositionLimit[j], model.upperPositionLimit[j]
        inertia = model.inertias[j + 1]
        joints.append(
            Joint(
                name=names[j],
                axis=axes[j][0],
                sign=axes[j][1],
                translation=steps[j + 1][1],
                rotation=steps[j + 1][0],
                limits=(float(lo), float(hi)) if np.isfinite(lo) and np.isfinite(hi) and lo < hi else None,
                mass_kg=float(inertia.mass),
                com=turn[j].T @ (1000.0 * np.asarray(inertia.lever)),
            )
        )
    return Chain(name=str(model.name), base=base, joints=tuple(joints))


# ---------------------------------------------------------------- back to the YAML schema of configs/robots
def _rpy_deg(r: np.ndarray) -> list[float]:
    """URDF rpy (R = Rz(y) Ry(p) Rx(r)) of a rotation matrix, deg."""
    return [float(np.degrees(v)) for v in rpy_of(r)]


def chain_to_dict(chain: Chain) -> dict:
    joints = []
    for jt in chain.joints:
        jd = {
            "name": jt.name,
            "axis": ("-" if jt.sign < 0 else "") + AXIS_NAME[jt.axis],
            "link_mm": [float(v) for v in jt.translation],
        }
        if not np.allclose(jt.rotation, np.eye(3)):
            jd["link_rpy_deg"] = _rpy_deg(jt.rotation)
        if jt.limits is not None:
            jd["limits_deg"] = [float(np.degrees(v)) for v in jt.limits]
        if jt.mass_kg:
            jd["mass_kg"] = jt.mass_kg
            jd["com_mm"] = [float(v) for v in jt.com]
        joints.append(jd)
    return {
        "name": chain.name,
        "base": {"translation_mm": [float(v) for v in chain.base[:3, 3]], "rpy_deg": _rpy_deg(chain.base[:3, :3])},
        "joints": joints,
    }
