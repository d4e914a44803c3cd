"""The real cell's hardware config (configs/hardware/README.md): read and validated, each mistake an InputError naming
the file and the key. Light: no driver's client is imported (the ISO 9283 commands read a session's stated tracker
from its copy; campaign/cells/hardware.py builds and connects the clients).

    hw = load_hardware("configs/hardware/example-cell.yaml")   # validated; InputError names file and key

The keys are the parameter names of the driver constructors (drivers.emscon.client.EmsconTracker,
drivers.plc.client.ModbusCellIO, drivers.meteo.client.SerialMeteo) and the defaults are theirs; the robot section's
`protocol` names the robot family (drivers/families.py: one `family` module per controller's driver package), which
gives the section's other keys and builds the client.
"""

from __future__ import annotations

import datetime
import difflib
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from trackcal.calib.io.files import read_yaml
from trackcal.campaign.errors import InputError
from trackcal.drivers.families import RobotFamily, families

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
