"""A UR arm's own (factory) calibration: the calibrated DH table the controller computes its kinematics with.

Two sources, both giving standard DH (link i: Rz(theta_i + q_i) Tz(d_i) Tx(a_i) Rx(alpha_i); metres, radians):
- the controller's calibration file, /root/.urcontrol/calibration.conf: an INI file whose `[mounting]` section holds
  `delta_theta`, `delta_a`, `delta_d`, `delta_alpha` as lists of 6 numbers (a `#` starts a comment), the
  deviations from the model's published nominal table (Universal Robots' DH page) that the factory calibration
  found; read with configparser as public tools do (e.g. UR "dry-parse" FK scripts built on the same keys);
- the primary client interface (port 30001): the robot state message (type 16) carries the sub-package
  KINEMATICS_INFO (type 5): 6 x uint32 checksum, then dh_theta, dh_a, dh_d, dh_alpha as 6 big-endian doubles each
  (the calibrated table itself, nominal + delta), then uint32 calibration_status (Universal Robots "Client
  Interface" document; ur_client_library primary/robot_state/kinematics_info.cpp parses the same layout, and its
  ur_calibration package builds the calibrated URDF from it).
Units at this module's boundary: millimetres and radians (a, d in mm), as calib.model.dh.dh_chain takes them.
"""

from __future__ import annotations

import ast
import configparser
import socket
import struct
import time
from dataclasses import dataclass
from pathlib import Path

from trackcal.drivers.errors import ConnectionLost, DeviceTimeout, ProtocolError

PRIMARY_PORT = 30001
ROBOT_STATE, KINEMATICS_INFO = 16, 5
KEYS = ("delta_theta", "delta_a", "delta_d", "delta_alpha")


@dataclass(frozen=True)
class DhTable:
    """A standard DH table: theta offsets and alpha in rad, a and d in mm; `source` says where it came from."""

    theta: tuple[float, ...]
    a_mm: tuple[float, ...]
    d_mm: tuple[float, ...]
    alpha: tuple[float, ...]
    source: str = ""

    def plus(self, delta: DhTable, source: str) -> DhTable:
        """This table with `delta` added term by term (the nominal table and a calibration's deltas)."""
        add = [
            tuple(x + y for x, y in zip(u, v, strict=True))
            for u, v in (
                (self.theta, delta.theta),
                (self.a_mm, delta.a_mm),
                (self.d_mm, delta.d_mm),
                (self.alpha, delta.alpha),
            )
        ]
        return DhTable(*add, source=source)


def read_calibration_conf(path: str | Path, dof: int = 6) -> DhTable:
    """The deltas of a calibration.conf's [mounting] section (ProtocolError naming the file and key if malformed)."""
    parser = configparser.ConfigParser(strict=False, inline_comment_prefixes=("#",))
    try:
        parser.read_string(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, configparser.Error) as exc:
        raise ProtocolError(f"{path}: not a readable calibration.conf ({exc})") from None
    if "mounting" not in parser:
        raise ProtocolError(f"{path}: no [mounting] section (the factory calibration's deltas live there)")
    values = []
    for key in KEYS:
        text = parser["mounting"].get(key)
        try:
            v = ast.literal_eval(text) if text is not None else None
            row = tuple(float(x) for x in v)  # type: ignore[union-attr]
        except (ValueError, SyntaxError, TypeError):
            raise ProtocolError(f"{path}: mounting.{key}: expected a list of {dof} numbers, got {text!r}") from None
        if len(row) != dof:
            raise ProtocolError(f"{path}: mounting.{key}: expected {dof} numbers, got {len(row)}")
        values.append(row)
    theta, a, d, alpha = values
    return DhTable(theta, tuple(1000.0 * x for x in a), tuple(1000.0 * x for x in d), alpha, source=str(path))


def parse_kinematics_info(body: bytes) -> DhTable:
    """The calibrated table of a KINEMATICS_INFO sub-package's body (after its int32 length and uint8 type)."""
    if len(body) < 24 + 4 * 48:
        raise ProtocolError(f"KINEMATICS_INFO of {len(body)} bytes: too short")
    rows = [struct.unpack_from(">6d", body, 24 + 48 * i) for i in range(4)]
    theta, a, d, alpha = rows
    return DhTable(theta, tuple(1000.0 * x for x in a), tuple(1000.0 * x for x in d), alpha, source="KINEMATICS_INFO")


def read_kinematics_info(host: str, port: int = PRIMARY_PORT, timeout_s: float = 5.0) -> DhTable:
    """Connect to the primary interface of the controller at `host` and return the first KINEMATICS_INFO it sends."""
    deadline = time.monotonic() + timeout_s
    where = f"UR {host}:{port}"
    try:
        with socket.create_connection((host, port), timeout=timeout_s) as s:
            buf = b""
            while time.monotonic() < deadline:
                while len(buf) >= 5:
                    (length, kind) = struct.unpack_from(">iB", buf)
                    if length < 5:
                        raise ProtocolError(f"message length {length}", device=where)
                    if len(buf) < length:
                        break
                    msg, buf = buf[:length], buf[length:]
                    if kind == ROBOT_STATE:
                        pos = 5
                        while pos + 5 <= len(msg):
                            (sub_len, sub_kind) = struct.unpack_from(">iB", msg, pos)
                            if sub_len < 5:
                                raise ProtocolError(f"sub-package length {sub_len}", device=where)
                            if sub_kind == KINEMATICS_INFO:
                                table = parse_kinematics_info(msg[pos + 5 : pos + sub_len])
                                return DhTable(
                                    table.theta,
                                    table.a_mm,
                                    table.d_mm,
                                    table.alpha,
                                    source=f"KINEMATICS_INFO of {host}",
                                )
                            pos += sub_len
                s.settimeout(max(0.01, deadline - time.monotonic()))
                data = s.recv(65536)
                if not data:
                    raise ConnectionLost("the primary interface closed the connection", device=where)
                buf += data
    except TimeoutError:  # the deadline passed inside recv: the same answer as a loop that ran out of time
        raise DeviceTimeout(f"no KINEMATICS_INFO within {timeout_s:g} s", device=where) from None
    except OSError as exc:
        raise ConnectionLost(f"primary interface: {exc.strerror or exc}", device=where) from None
    raise DeviceTimeout(f"no KINEMATICS_INFO within {timeout_s:g} s", device=where)
