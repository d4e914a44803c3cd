"""The Universal Robots family of the hardware file (`robot.protocol: ur`; drivers/families.py): the robot section's
keys are UrRtde's parameters. trackcal is the client here: it connects to the controller's address (`host`) on
the dashboard (29999), RTDE (30004) and script (30003) ports, and to nothing else."""

from __future__ import annotations

from trackcal.drivers.families import REQUIRED, RobotFamily
from trackcal.drivers.ur.calibration import read_calibration_conf, read_kinematics_info
from trackcal.drivers.ur.client import (
    AXES,
    MOVEJ_ACCELERATION_MAX_DEG_S2,
    MOVEJ_SPEED_MAX_DEG_S,
    RESOLUTION_DEG,
    UrRtde,
    divert_native_output,
)
from trackcal.drivers.ur.program import PROGRAM
from trackcal.drivers.ur.urscript_reader import read_urscript

SCHEMAS = {
    "": {
        "protocol": ("protocol", REQUIRED),
        "host": ("host", REQUIRED),  # the controller's address: the one peer trackcal connects to
        "connect_timeout_s": ("timeout", 30.0),
        "move_timeout_s": ("timeout", 300.0),
        "io_timeout_s": ("timeout", 5.0),
        "stale_s": ("timeout", 1.0),  # no RTDE frame for this long during a move: the stream is stale
        # at 100 % override; ur_rtde's moveJ default 1.05 rad/s, its most 3.14 rad/s
        "joint_speed_deg_s": ("positive", 60.0, MOVEJ_SPEED_MAX_DEG_S),
        "joint_acceleration_deg_s2": ("positive", 80.0, MOVEJ_ACCELERATION_MAX_DEG_S2),  # default 1.4 rad/s2, most 40
        "stop_deceleration_deg_s2": ("positive", 229.0),  # stopJ on the door: 4 rad/s2
        "target_tolerance_deg": ("positive", RESOLUTION_DEG),  # joints reported after a move vs its target
        "unlock_timeout_s": ("timeout", 10.0),  # the controller refuses an unlock until 5 s after the stop
    },
}


def build(r: dict, *, joint_limits_deg, cell_box_check, motion_guard) -> UrRtde:
    keys = [k for k in SCHEMAS[""] if k not in ("protocol", "host")]
    return UrRtde(
        r["host"],
        joint_limits_deg=joint_limits_deg,
        cell_box_check=cell_box_check,
        motion_guard=motion_guard,
        **{k: r[k] for k in keys},
    )


def where(r: dict) -> str:
    return f"Universal Robots controller at {r['host']}: dashboard 29999, RTDE 30004, script 30003"


def waiting(r: dict) -> str:
    return f"connecting to the UR controller at {r['host']} (up to {r['connect_timeout_s']:g} s; Remote Control on)"


def claim(robot: UrRtde) -> None:
    """This PC's claim on the controller (UrRtde.claim): a second campaign on the same arm is refused."""
    robot.claim()


def factory_table(conf: str | None = None, host: str | None = None) -> tuple:
    """calibration.conf's deltas (conf), or the primary interface's KINEMATICS_INFO of the controller at host."""
    if conf is not None:
        t = read_calibration_conf(conf)
        return t.theta, t.a_mm, t.d_mm, t.alpha, t.source, True
    t = read_kinematics_info(str(host))
    return t.theta, t.a_mm, t.d_mm, t.alpha, t.source, False


FAMILY = RobotFamily(
    name="ur",
    title="Universal Robots",
    dof=len(AXES),
    schemas=SCHEMAS,
    build=build,
    describe=where,
    where=where,
    waiting=waiting,
    claim=claim,
    factory_table=factory_table,
    native_output=divert_native_output,
    program=PROGRAM,
    readers={".script": read_urscript, ".urscript": read_urscript},
)
