"""The KR C2 family of the hardware file (`robot.protocol: krc2`; drivers/families.py): the robot section's keys are
KukaKrc2's parameters, host and port grouped per channel (`eki`, `rsi`), because trackcal listens there and the
controller connects (configs/hardware/README.md)."""

from __future__ import annotations

from trackcal.drivers.families import REQUIRED, RobotFamily
from trackcal.drivers.interfaces import FROM_HARDWARE_FILE, DeviceIdentity
from trackcal.drivers.kuka.client import KukaKrc2
from trackcal.drivers.kuka.eki_codec import AXES
from trackcal.drivers.kuka.krl_reader import read_krl
from trackcal.drivers.kuka.program import PROGRAM
from trackcal.drivers.kuka.rsi_codec import KRC2_CYCLE_S
from trackcal.drivers.kuka.rsi_codec import SHIPPED as RSI_SHIPPED

SCHEMAS = {
    "": {
        "protocol": ("protocol", REQUIRED),
        "controller_host": ("host", REQUIRED),  # the only peer served on the EKI and RSI ports
        "eki": ("section", REQUIRED),
        "rsi": ("section", REQUIRED),
        "connect_timeout_s": ("timeout", 60.0),
        "move_timeout_s": ("timeout", 300.0),
        "io_timeout_s": ("timeout", 5.0),
        "rsi_stale_s": ("timeout", 1.0),
        # the controller's identity for the certificate (#39): EKI and RSI offer no query of it (see KukaKrc2.identity)
        "serial": ("text", None),
        "software": ("text", None),
    },
    "eki": {
        "host": ("host", REQUIRED),  # this PC's address on the robot network: no listening on every interface
        "port": ("port", REQUIRED),
    },
    "rsi": {
        "protocol": ("protocol", RSI_SHIPPED.protocol),  # protocol and passive: configs/krc2/trackcal_rsi.xml's
        "passive": ("bool", RSI_SHIPPED.passive),
        "cycle_s": ("positive", KRC2_CYCLE_S),  # the controller's interpolation cycle: 12 ms KR C2, 4 ms KR C4
        "host": ("host", REQUIRED),
        "port": ("port", REQUIRED),
    },
}


def build(r: dict, *, joint_limits_deg, cell_box_check, motion_guard) -> KukaKrc2:
    eki, rsi = r["eki"], r["rsi"]
    return KukaKrc2(
        eki["host"],
        eki["port"],
        rsi["host"],
        rsi["port"],
        rsi_protocol=rsi["protocol"],
        controller_host=r["controller_host"],
        rsi_passive=rsi["passive"],
        rsi_cycle_s=rsi["cycle_s"],
        joint_limits_deg=joint_limits_deg,
        cell_box_check=cell_box_check,
        motion_guard=motion_guard,
        connect_timeout_s=r["connect_timeout_s"],
        move_timeout_s=r["move_timeout_s"],
        io_timeout_s=r["io_timeout_s"],
        rsi_stale_s=r["rsi_stale_s"],
        identity=stated_identity(r, "KUKA KR C2"),
    )


def stated_identity(r: dict, model: str) -> DeviceIdentity:
    """The controller's identity as the hardware file states it (robot.serial, robot.software)."""
    return DeviceIdentity(r.get("serial", ""), model, r.get("software", ""), FROM_HARDWARE_FILE)


def where(r: dict) -> str:
    eki, rsi = r["eki"], r["rsi"]
    return (
        f"listening for EKI on {eki['host']}:{eki['port']}, RSI {rsi['protocol']} on {rsi['host']}:{rsi['port']}, "
        f"for the controller at {r['controller_host']} only"
    )


def describe(r: dict) -> str:
    rsi = r["rsi"]
    return (
        f"KR C2, listening for EKI on {r['eki']['host']}:{r['eki']['port']} and RSI {rsi['protocol']} "
        f"({'passive' if rsi['passive'] else 'answered'}, {rsi['cycle_s'] * 1000:g} ms) on "
        f"{rsi['host']}:{rsi['port']}"
    )


def waiting(r: dict) -> str:
    return (
        f"waiting up to {r['connect_timeout_s']:g} s for the KR C2 to connect ({where(r)}; start trackcal_eki on "
        "the controller)"
    )


def claim(robot: KukaKrc2) -> None:
    """Bind the EKI and RSI ports: the controller connects to those only (configs/krc2/XmlApiConfig.xml names one
    server IP and PORT), so a second campaign on this PC finds the EKI port in use."""
    robot.listen()


FAMILY = RobotFamily(
    name="krc2",
    title="KR C2",
    dof=len(AXES),
    schemas=SCHEMAS,
    build=build,
    describe=describe,
    where=where,
    waiting=waiting,
    claim=claim,
    protocols={"rsi": ("tcp", "udp")},
    program=PROGRAM,
    readers={".src": read_krl},
)
