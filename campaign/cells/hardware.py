"""The real cell: the hardware config (configs/hardware/README.md) and the clients it describes.

    hw = load_hardware("configs/hardware/example-cell.yaml")   # validated; InputError names file and key
    clients = claim_cell(hw, cell)                             # built, the robot's ports bound: the cell is ours
    live = connect_hardware(clients, say, operator)            # engine.Live with every device connected

The keys are the parameter names of the driver constructors (drivers.emscon.client.EmsconTracker,
drivers.kuka.client.KukaKrc2, drivers.plc.client.ModbusCellIO, drivers.meteo.client.SerialMeteo) and the defaults are
theirs; only `host`/`port` are grouped per channel for the robot (`eki`, `rsi`), because trackcal listens there and
the controller connects.
"""

from __future__ import annotations

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
from trackcal.drivers.interfaces import Operator, RealClock
from trackcal.drivers.kuka.client import KukaKrc2
from trackcal.drivers.kuka.rsi_codec import KRC2_CYCLE_S
from trackcal.drivers.kuka.rsi_codec import SHIPPED as RSI_SHIPPED
from trackcal.drivers.meteo.client import SerialMeteo
from trackcal.drivers.plc.client import ModbusCellIO

# section -> key -> (kind, default); `...` marks a required key. port: integer 1..65535, unit: 0..255,
# timeout / positive: a number > 0 (seconds / per second), host: name or address, device: serial path or URL.
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
    },
    "robot": {
        "protocol": ("protocol", _REQUIRED),
        "controller_host": ("host", _REQUIRED),  # the only peer served on the EKI and RSI ports
        "eki": ("section", _REQUIRED),
        "rsi": ("section", _REQUIRED),
        "connect_timeout_s": ("timeout", 60.0),
        "move_timeout_s": ("timeout", 300.0),
        "io_timeout_s": ("timeout", 5.0),
        "rsi_stale_s": ("timeout", 1.0),
    },
    "robot.eki": {
        "host": ("host", _REQUIRED),  # this PC's address on the robot network: no listening on every interface
        "port": ("port", _REQUIRED),
    },
    "robot.rsi": {
        "protocol": ("protocol", RSI_SHIPPED.protocol),  # protocol and passive: configs/krc2/trackcal_rsi.xml's
        "passive": ("bool", RSI_SHIPPED.passive),
        "cycle_s": ("positive", KRC2_CYCLE_S),  # the controller's interpolation cycle: 12 ms KR C2, 4 ms KR C4
        "host": ("host", _REQUIRED),
        "port": ("port", _REQUIRED),
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
PROTOCOLS = {"tracker": ("emscon",), "robot": ("krc2",), "robot.rsi": ("tcp", "udp"), "plc": ("modbus",),
             "meteo": ("serial",)}  # fmt: skip
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

    def describe(self) -> dict[str, str]:
        r = self.robot
        out = {"tracker": f"emScon {self.tracker['host']}:{self.tracker['port']}",
               "robot": f"KR C2, listening for EKI on {r['eki']['host']}:{r['eki']['port']} and RSI "
                        f"{r['rsi']['protocol']} ({'passive' if r['rsi']['passive'] else 'answered'}, "
                        f"{r['rsi']['cycle_s'] * 1000:g} ms) on {r['rsi']['host']}:{r['rsi']['port']}",
               "operator": (f"cell PLC {self.plc['host']}:{self.plc['port']} unit {self.plc['unit_id']}"
                            if self.plc else "console (no PLC configured)")}  # fmt: skip
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
        out[name] = _section(path, name, doc[name])
    return Hardware(path, out["tracker"], out["robot"], out["plc"], out["meteo"])  # type: ignore[arg-type]


def _unknown(path: Path, doc: dict, known, where: str) -> None:
    for key in doc:
        if key not in known:
            near = difflib.get_close_matches(str(key), list(known), n=1)
            hint = f"did you mean {near[0]}?" if near else f"known keys: {', '.join(known)}"
            raise InputError(f"{path}: {where}{key}: unknown key ({hint})")


def _section(path: Path, name: str, doc) -> dict:
    schema = SCHEMA[name]
    if not isinstance(doc, dict):
        raise InputError(f"{path}: {name}: expected a mapping of {', '.join(schema)}")
    _unknown(path, doc, schema, f"{name}.")
    out = {}
    for key, (kind, default) in schema.items():
        where = f"{name}.{key}"
        if key not in doc or doc[key] is None:
            if default is _REQUIRED:
                raise InputError(f"{path}: {where}: missing (required)")
            if kind == "section":
                continue
            out[key] = default
            continue
        v = doc[key]
        if kind == "section":
            out[key] = _section(path, where, v)
        elif kind == "protocol":
            choices = PROTOCOLS[name]
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
        elif kind == "bool":
            if not isinstance(v, bool):
                raise InputError(f"{path}: {where}: expected true or false, got {v!r}")
            out[key] = v
        elif kind in ("timeout", "positive"):
            if not isinstance(v, int | float) or isinstance(v, bool) or not math.isfinite(v) or v <= 0:
                raise InputError(f"{path}: {where}: expected a positive number, got {v!r}")
            out[key] = float(v)
    return out


@dataclass
class CellClients:
    """The clients of a hardware config, built (no I/O) with the robot's EKI and RSI ports bound (claim_cell)."""

    hw: Hardware
    tracker: EmsconTracker
    robot: KukaKrc2
    cellio: ModbusCellIO | None
    meteo: SerialMeteo | None


def claim_cell(hw: Hardware, cell: Cell) -> CellClients:
    """Build the clients of `hw` and bind the robot's EKI and RSI ports, touching no device. The controller
    connects to those ports only (configs/krc2/XmlApiConfig.xml names one server IP and PORT), so the campaign
    holding them is the only one the cell serves: a second campaign on this PC finds the EKI port in use (a TCP
    port has one listener) and is refused here, an InputError naming the reason, before it touches the tracker,
    the PLC or the meteo sensor of the running one."""
    if cell.chain.dof != 6:
        raise InputError(f"{hw.path}: the KR C2 drives 6 axes, robot {cell.chain.name} of cell {cell.name} has "
                         f"{cell.chain.dof}")  # fmt: skip
    t, r, p, m = hw.tracker, hw.robot, hw.plc, hw.meteo
    # with trackcal's own meteo sensor the tracker takes the environment trackcal sets; without one, its own
    # weather monitor reads it and computes the refraction (drivers.emscon.client: weather_monitor)
    weather_monitor = "not_connected" if m is not None else "read_and_calculate_refractions"
    tracker = EmsconTracker(t["host"], t["port"], timeout_s=t["timeout_s"], measure_timeout_s=t["measure_timeout_s"],
                            motion_timeout_s=t["motion_timeout_s"], search_timeout_s=t["search_timeout_s"],
                            samples_per_second=t["samples_per_second"], weather_monitor=weather_monitor)  # fmt: skip
    cellio = None if p is None else ModbusCellIO(p["host"], p["port"], unit_id=p["unit_id"], timeout_s=p["timeout_s"])
    meteo = None if m is None else SerialMeteo(m["port"], baudrate=m["baudrate"], timeout_s=m["timeout_s"])
    eki, rsi = r["eki"], r["rsi"]
    robot = KukaKrc2(eki["host"], eki["port"], rsi["host"], rsi["port"], rsi_protocol=rsi["protocol"],
                     controller_host=r["controller_host"],
                     rsi_passive=rsi["passive"], rsi_cycle_s=rsi["cycle_s"],
                     joint_limits_deg=joint_limits_deg(cell), cell_box_check=cell_box_check(cell),
                     motion_guard=None if cellio is None else motion_guard(cellio),
                     connect_timeout_s=r["connect_timeout_s"], move_timeout_s=r["move_timeout_s"],
                     io_timeout_s=r["io_timeout_s"], rsi_stale_s=r["rsi_stale_s"])  # fmt: skip
    try:
        robot.listen()
    except DeviceError as exc:
        robot.close()
        cause = exc.__cause__
        if isinstance(cause, OSError) and cause.errno == errno.EADDRINUSE:
            raise InputError(f"{hw.path}: the cell is busy: another trackcal campaign holds its robot ports "
                             f"({exc})") from None  # fmt: skip
        # any other failure (an address not on this PC) is the robot's connection error in connect_hardware,
        # in the order of the devices, once the session exists for `trackcal resume`
    return CellClients(hw, tracker, robot, cellio, meteo)


def connect_hardware(clients: CellClients, say: Callable[[str], None], console_operator: Operator) -> Live:
    """The claimed clients (claim_cell), connected, as an engine.Live (operator: PlcOperator with a PLC, else
    `console_operator`; clock: the real one). `say` shows a line (rich markup) to whoever runs the campaign. A
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
                say(f"[yellow]warning[/]: closing {getattr(dev, 'device', dev)}: {exc}")
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
    eki, rsi = r["eki"], r["rsi"]
    where = (f"listening for EKI on {eki['host']}:{eki['port']}, RSI {rsi['protocol']} on {rsi['host']}:{rsi['port']}, "
             f"for the controller at {r['controller_host']} only")  # fmt: skip
    say(f"waiting up to {r['connect_timeout_s']:g} s for the KR C2 to connect ({where}; start "
                  "trackcal_eki on the controller)")  # fmt: skip
    up("robot controller", robot, where)
    operator = PlcOperator(cellio, say, poll_s=p["poll_s"]) if cellio is not None else console_operator
    return Live(tracker, robot, operator, RealClock(), cellio, meteo, close=close)
