"""The ABB family of the hardware file (`robot.protocol: abb`; drivers/families.py): an IRC5 controller with RobotWare
6, driven over Robot Web Services 1.0 (drivers.abb.rws) and the RAPID module TrackcalRws (drivers.abb.program).
trackcal is the client: it connects to the controller's address (`host`), HTTP port `port` (80 on the controller's
WAN port), and to nothing else."""

from __future__ import annotations

from trackcal.drivers.abb.client import AXES, AbbRws
from trackcal.drivers.abb.program import PROGRAM
from trackcal.drivers.abb.rapid_reader import read_rapid
from trackcal.drivers.abb.rws import DEFAULT_PASSWORD, DEFAULT_USER
from trackcal.drivers.families import REQUIRED, RobotFamily

SCHEMAS = {
    "": {
        "protocol": ("protocol", REQUIRED),
        "host": ("host", REQUIRED),  # the controller's address: the one peer trackcal connects to
        "port": ("port", 80),  # RWS's HTTP port (the Robot Web Services manual: port 80 of the WAN port)
        "user": ("text", DEFAULT_USER),
        "password": ("text", DEFAULT_PASSWORD),
        "connect_timeout_s": ("timeout", 30.0),
        "move_timeout_s": ("timeout", 300.0),
        "io_timeout_s": ("timeout", 5.0),
        "egm": ("section", None),  # optional: the EGM position stream as the joint monitor (drivers.abb.egm_link)
        "egm_stale_s": ("timeout", 1.0),  # no EGM frame for this long during a move or a settle: the stream is stale
    },
    "egm": {
        "host": ("host", REQUIRED),  # this PC's address on the robot network (the controller's EGM config names it)
        "port": ("port", REQUIRED),
    },
}


def build(r: dict, *, joint_limits_deg, cell_box_check, motion_guard) -> AbbRws:
    keys = [k for k in SCHEMAS[""] if k not in ("protocol", "host", "egm")]
    egm = (r["egm"]["host"], r["egm"]["port"]) if r.get("egm") else None
    return AbbRws(
        r["host"],
        joint_limits_deg=joint_limits_deg,
        cell_box_check=cell_box_check,
        motion_guard=motion_guard,
        egm=egm,
        **{k: r[k] for k in keys},
    )


def where(r: dict) -> str:
    egm = f", EGM to {r['egm']['host']}:{r['egm']['port']}" if r.get("egm") else ""
    return f"ABB controller at {r['host']}: Robot Web Services on port {r['port']}{egm}"


def waiting(r: dict) -> str:
    return (
        f"connecting to the ABB controller at {r['host']}:{r['port']} (up to {r['connect_timeout_s']:g} s; AUTO "
        "mode, TrackcalRws loaded in T_ROB1)"
    )


def claim(robot: AbbRws) -> None:
    """This PC's claim on the controller (AbbRws.claim): a second campaign on the same arm is refused."""
    robot.claim()


FAMILY = RobotFamily(
    name="abb",
    title="ABB",
    dof=len(AXES),
    schemas=SCHEMAS,
    build=build,
    describe=where,
    where=where,
    waiting=waiting,
    claim=claim,
    program=PROGRAM,
    readers={".mod": read_rapid, ".modx": read_rapid, ".prg": read_rapid},
)
