"""Primary / secondary client interface (ports 30001 / 30002) messages the mock sends: the version message on
connect and robot state messages carrying KINEMATICS_INFO (the arm's calibrated DH).

Layout (Universal Robots "Client Interface" document; ur_client_library primary/primary_package.h,
primary/robot_message/version_message.cpp and primary/robot_state/kinematics_info.cpp): every message is int32
length (header included) + uint8 message type, big-endian. ROBOT_MESSAGE (20): uint64 timestamp, int8 source,
uint8 robot message type (VERSION = 3), then int8 project-name length, the name, uint8 major, uint8 minor, int32
bugfix, int32 build, the build date (rest). ROBOT_STATE (16): a sequence of sub-packages, each int32 length + uint8
type; KINEMATICS_INFO (5): 6 x uint32 checksum, 6 x double dh_theta, dh_a, dh_d, dh_alpha, uint32
calibration_status.
"""

from __future__ import annotations

import struct

from trackcal.mocks.servers.ur.kinematics import Calibration

ROBOT_STATE, ROBOT_MESSAGE = 16, 20
VERSION = 3
KINEMATICS_INFO = 5
SOURCE_CONTROLLER = -2  # message source of the controller (ur_client_library: the version message comes with -2)


def message(kind: int, body: bytes) -> bytes:
    return struct.pack(">iB", 5 + len(body), kind) + body


def version_message(version: tuple[int, ...], timestamp_us: int, build_date: str = "16-01-2024, 10:04:12") -> bytes:
    name = b"URControl"
    body = struct.pack(">QbB", timestamp_us, SOURCE_CONTROLLER, VERSION)
    body += struct.pack(">b", len(name)) + name
    body += struct.pack(">BBii", version[0], version[1], version[2], version[3]) + build_date.encode()
    return message(ROBOT_MESSAGE, body)


def kinematics_info(cal: Calibration) -> bytes:
    body = struct.pack(">6I", *cal.checksum)
    for values in (cal.dh_theta, cal.dh_a, cal.dh_d, cal.dh_alpha):
        body += struct.pack(">6d", *values)
    body += struct.pack(">I", cal.calibration_status)
    return struct.pack(">iB", 5 + len(body), KINEMATICS_INFO) + body


def robot_state(cal: Calibration) -> bytes:
    return message(ROBOT_STATE, kinematics_info(cal))


def parse_kinematics_info(data: bytes) -> Calibration:
    """The inverse of kinematics_info (a KINEMATICS_INFO sub-package, header included): for tests and readers."""
    length, kind = struct.unpack_from(">iB", data)
    if kind != KINEMATICS_INFO or length != 5 + 24 + 4 * 48 + 4:
        raise ValueError("not a KINEMATICS_INFO sub-package")
    checksum = struct.unpack_from(">6I", data, 5)
    vals = [struct.unpack_from(">6d", data, 29 + 48 * i) for i in range(4)]
    (status,) = struct.unpack_from(">I", data, 29 + 192)
    return Calibration(tuple(checksum), *vals, calibration_status=status)
