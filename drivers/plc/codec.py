"""The cell PLC's register map and the values that go in its registers (configs/hardware/cell-plc-registers.md):
pure functions and data, no I/O. The client (drivers.plc.client) and the mock PLC (mocks.servers.plc) share it.
"""

from __future__ import annotations

from dataclasses import dataclass

# Modbus exception codes (Modbus Application Protocol Specification V1.1b3, section 7).
MODBUS_EXCEPTIONS = {
    0x01: "ILLEGAL FUNCTION",
    0x02: "ILLEGAL DATA ADDRESS",
    0x03: "ILLEGAL DATA VALUE",
    0x04: "SERVER DEVICE FAILURE",
    0x05: "ACKNOWLEDGE",
    0x06: "SERVER DEVICE BUSY",
    0x08: "MEMORY PARITY ERROR",
    0x0A: "GATEWAY PATH UNAVAILABLE",
    0x0B: "GATEWAY TARGET DEVICE FAILED TO RESPOND",
}
# 01..03 say our request does not fit the PLC program (wrong register map): a protocol mismatch on our side.
REQUEST_MISMATCH_CODES = frozenset({0x01, 0x02, 0x03})

STATUS_RUN = 1 << 0
STATUS_ESTOP_OK = 1 << 1
STATUS_WATCHDOG_EXPIRED = 1 << 2

# The operator request shown on the cell HMI (configs/hardware/cell-plc-registers.md, "HMI request"):
# REQUEST_REGISTERS holding registers from PlcRegisterMap.request_hr: kind code, sequence number, then the
# target's name in ASCII, 2 characters per register (first character in the high byte), NUL-padded.
REQUEST_KINDS = {"move_reflector": 1, "change_station": 2, "resume": 3}  # 0: no request pending
REQUEST_KIND_NAMES = {code: kind for kind, code in REQUEST_KINDS.items()}
REQUEST_TARGET_CHARS = 16
REQUEST_REGISTERS = 2 + REQUEST_TARGET_CHARS // 2


@dataclass(frozen=True)
class PlcRegisterMap:
    """Where each signal lives (0-based PDU addresses). Defaults = configs/hardware/cell-plc-registers.md."""

    door_closed_di: int = 0  # discrete input, 1 = door closed and locked (safety switch)
    acknowledge_di: int = 1  # discrete input, 1 = operator acknowledge button pressed
    request_lamp_coil: int = 0  # coil, 1 = request lamp on
    heartbeat_hr: int = 0  # holding register, host heartbeat counter (PLC watchdog)
    request_hr: int = 1  # first of REQUEST_REGISTERS holding registers: the pending operator request (HMI)
    status_ir: int = 0  # input register, PLC status word (STATUS_* bits)
    map_version_ir: int = 1  # input register, map version implemented by the PLC (IR 1 in every version)
    map_version: int = 0x0100  # the version this map describes (major.minor in the high/low byte)

    def __post_init__(self) -> None:
        if self.request_hr <= self.heartbeat_hr < self.request_hr + REQUEST_REGISTERS:
            raise ValueError(
                f"heartbeat HR {self.heartbeat_hr} inside the operator request block "
                f"HR {self.request_hr}..{self.request_hr + REQUEST_REGISTERS - 1}"
            )


DEFAULT_REGISTER_MAP = PlcRegisterMap()


@dataclass(frozen=True)
class OperatorRequest:
    """What the HMI shows: `kind` None when no request is pending; `seq` changes with every new request."""

    kind: str | None
    seq: int
    target: str


def hmi_text(target: str) -> str:
    """What the HMI shows of a target's name: ASCII ('?' for any other character and for NUL), cut to
    REQUEST_TARGET_CHARS. Two names shown alike cannot be told apart at the cell (campaign.cells.checks refuses
    such a cell)."""
    return target.encode("ascii", errors="replace")[:REQUEST_TARGET_CHARS].replace(b"\0", b"?").decode("ascii")


def encode_request(kind: str | None, seq: int, target: str = "") -> list[int]:
    """The REQUEST_REGISTERS register values of a request (kind None: no request pending).

    The target is sent as `hmi_text` shows it: the HMI shows what fits; the full text is on the trackcal console."""
    if kind is not None and kind not in REQUEST_KINDS:
        raise ValueError(f"unknown operator request kind {kind!r} (known: {', '.join(REQUEST_KINDS)})")
    raw = (
        hmi_text(target).encode("ascii").ljust(REQUEST_TARGET_CHARS, b"\0")
        if kind is not None
        else bytes(REQUEST_TARGET_CHARS)
    )
    chars = [(raw[i] << 8) | raw[i + 1] for i in range(0, REQUEST_TARGET_CHARS, 2)]
    return [REQUEST_KINDS[kind] if kind is not None else 0, seq & 0xFFFF, *chars]


def decode_request(registers) -> OperatorRequest:
    """Inverse of encode_request; raises ValueError for an unknown kind code or a wrong register count."""
    regs = [int(v) for v in registers]
    if len(regs) != REQUEST_REGISTERS:
        raise ValueError(f"an operator request is {REQUEST_REGISTERS} registers, got {len(regs)}")
    code = regs[0]
    if code != 0 and code not in REQUEST_KIND_NAMES:
        raise ValueError(f"unknown operator request kind code {code}")
    raw = b"".join(bytes(((v >> 8) & 0xFF, v & 0xFF)) for v in regs[2:])
    target = raw.split(b"\0", 1)[0].decode("ascii", errors="replace")
    return OperatorRequest(REQUEST_KIND_NAMES.get(code), regs[1], target)


@dataclass(frozen=True)
class PlcStatus:
    running: bool
    estop_ok: bool
    watchdog_expired: bool
    raw: int

    @classmethod
    def from_word(cls, word: int) -> PlcStatus:
        return cls(
            running=bool(word & STATUS_RUN),
            estop_ok=bool(word & STATUS_ESTOP_OK),
            watchdog_expired=bool(word & STATUS_WATCHDOG_EXPIRED),
            raw=word,
        )
