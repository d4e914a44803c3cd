"""The KR C4 / KR C5 family of the hardware file (`robot.protocol: krc4`; drivers/families.py): KSS 8 with
EthernetKRL 3.x and RSI 4.x/5.x (drivers.krc4.client.KukaKrc4, configs/krc4). trackcal connects to the
controller's EKI server (`controller_host`, `eki.port`) and listens for its RSI stream (`rsi.host`, `rsi.port`,
UDP); the controller named is the only peer served. The compensated program is KRL written by the kuka family's
writer (drivers.kuka.program: PTP over E6AXIS data, the syntax KSS 8 loads as KSS 5 did); the KRL reader of program
filtering is registered once, by the kuka family."""

from __future__ import annotations

from trackcal.drivers.families import REQUIRED, RobotFamily
from trackcal.drivers.krc4.client import DEFAULT_EKI_PORT, KRC4_CYCLE_S, TITLE, KukaKrc4
from trackcal.drivers.krc4.configs import RSI
from trackcal.drivers.kuka.eki_codec import AXES
from trackcal.drivers.kuka.family import SCHEMAS as KRC2_SCHEMAS
from trackcal.drivers.kuka.family import stated_identity
from trackcal.drivers.kuka.program import PROGRAM

SCHEMAS = {
    "": KRC2_SCHEMAS[""],  # the KR C2's keys; controller_host: the EKI server trackcal connects to, the RSI peer
    "eki": {
        "port": ("port", DEFAULT_EKI_PORT),  # INTERNAL/PORT of configs/krc4/TrackcalEki.xml
    },
    "rsi": {
        "passive": ("bool", RSI.passive),  # ONLYSEND of configs/krc4/trackcal_rsi_ethernet.xml
        "cycle_s": ("positive", KRC4_CYCLE_S),  # IPO_FAST 4 ms, or 12 ms
        "host": ("host", REQUIRED),  # this PC's address on the RSI network (IP_NUMBER of the RSI file)
        "port": ("port", REQUIRED),
    },
}


def build(r: dict, *, joint_limits_deg, cell_box_check, motion_guard) -> KukaKrc4:
    rsi = r["rsi"]
    return KukaKrc4(
        r["eki"]["port"],
        rsi["host"],
        rsi["port"],
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
        identity=stated_identity(r, f"KUKA {TITLE}"),
    )


def where(r: dict) -> str:
    rsi = r["rsi"]
    return (
        f"EKI at {r['controller_host']}:{r['eki']['port']}, listening for RSI on {rsi['host']}:{rsi['port']} "
        "for that controller only"
    )


def describe(r: dict) -> str:
    rsi = r["rsi"]
    return (
        f"{TITLE}, EKI at {r['controller_host']}:{r['eki']['port']}, RSI udp "
        f"({'passive' if rsi['passive'] else 'answered'}, {rsi['cycle_s'] * 1000:g} ms) on "
        f"{rsi['host']}:{rsi['port']}"
    )


def waiting(r: dict) -> str:
    return f"waiting up to {r['connect_timeout_s']:g} s for the {TITLE} ({where(r)}; start trackcal_eki on it)"


def claim(robot: KukaKrc4) -> None:
    """Bind the RSI port: the controller streams to that one address (IP_NUMBER/PORT of its RSI file), so a
    second campaign on this PC finds it in use; the kernel releases it when the process dies, even on kill -9."""
    robot.listen()


FAMILY = RobotFamily(
    name="krc4",
    title=TITLE,
    dof=len(AXES),
    schemas=SCHEMAS,
    build=build,
    describe=describe,
    where=where,
    waiting=waiting,
    claim=claim,
    program=PROGRAM,
)
