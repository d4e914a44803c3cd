"""The real cell: the hardware config (configs/hardware/README.md) and the clients it describes.

    hw = load_hardware("configs/hardware/example-cell.yaml")   # validated; InputError names file and key
    clients = claim_cell(hw, cell)                             # built, the robot's ports bound: the cell is ours
    live = connect_hardware(clients, say, operator)            # engine.Live with every device connected

The keys are the parameter names of the driver constructors (drivers.emscon.client.EmsconTracker,
drivers.plc.client.ModbusCellIO, drivers.meteo.client.SerialMeteo) and the defaults are theirs; the robot section's
`protocol` names the robot family (drivers/families.py: one `family` module per controller's driver package), which
gives the section's other keys and builds the client.
"""

from __future__ import annotations

import datetime
import difflib
import errno
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from trackcal.calib.io.files import read_yaml
from trackcal.calib.model.cell import Cell
from trackcal.campaign.cells.checks import cell_box_check, joint_limits_deg, motion_guard
from trackcal.campaign.cells.operator import PlcOperator
from trackcal.campaign.engine.engine import Live
from trackcal.campaign.errors import InputError
from trackcal.drivers.emscon.client import EmsconTracker
from trackcal.drivers.errors import DeviceError
from trackcal.drivers.families import RobotFamily, families
from trackcal.drivers.interfaces import Operator, RealClock, Robot
from trackcal.drivers.meteo.client import SerialMeteo
from trackcal.drivers.plc.client import ModbusCellIO

# section -> key -> (kind, default[, most]); `...` marks a required key. port: integer 1..65535, unit: 0..255,
# timeout / positive: a number > 0 (seconds / per second) and at most `most` if given, host: name or address, device:
# serial path or URL.
_REQUIRED = ...
SCHEMA: dict[str, dict[str, tuple[str, Any]]] = {
    "tracker": {
        "protocol": ("protocol", _REQUIRED),
        "host": ("host", _REQUIRED),
        "port": ("port", 700),  # emScon TPI default (drivers.emscon.client.DEFAULT_PORT)
        "timeout_s": ("timeout", 5.0),
        "measure_timeout_s": ("timeout", 60.0),
        "motion_timeout_s": ("timeout", 120.0),
        "search_timeout_s": ("timeout", 10.0),
        "samples_per_second": ("positive", 1000.0),
        # traceability (#39): the tracker's serial number and its calibration certificate, its date and due date, for
        # the ISO 9283 report; a certificate past its due date at the test is refused for a report unless asked
        "serial": ("text", None),
        "certificate": ("text", None),
        "certificate_date": ("date", None),
        "certificate_due": ("date", None),
        # the tracker's MPE as its certificate or datasheet states it, A um + B um/m of range (ASME B89.4.19), for the
        # ISO 9283 plan's field check (default: the cell's tracker model's datasheet MPE)
        "mpe_um": ("positive", None),
        "mpe_um_per_m": ("positive", None),
    },
    "plc": {
        "protocol": ("protocol", _REQUIRED),
        "host": ("host", _REQUIRED),
        "port": ("port", 502),
        "unit_id": ("unit", 1),
        "timeout_s": ("timeout", 1.0),
        "poll_s": ("timeout", 0.1),  # how often the acknowledge button is read while a request is pending
    },
    "meteo": {
        "protocol": ("protocol", _REQUIRED),
        "port": ("device", _REQUIRED),
        "baudrate": ("baud", 9600),
        "timeout_s": ("timeout", 1.0),
    },
}
PROTOCOLS = {"tracker": ("emscon",), "plc": ("modbus",), "meteo": ("serial",)}
SECTIONS = ("tracker", "robot", "plc", "meteo")
OPTIONAL_SECTIONS = ("plc", "meteo")  # without a PLC the operator answers on the console


@dataclass(frozen=True)
class Hardware:
    """A validated hardware config: every section with every key (defaults filled in); plc / meteo may be None."""

    path: Path
    tracker: dict
    robot: dict
    plc: dict | None
    meteo: dict | None

    @property
    def family(self) -> RobotFamily:
        """The robot's family (drivers/families.py), named by robot.protocol."""
        return families()[self.robot["protocol"]]

    def describe(self) -> dict[str, str]:
        out = {
            "tracker": f"emScon {self.tracker['host']}:{self.tracker['port']}",
            "robot": self.family.describe(self.robot),
            "operator": (
                f"cell PLC {self.plc['host']}:{self.plc['port']} unit {self.plc['unit_id']}"
                if self.plc
                else "console (no PLC configured)"
            ),
        }
        if self.meteo:
            out["meteo"] = f"serial {self.meteo['port']} at {self.meteo['baudrate']} baud"
        return out


def load_hardware(path: str | Path, text: str | None = None) -> Hardware:
    """Read and validate a hardware config; every mistake is an InputError naming the file and the key.
    `text`: the file's content when the caller already read it."""
    path = Path(path)
    doc = read_yaml(path, InputError, text)
    _unknown(path, doc, SECTIONS, "")
    out: dict[str, dict | None] = {}
    for name in SECTIONS:
        if doc.get(name) is None:
            if name not in OPTIONAL_SECTIONS:
                raise InputError(f"{path}: {name}: missing (the {name} section is required)")
            out[name] = None
            continue
        out[name] = _robot(path, doc[name]) if name == "robot" else _section(path, name, doc[name], SCHEMA, PROTOCOLS)
    tracker = out["tracker"] or {}
    if (
        tracker.get("certificate_date")
        and tracker.get("certificate_due")
        and tracker["certificate_due"] < tracker["certificate_date"]
    ):
        raise InputError(
            f"{path}: tracker.certificate_due: {tracker['certificate_due']} is before its "
            f"certificate_date {tracker['certificate_date']}"
        )
    return Hardware(path, out["tracker"], out["robot"], out["plc"], out["meteo"])  # type: ignore[arg-type]


def _date(path: Path, where: str, v) -> str:
    """A calendar date, YYYY-MM-DD (YAML reads an unquoted one as a date), as its ISO text."""
    if isinstance(v, datetime.date) and not isinstance(v, datetime.datetime):
        return v.isoformat()
    try:
        return datetime.date.fromisoformat(str(v)).isoformat()
    except ValueError:
        raise InputError(f"{path}: {where}: expected a date YYYY-MM-DD, got {v!r}") from None


def _unknown(path: Path, doc: dict, known, where: str) -> None:
    for key in doc:
        if key not in known:
            near = difflib.get_close_matches(str(key), list(known), n=1)
            hint = f"did you mean {near[0]}?" if near else f"known keys: {', '.join(known)}"
            raise InputError(f"{path}: {where}{key}: unknown key ({hint})")


def _robot(path: Path, doc) -> dict:
    """The robot section, by the schema of the family its `protocol` names."""
    known = families()
    protocol = doc.get("protocol") if isinstance(doc, dict) else None
    if isinstance(doc, dict) and protocol is None:
        raise InputError(f"{path}: robot.protocol: missing (required: the robot family, one of {', '.join(known)})")
    if not isinstance(protocol, str) or protocol.lower() not in known:
        got = protocol if isinstance(doc, dict) else doc
        raise InputError(f"{path}: robot.protocol: unknown protocol {got!r} (supported: {', '.join(known)})")
    family = known[protocol.lower()]
    schemas = {"robot" + (f".{k}" if k else ""): v for k, v in family.schemas.items()}
    protocols = {"robot": tuple(known), **{f"robot.{k}": v for k, v in (family.protocols or {}).items()}}
    return _section(path, "robot", doc, schemas, protocols)


def _section(path: Path, name: str, doc, schemas: dict, protocols: dict) -> dict:
    schema = schemas[name]
    if not isinstance(doc, dict):
        raise InputError(f"{path}: {name}: expected a mapping of {', '.join(schema)}")
    _unknown(path, doc, schema, f"{name}.")
    out = {}
    for key, (kind, default, *most) in schema.items():  # most: a number's upper bound, if the driver has one
        where = f"{name}.{key}"
        if key not in doc or doc[key] is None:
            if default is _REQUIRED:
                raise InputError(f"{path}: {where}: missing (required)")
            if kind == "section" or (default is None and kind in ("text", "date", "positive")):  # left out: no key
                continue
            out[key] = default
            continue
        v = doc[key]
        if kind == "section":
            out[key] = _section(path, where, v, schemas, protocols)
        elif kind == "protocol":
            choices = protocols[name]
            if not isinstance(v, str) or v.lower() not in choices:
                raise InputError(f"{path}: {where}: unknown protocol {v!r} (supported: {', '.join(choices)})")
            out[key] = v.lower()
        elif kind in ("host", "device"):
            if not isinstance(v, str) or not v.strip() or any(c.isspace() for c in v.strip()):
                what = "a host name or IP address" if kind == "host" else "a serial device path or pyserial URL"
                raise InputError(f"{path}: {where}: expected {what}, got {v!r}")
            out[key] = v.strip()
        elif kind in ("port", "unit", "baud"):
            lo, hi = {"port": (1, 65535), "unit": (0, 255), "baud": (1, 10_000_000)}[kind]
            if not isinstance(v, int) or isinstance(v, bool):
                raise InputError(f"{path}: {where}: expected an integer in {lo}..{hi}, got {v!r}")
            if not lo <= v <= hi:
                raise InputError(f"{path}: {where}: {v} out of range {lo}..{hi}")
            out[key] = v
        elif kind == "text":  # a name with spaces (a controller's user name)
            if not isinstance(v, str) or not v.strip():
                raise InputError(f"{path}: {where}: expected a non-empty text, got {v!r}")
            out[key] = v
        elif kind == "bool":
            if not isinstance(v, bool):
                raise InputError(f"{path}: {where}: expected true or false, got {v!r}")
            out[key] = v
        elif kind == "text":
            if not isinstance(v, str | int) or isinstance(v, bool) or not str(v).strip():
                raise InputError(f"{path}: {where}: expected a non-empty text, got {v!r}")
            out[key] = str(v).strip()
        elif kind == "date":
            out[key] = _date(path, where, v)
        elif kind in ("timeout", "positive"):
            if not isinstance(v, int | float) or isinstance(v, bool) or not math.isfinite(v) or v <= 0:
                raise InputError(f"{path}: {where}: expected a positive number, got {v!r}")
            if most and v > most[0]:
                raise InputError(f"{path}: {where}: {v:g} is more than the driver takes ({most[0]:.6g})")
            out[key] = float(v)
    return out


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
