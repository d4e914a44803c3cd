"""RTDE framing and recipes, pure functions (no sockets): what the mock controller sends and parses on port 30004.

Sources (public):
- UniversalRobots/RTDE_Python_Client_Library rtde/rtde.py (command letters, protocol version 2, payload layouts of
  every request and answer) and rtde/serialize.py (the `>HB` header, the struct letter of every data type, the
  recipe answer: one byte recipe id then the comma-separated type names, IN_USE / NOT_FOUND).
- ur_rtde src/rtde.cpp (the client the mock must satisfy: it sends the protocol version as `>H`, the output
  frequency as a big-endian double before the names, names with a trailing comma, and reads every answer as
  header + body).
- Universal Robots, "Real-Time Data Exchange (RTDE) Guide" (universal-robots.com support article 22229): the
  variable names and types of the tables below, NOT_FOUND for an unknown name, IN_USE for an input another
  client holds, recipe id 0 for a refused recipe, frequency 1..125 Hz on a CB3 and 1..500 Hz on an e-Series.
"""

from __future__ import annotations

import re
import struct
from dataclasses import dataclass

HEADER = struct.Struct(">HB")  # size (header included), type: serialize.py ControlHeader.unpack
HEADER_SIZE = HEADER.size
MAX_PACKAGE = 0xFFFF  # the size field is a uint16

# rtde.py class Command
REQUEST_PROTOCOL_VERSION = 86  # 'V'
GET_URCONTROL_VERSION = 118  # 'v'
TEXT_MESSAGE = 77  # 'M'
DATA_PACKAGE = 85  # 'U'
CONTROL_PACKAGE_SETUP_OUTPUTS = 79  # 'O'
CONTROL_PACKAGE_SETUP_INPUTS = 73  # 'I'
CONTROL_PACKAGE_START = 83  # 'S'
CONTROL_PACKAGE_PAUSE = 80  # 'P'
COMMANDS = frozenset(
    {
        REQUEST_PROTOCOL_VERSION,
        GET_URCONTROL_VERSION,
        TEXT_MESSAGE,
        DATA_PACKAGE,
        CONTROL_PACKAGE_SETUP_OUTPUTS,
        CONTROL_PACKAGE_SETUP_INPUTS,
        CONTROL_PACKAGE_START,
        CONTROL_PACKAGE_PAUSE,
    }
)
PROTOCOL_VERSIONS = (1, 2)  # rtde.py RTDE_PROTOCOL_VERSION_1/2; the mock speaks 2 (v1 has no recipe id in data)

# Text message levels (serialize.py Message)
EXCEPTION_MESSAGE, ERROR_MESSAGE, WARNING_MESSAGE, INFO_MESSAGE = 0, 1, 2, 3

# struct letters of each type: serialize.py DataConfig.unpack_recipe
TYPE_FORMAT = {
    "BOOL": "?",
    "UINT8": "B",
    "UINT32": "I",
    "UINT64": "Q",
    "INT32": "i",
    "DOUBLE": "d",
    "VECTOR3D": "ddd",
    "VECTOR6D": "dddddd",
    "VECTOR6INT32": "iiiiii",
    "VECTOR6UINT32": "IIIIII",
}
NOT_FOUND, IN_USE = "NOT_FOUND", "IN_USE"

# Outputs of the RTDE guide (controller -> client), name: type.
OUTPUTS: dict[str, str] = {
    "timestamp": "DOUBLE",
    "target_q": "VECTOR6D",
    "target_qd": "VECTOR6D",
    "target_qdd": "VECTOR6D",
    "target_current": "VECTOR6D",
    "target_moment": "VECTOR6D",
    "actual_q": "VECTOR6D",
    "actual_qd": "VECTOR6D",
    "actual_current": "VECTOR6D",
    "actual_current_window": "VECTOR6D",
    "joint_control_output": "VECTOR6D",
    "actual_TCP_pose": "VECTOR6D",
    "actual_TCP_speed": "VECTOR6D",
    "actual_TCP_force": "VECTOR6D",
    "target_TCP_pose": "VECTOR6D",
    "target_TCP_speed": "VECTOR6D",
    "actual_digital_input_bits": "UINT64",
    "joint_temperatures": "VECTOR6D",
    "actual_execution_time": "DOUBLE",
    "robot_mode": "INT32",
    "joint_mode": "VECTOR6INT32",
    "safety_mode": "INT32",
    "safety_status": "INT32",
    "actual_tool_accelerometer": "VECTOR3D",
    "speed_scaling": "DOUBLE",
    "target_speed_fraction": "DOUBLE",
    "actual_momentum": "DOUBLE",
    "actual_main_voltage": "DOUBLE",
    "actual_robot_voltage": "DOUBLE",
    "actual_robot_current": "DOUBLE",
    "actual_joint_voltage": "VECTOR6D",
    "actual_digital_output_bits": "UINT64",
    "runtime_state": "UINT32",
    "elbow_position": "VECTOR3D",
    "elbow_velocity": "VECTOR3D",
    "robot_status_bits": "UINT32",
    "safety_status_bits": "UINT32",
    "analog_io_types": "UINT32",
    "standard_analog_input0": "DOUBLE",
    "standard_analog_input1": "DOUBLE",
    "standard_analog_output0": "DOUBLE",
    "standard_analog_output1": "DOUBLE",
    "io_current": "DOUBLE",
    "euromap67_input_bits": "UINT32",
    "euromap67_output_bits": "UINT32",
    "euromap67_24V_voltage": "DOUBLE",
    "euromap67_24V_current": "DOUBLE",
    "tool_mode": "UINT32",
    "tool_analog_input_types": "UINT32",
    "tool_analog_input0": "DOUBLE",
    "tool_analog_input1": "DOUBLE",
    "tool_output_voltage": "INT32",
    "tool_output_current": "DOUBLE",
    "tool_temperature": "DOUBLE",
    "tcp_force_scalar": "DOUBLE",
    "output_bit_registers0_to_31": "UINT32",
    "output_bit_registers32_to_63": "UINT32",
    "input_bit_registers0_to_31": "UINT32",
    "input_bit_registers32_to_63": "UINT32",
    "tool_output_mode": "UINT8",
    "tool_digital_output0_mode": "UINT8",
    "tool_digital_output1_mode": "UINT8",
    "payload": "DOUBLE",
    "payload_cog": "VECTOR3D",
    "payload_inertia": "VECTOR6D",
    "script_control_line": "UINT32",
    "ft_raw_wrench": "VECTOR6D",
    "joint_position_deviation_ratio": "DOUBLE",
    "collision_detection_ratio": "DOUBLE",
    "time_scale_source": "UINT32",
    "actual_current_as_torque": "VECTOR6D",
}
# Inputs of the RTDE guide (client -> controller), name: type.
INPUTS: dict[str, str] = {
    "speed_slider_mask": "UINT32",
    "speed_slider_fraction": "DOUBLE",
    "standard_digital_output_mask": "UINT8",
    "standard_digital_output": "UINT8",
    "configurable_digital_output_mask": "UINT8",
    "configurable_digital_output": "UINT8",
    "tool_digital_output_mask": "UINT8",
    "tool_digital_output": "UINT8",
    "standard_analog_output_mask": "UINT8",
    "standard_analog_output_type": "UINT8",
    "standard_analog_output_0": "DOUBLE",
    "standard_analog_output_1": "DOUBLE",
    "input_bit_registers0_to_31": "UINT32",
    "input_bit_registers32_to_63": "UINT32",
    "external_force_torque": "VECTOR6D",
    "ft_rtde_input_enable": "BOOL",
}
# Registers (guide: bit 64..127, int and double 0..47, each readable as output; the input ones also as input).
_REGISTER = re.compile(r"(input|output)_(bit|int|double)_register_(\d{1,3})\Z")
_REGISTER_TYPE = {"bit": "BOOL", "int": "INT32", "double": "DOUBLE"}
_REGISTER_RANGE = {"bit": range(64, 128), "int": range(48), "double": range(48)}


def register(name: str) -> tuple[str, str, int] | None:
    """('input'|'output', 'bit'|'int'|'double', index) of a register variable name, None for any other name."""
    m = _REGISTER.match(name)
    if m is None or str(int(m.group(3))) != m.group(3) or int(m.group(3)) not in _REGISTER_RANGE[m.group(2)]:
        return None
    return m.group(1), m.group(2), int(m.group(3))


def output_type(name: str) -> str:
    """Type of an output variable (every register, input or output, can be read), NOT_FOUND if there is none."""
    reg = register(name)
    if reg is not None:
        return _REGISTER_TYPE[reg[1]]
    return OUTPUTS.get(name, NOT_FOUND)


def input_type(name: str) -> str:
    """Type of an input variable (only input registers can be written), NOT_FOUND if there is none."""
    reg = register(name)
    if reg is not None:
        return _REGISTER_TYPE[reg[1]] if reg[0] == "input" else NOT_FOUND
    return INPUTS.get(name, NOT_FOUND)


class FrameError(ValueError):
    """A byte stream that is no RTDE: the real controller closes such a connection."""


def pack(command: int, payload: bytes = b"") -> bytes:
    size = HEADER_SIZE + len(payload)
    if size > MAX_PACKAGE:
        raise FrameError(f"package of {size} bytes exceeds the uint16 size field")
    return HEADER.pack(size, command) + payload


class Deframer:
    """Cuts a byte stream into (command, payload) packages (serialize.py ControlHeader: size counts the header)."""

    def __init__(self) -> None:
        self._buf = bytearray()

    def feed(self, data: bytes) -> list[tuple[int, bytes]]:
        self._buf += data
        out = []
        while len(self._buf) >= HEADER_SIZE:
            size, command = HEADER.unpack_from(self._buf)
            if size < HEADER_SIZE:
                raise FrameError(f"package size {size} is smaller than its header")
            if command not in COMMANDS:
                raise FrameError(f"unknown package type {command}")
            if len(self._buf) < size:
                break
            out.append((command, bytes(self._buf[HEADER_SIZE:size])))
            del self._buf[:size]
        return out


@dataclass(frozen=True)
class Recipe:
    id: int
    names: tuple[str, ...]
    types: tuple[str, ...]
    frequency: float = 0.0  # outputs only

    @property
    def valid(self) -> bool:
        return self.id != 0

    @property
    def struct(self) -> struct.Struct:
        return struct.Struct(">B" + "".join(TYPE_FORMAT[t] for t in self.types))

    def answer(self) -> bytes:
        """The controller's answer to a setup request: recipe id then the types (serialize.py unpack_recipe)."""
        return bytes([self.id]) + ",".join(self.types).encode()


def split_names(text: bytes) -> tuple[str, ...]:
    """Variable names of a setup request; ur_rtde ends the list with a comma (rtde.cpp sendInputSetup)."""
    try:
        names = text.decode("ascii").split(",")
    except UnicodeDecodeError as exc:
        raise FrameError("variable names are not ASCII") from exc
    if names and names[-1] == "":
        names.pop()
    return tuple(names)


def parse_output_setup(payload: bytes) -> tuple[float, tuple[str, ...]]:
    """Protocol 2 'O': frequency (big-endian double) then the names (rtde.py send_output_setup)."""
    if len(payload) < 8:
        raise FrameError("output setup shorter than its frequency")
    (frequency,) = struct.unpack_from(">d", payload)
    return frequency, split_names(payload[8:])


def pack_data(recipe: Recipe, values: dict[str, object]) -> bytes:
    """A 'U' package of an output recipe: recipe id then each variable (serialize.py DataConfig.pack)."""
    flat: list[object] = [recipe.id]
    for name, typ in zip(recipe.names, recipe.types, strict=True):
        v = values[name]
        if typ.startswith("VECTOR"):
            flat.extend(v)  # type: ignore[arg-type]
        else:
            flat.append(v)
    return pack(DATA_PACKAGE, recipe.struct.pack(*flat))


def unpack_data(recipe: Recipe, payload: bytes) -> dict[str, object]:
    """Values of an input 'U' package (payload after the header, recipe id included)."""
    st = recipe.struct
    if len(payload) != st.size:
        raise FrameError(f"data package of {len(payload)} bytes for recipe {recipe.id} of {st.size}")
    flat = st.unpack(payload)[1:]
    out, i = {}, 0
    for name, typ in zip(recipe.names, recipe.types, strict=True):
        n = len(TYPE_FORMAT[typ])
        out[name] = list(flat[i : i + n]) if typ.startswith("VECTOR") else flat[i]
        i += n
    return out


def pack_text(message: str, source: str, level: int) -> bytes:
    """Protocol 2 text message (serialize.py Message.unpack: length-prefixed message and source, then level)."""
    m, s = message.encode()[:255], source.encode()[:255]
    return pack(TEXT_MESSAGE, bytes([len(m)]) + m + bytes([len(s)]) + s + bytes([level]))


def pack_version(major: int, minor: int, bugfix: int, build: int) -> bytes:
    return pack(GET_URCONTROL_VERSION, struct.pack(">IIII", major, minor, bugfix, build))


def pack_success(command: int, ok: bool) -> bytes:
    return pack(command, bytes([1 if ok else 0]))
