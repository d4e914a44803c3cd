"""The real cell: the clients its hardware config (campaign/cells/hardware_config.py) describes.

hw = load_hardware("configs/hardware/example-cell.yaml")   # cells.hardware_config: validated
clients = claim_cell(hw, cell)                             # built, the robot's ports bound: the cell is ours
live = connect_hardware(clients, say, operator)            # engine.Live with every device connected
"""

from __future__ import annotations

import errno
from collections.abc import Callable
from dataclasses import dataclass

from trackcal.calib.model.cell import Cell
from trackcal.campaign.cells.checks import cell_box_check, joint_limits_deg, motion_guard
from trackcal.campaign.cells.hardware_config import Hardware
from trackcal.campaign.cells.operator import PlcOperator
from trackcal.campaign.engine.engine import Live
from trackcal.campaign.errors import InputError
from trackcal.drivers.emscon.client import EmsconTracker
from trackcal.drivers.errors import DeviceError
from trackcal.drivers.interfaces import Operator, RealClock, Robot
from trackcal.drivers.meteo.client import SerialMeteo
from trackcal.drivers.plc.client import ModbusCellIO


@dataclass
class CellClients:
    """The clients of a hardware config, built (no I/O) with the robot's EKI and RSI ports bound (claim_cell)."""

    hw: Hardware
    tracker: EmsconTracker
    robot: Robot
    cellio: ModbusCellIO | None
    meteo: SerialMeteo | None


def claim_cell(hw: Hardware, cell: Cell) -> CellClients:
    """Build the clients of `hw` and let the robot's family claim its channel, touching no device (the KR C2's:
    bind the EKI and RSI ports the controller connects to, so a second campaign on this PC finds them in use and is
    refused here, an InputError naming the reason, before it touches the tracker, the PLC or the meteo sensor of
    the running one)."""
    family = hw.family
    if cell.chain.dof != family.dof:
        raise InputError(
            f"{hw.path}: the {family.title} drives {family.dof} axes, robot {cell.chain.name} of cell "
            f"{cell.name} has {cell.chain.dof}"
        )
    t, r, p, m = hw.tracker, hw.robot, hw.plc, hw.meteo
    # with trackcal's own meteo sensor the tracker takes the environment trackcal sets; without one, its own
    # weather monitor reads it and computes the refraction (drivers.emscon.client: weather_monitor)
    weather_monitor = "not_connected" if m is not None else "read_and_calculate_refractions"
    tracker = EmsconTracker(
        t["host"],
        t["port"],
        timeout_s=t["timeout_s"],
        measure_timeout_s=t["measure_timeout_s"],
        motion_timeout_s=t["motion_timeout_s"],
        search_timeout_s=t["search_timeout_s"],
        samples_per_second=t["samples_per_second"],
        weather_monitor=weather_monitor,
    )
    cellio = None if p is None else ModbusCellIO(p["host"], p["port"], unit_id=p["unit_id"], timeout_s=p["timeout_s"])
    meteo = None if m is None else SerialMeteo(m["port"], baudrate=m["baudrate"], timeout_s=m["timeout_s"])
    robot = family.build(
        r,
        joint_limits_deg=joint_limits_deg(cell),
        cell_box_check=cell_box_check(cell),
        motion_guard=None if cellio is None else motion_guard(cellio),
    )
    try:
        if family.claim is not None:
            family.claim(robot)
    except DeviceError as exc:
        robot.close()
        cause = exc.__cause__
        if isinstance(cause, OSError) and cause.errno == errno.EADDRINUSE:
            raise InputError(
                f"{hw.path}: the cell is busy: another trackcal campaign holds its robot ports ({exc})"
            ) from None
        # any other failure (an address not on this PC) is the robot's connection error in connect_hardware,
        # in the order of the devices, once the session exists for `trackcal resume`
    return CellClients(hw, tracker, robot, cellio, meteo)


def connect_hardware(clients: CellClients, say: Callable[[str], None], console_operator: Operator) -> Live:
    """The claimed clients (claim_cell), connected, as an engine.Live (operator: PlcOperator with a PLC, else
    `console_operator`; clock: the real one). `say` shows a line as it is to whoever runs the campaign. A
    device that cannot be reached is a InputError naming it, its host and port; whatever was connected before
    is closed again, the robot's ports with it."""
    hw, tracker, robot, cellio, meteo = clients.hw, clients.tracker, clients.robot, clients.cellio, clients.meteo
    t, r, p, m = hw.tracker, hw.robot, hw.plc, hw.meteo
    opened: list = [robot]

    def close() -> None:
        for dev in reversed(opened):
            try:
                dev.close()
            except Exception as exc:  # one failing close never keeps the others open
                say(f"warning: closing {getattr(dev, 'device', dev)}: {exc}")
        opened.clear()

    def up(what: str, dev, where: str):
        if dev not in opened:
            opened.append(dev)
        try:
            dev.connect()
        except DeviceError as exc:
            close()
            raise InputError(f"{hw.path}: cannot connect the {what} ({where}): {exc}") from None
        except BaseException:  # Ctrl-C while waiting for the controller, a bug: nothing stays open
            close()
            raise
        return dev

    up("tracker", tracker, f"emScon {t['host']}:{t['port']}")
    if cellio is not None:
        up("cell PLC", cellio, f"Modbus TCP {p['host']}:{p['port']} unit {p['unit_id']}")
    if meteo is not None:
        up("meteo sensor", meteo, f"serial {m['port']}")
    say(hw.family.waiting(r))
    up("robot controller", robot, hw.family.where(r))
    operator = PlcOperator(cellio, say, poll_s=p["poll_s"]) if cellio is not None else console_operator
    return Live(tracker, robot, operator, RealClock(), cellio, meteo, close=close)
