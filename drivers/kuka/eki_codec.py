"""KUKA KR C2 "Ethernet KRL XML 1.2" (KRL API EKX_*) codec of trackcal's move/acknowledge exchange.

Pure functions, no I/O. trackcal -> robot (one XML document per send, angles in degrees, 4 decimals; Speed =
axis speed override in %):

    <RobotCommand ID="17" Speed="20"><Pos A1="0.0000" A2="-90.0000" A3="90.0000" A4="0.0000" A5="90.0000"
     A6="0.0000"/></RobotCommand>

robot -> trackcal, after PTP without approximation, WAIT SEC 0 (advance-run stop) and the dwell; Pos is
$AXIS_ACT at standstill, the echoed ID is the acknowledgement, Done/Error say how the command ended:

    <RobotState><Pos A1=".." A2=".." A3=".." A4=".." A5=".." A6=".."/>
     <RobotCommand ID="17" Done="1" Error="0"/></RobotState>

The element/attribute paths are listed once, in COMMAND_TAGS and STATE_TAGS, in the XPath notation of the EKI
configuration files ("Root/Elem/@Attr", KUKA.EthernetKRL 2.2 manual, sec. 6.1.4 "Configuration according to
the XPath schema", https://www.easymanua.ls/kuka/kuka-ethernetkrl-2-2/manual?p=27);
configs/krc2/TrackcalEki+.xml declares the same paths and tests/test_kuka_codecs.py checks that they agree.

What the KR C2 variant changes (ros-industrial/kuka_experimental issue #196, "kuka_eki_hw_interface for KRC2",
https://github.com/ros-industrial/kuka_experimental/issues/196): Ethernet KRL XML 1.2 names its functions
EKX_* instead of EKI_*, they return an INT instead of EKI_STATUS, there is no
EKI_Init/EKI_Clear/EKI_CheckBuffer, and the configuration is split into NAME.xml, NAME+.xml and
XmlApiConfig.xml; the EKX_Get*Element functions take a first INT parameter choosing FIFO (0) or "current
value" (1). The controller is the TCP client, trackcal the server.

Safety of the XML parsing (every parser here and in drivers.kuka.rsi_codec goes through `parse_document`):
- a size cap per document (MAX_DOC_BYTES) before anything is parsed;
- any markup declaration "<!" (DOCTYPE, ENTITY, comments, CDATA) is refused outright, so no entity can be
  defined: no XXE, no "billion laughs" (Python docs, "XML vulnerabilities": xml.etree does not fetch external
  entities but expands internal ones; refusing the DOCTYPE removes both);
- every failure of the stdlib parser becomes drivers.errors.ProtocolError; nothing else escapes.
"""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass

from drivers.errors import ProtocolError

AXES = ("A1", "A2", "A3", "A4", "A5", "A6")
COMMAND_ROOT = "RobotCommand"
STATE_ROOT = "RobotState"
MAX_DOC_BYTES = 4096  # a command or a state is ~250 bytes; the cap bounds parsing time and memory
MAX_ID = 2**31 - 1  # a KRL INT is a 32-bit signed integer
ANGLE_LIMIT_DEG = (
    10_000.0  # plausibility bound on the wire (KRL axis values are a few hundred degrees at most)
)

# Error codes of RobotState/RobotCommand/@Error, set by configs/krc2/trackcal_eki.src.
ERR_NONE = 0
ERR_ESTOP = 1  # $STOPMESS with an emergency stop active
ERR_DRIVES_OFF = 2  # drives not ready ($PERI_RDY false)
ERR_SOFT_LIMIT = 3  # target outside $SOFTN_END/$SOFTP_END, or a software limit switch reached
ERR_RSI_STOPPED = 4  # the RSI monitor stopped the robot (more than eERXmaxLatePackages late answers)
ERR_BAD_COMMAND = 5  # the command could not be read (missing element, speed out of range)
ERROR_TEXT = {
    ERR_ESTOP: "emergency stop",
    ERR_DRIVES_OFF: "drives off",
    ERR_SOFT_LIMIT: "software limit switch / target outside the axis limits",
    ERR_RSI_STOPPED: "RSI stopped the robot (too many late answers)",
    ERR_BAD_COMMAND: "command rejected by the robot program",
}

COMMAND_TAGS = (
    f"{COMMAND_ROOT}/@ID",
    f"{COMMAND_ROOT}/@Speed",
    *(f"{COMMAND_ROOT}/Pos/@{a}" for a in AXES),
)
STATE_TAGS = (
    *(f"{STATE_ROOT}/Pos/@{a}" for a in AXES),
    f"{STATE_ROOT}/{COMMAND_ROOT}/@ID",
    f"{STATE_ROOT}/{COMMAND_ROOT}/@Done",
    f"{STATE_ROOT}/{COMMAND_ROOT}/@Error",
)

# Numbers on the wire: a decimal with an optional exponent, at most 40 characters; no nan/inf/underscores.
_REAL_RE = re.compile(r"[-+]?(?:[0-9]{1,12}(?:\.[0-9]{0,12})?|\.[0-9]{1,12})(?:[eE][-+]?[0-9]{1,3})?")
_INT_RE = re.compile(r"[-+]?[0-9]{1,19}")
_WS = b" \t\r\n"


@dataclass(frozen=True)
class MoveCommand:
    command_id: int
    target_deg: tuple[float, ...]
    speed_pct: int


@dataclass(frozen=True)
class RobotState:
    joints_deg: tuple[float, ...]
    command_id: int
    done: bool
    error: int


# --- shared XML helpers (also used by drivers.kuka.rsi_codec) -----------------------------------------------


def parse_document(data: bytes, root: str, max_bytes: int = MAX_DOC_BYTES) -> ET.Element:
    """One XML document -> its root element, which must be named `root`. ProtocolError for anything else."""
    if not isinstance(data, bytes | bytearray):
        raise ProtocolError(f"expected bytes, got {type(data).__name__}")
    if len(data) > max_bytes:
        raise ProtocolError(f"<{root}> document of {len(data)} bytes exceeds the {max_bytes}-byte cap")
    if b"<!" in data:
        raise ProtocolError("DOCTYPE, entity declarations, comments and CDATA are not accepted")
    try:
        element = ET.fromstring(bytes(data))
    except Exception as exc:  # ParseError, unknown encodings, ...: all are malformed input
        raise ProtocolError(f"malformed <{root}> XML: {exc}") from None
    if element.tag != root:
        raise ProtocolError(f"expected a <{root}> document, got <{str(element.tag)[:40]}>")
    return element


def parse_real(text: str | None, what: str, limit: float = ANGLE_LIMIT_DEG) -> float:
    if text is None:
        raise ProtocolError(f"{what} is missing")
    text = text.strip()
    if len(text) > 40 or not _REAL_RE.fullmatch(text):
        raise ProtocolError(f"{what}={text[:40]!r} is not a number")
    value = float(text)
    if not math.isfinite(value) or abs(value) > limit:
        raise ProtocolError(f"{what}={text!r} is outside +-{limit}")
    return value


def parse_int(text: str | None, what: str, low: int, high: int) -> int:
    if text is None:
        raise ProtocolError(f"{what} is missing")
    text = text.strip()
    if not _INT_RE.fullmatch(text):
        raise ProtocolError(f"{what}={text[:40]!r} is not an integer")
    value = int(text)
    if not low <= value <= high:
        raise ProtocolError(f"{what}={value} is outside {low}..{high}")
    return value


def parse_bool(text: str | None, what: str) -> bool:
    if text is None:
        raise ProtocolError(f"{what} is missing")
    value = text.strip().upper()
    if value in ("1", "TRUE"):
        return True
    if value in ("0", "FALSE"):
        return False
    raise ProtocolError(f"{what}={text[:40]!r} is not a boolean (1/0/TRUE/FALSE)")


def parse_attrs(
    element: ET.Element | None, names: tuple[str, ...], what: str, limit: float
) -> tuple[float, ...]:
    if element is None:
        raise ProtocolError(f"<{what}> is missing")
    return tuple(parse_real(element.get(n), f"{what}/@{n}", limit) for n in names)


def fmt4(value: float) -> str:
    """A value at the controller's precision, 4 decimals, never '-0.0000'."""
    text = f"{value:.4f}"
    return "0.0000" if text == "-0.0000" else text


def _check_axes(values: tuple[float, ...], what: str) -> tuple[float, ...]:
    values = tuple(float(v) for v in values)
    if len(values) != len(AXES):
        raise ValueError(f"{what}: need {len(AXES)} axis values A1..A6, got {len(values)}")
    for name, v in zip(AXES, values, strict=True):
        if not math.isfinite(v) or abs(v) > ANGLE_LIMIT_DEG:
            raise ValueError(f"{what}: {name}={v} is not a finite angle within +-{ANGLE_LIMIT_DEG} deg")
    return values


def _axes_xml(tag: str, values: tuple[float, ...]) -> str:
    attrs = " ".join(f'{n}="{fmt4(v)}"' for n, v in zip(AXES, values, strict=True))
    return f"<{tag} {attrs}/>"


class XmlStreamFramer:
    """Cuts a TCP byte stream into complete `<root ...>...</root>` documents.

    Survives partial reads (keeps the tail) and several documents in one read; whitespace between documents
    (the KR C2 RSI ends each <Rob> with two LF) and an optional `<?xml ...?>` declaration are accepted.
    Anything else before a document, or a document longer than `max_doc_bytes`, raises ProtocolError, after
    which the framer stays failed (the stream cannot be resynchronised: the caller drops the connection).
    """

    def __init__(self, root: str, max_doc_bytes: int = MAX_DOC_BYTES) -> None:
        if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_.-]*", root):
            raise ValueError(f"bad root tag {root!r}")
        self.root = root
        self.max_doc_bytes = max_doc_bytes
        self._open = b"<" + root.encode("ascii")
        self._close_re = re.compile(rb"</" + re.escape(root.encode("ascii")) + rb"\s*>")
        self._buf = bytearray()
        self._failed: ProtocolError | None = None

    @property
    def pending(self) -> int:
        return len(self._buf)

    def feed(self, data: bytes) -> list[bytes]:
        if self._failed is not None:
            raise self._failed
        self._buf += data
        docs: list[bytes] = []
        try:
            while (doc := self._next()) is not None:
                docs.append(doc)
        except ProtocolError as exc:
            self._failed = exc
            self._buf.clear()
            raise
        return docs

    def _fail(self, why: str) -> ProtocolError:
        return ProtocolError(f"<{self.root}> stream: {why}")

    def _skip_ws(self, i: int) -> int:
        buf = self._buf
        while i < len(buf) and buf[i] in _WS:
            i += 1
        return i

    def _next(self) -> bytes | None:
        buf = self._buf
        i = self._skip_ws(0)
        if i:
            del buf[:i]
            i = 0
        if not buf:
            return None
        start = 0
        if buf.startswith(b"<?"):
            j = buf.find(b"?>")
            if j < 0:
                if len(buf) > self.max_doc_bytes:
                    raise self._fail(f"no end of the XML declaration within {self.max_doc_bytes} bytes")
                return None
            if not buf.startswith(b"<?xml") or buf[5:6] not in (b" ", b"\t", b"\r", b"\n"):
                raise self._fail(f"unexpected processing instruction {bytes(buf[:40])!r}")
            i = self._skip_ws(j + 2)
            if i == len(buf):
                return None
        head = bytes(buf[i : i + len(self._open) + 1])
        if not self._open.startswith(head[: len(self._open)]):
            raise self._fail(f"expected <{self.root}>, got {bytes(buf[i : i + 40])!r}")
        if len(head) <= len(self._open):
            return None
        if head[-1] not in b" \t\r\n/>":
            raise self._fail(f"expected <{self.root}>, got {bytes(buf[i : i + 40])!r}")
        # end of the start tag: the first '>' outside a quoted attribute value
        k, quote = i + len(self._open), 0
        while k < len(buf):
            c = buf[k]
            if quote:
                if c == quote:
                    quote = 0
            elif c in (0x22, 0x27):
                quote = c
            elif c == 0x3E:
                break
            k += 1
        else:
            return self._incomplete(start)
        if buf[k - 1] == 0x2F:  # self-closing root
            end = k + 1
        else:
            m = self._close_re.search(buf, k + 1)
            if m is None:
                return self._incomplete(start)
            end = m.end()
        if end - start > self.max_doc_bytes:
            raise self._fail(f"document of {end - start} bytes exceeds the {self.max_doc_bytes}-byte cap")
        doc = bytes(buf[start:end])
        del buf[:end]
        return doc

    def _incomplete(self, start: int) -> None:
        if len(self._buf) - start > self.max_doc_bytes:
            raise self._fail(f"no complete document within {self.max_doc_bytes} bytes")
        return None


# --- RobotCommand -------------------------------------------------------------------------------------------


def encode_command(cmd: MoveCommand) -> bytes:
    if isinstance(cmd.command_id, bool) or not 1 <= int(cmd.command_id) <= MAX_ID:
        raise ValueError(f"command id {cmd.command_id!r} outside 1..{MAX_ID}")
    if (
        isinstance(cmd.speed_pct, bool)
        or int(cmd.speed_pct) != cmd.speed_pct
        or not 1 <= cmd.speed_pct <= 100
    ):
        raise ValueError(f"speed override {cmd.speed_pct!r} is not an integer percentage 1..100")
    target = _check_axes(cmd.target_deg, "target")
    text = (
        f'<{COMMAND_ROOT} ID="{int(cmd.command_id)}" Speed="{int(cmd.speed_pct)}">'
        f"{_axes_xml('Pos', target)}</{COMMAND_ROOT}>"
    )
    return text.encode("ascii")


def parse_command(data: bytes) -> MoveCommand:
    root = parse_document(data, COMMAND_ROOT)
    return MoveCommand(
        command_id=parse_int(root.get("ID"), f"{COMMAND_ROOT}/@ID", 1, MAX_ID),
        target_deg=parse_attrs(root.find("Pos"), AXES, f"{COMMAND_ROOT}/Pos", ANGLE_LIMIT_DEG),
        speed_pct=parse_int(root.get("Speed"), f"{COMMAND_ROOT}/@Speed", 1, 100),
    )


def command_id_of(data: bytes) -> int | None:
    """Best effort: the ID of a command that failed to parse (so the robot can echo it with an error)."""
    try:
        return parse_int(parse_document(data, COMMAND_ROOT).get("ID"), "ID", 1, MAX_ID)
    except ProtocolError:
        return None


# --- RobotState ---------------------------------------------------------------------------------------------


def encode_state(state: RobotState) -> bytes:
    if isinstance(state.command_id, bool) or not 0 <= int(state.command_id) <= MAX_ID:
        raise ValueError(f"command id {state.command_id!r} outside 0..{MAX_ID}")
    if isinstance(state.error, bool) or not 0 <= int(state.error) <= MAX_ID:
        raise ValueError(f"error code {state.error!r} outside 0..{MAX_ID}")
    joints = _check_axes(state.joints_deg, "joints")
    text = (
        f"<{STATE_ROOT}>{_axes_xml('Pos', joints)}"
        f'<{COMMAND_ROOT} ID="{int(state.command_id)}" Done="{1 if state.done else 0}" '
        f'Error="{int(state.error)}"/>'
        f"</{STATE_ROOT}>"
    )
    return text.encode("ascii")


def parse_state(data: bytes) -> RobotState:
    root = parse_document(data, STATE_ROOT)
    ack = root.find(COMMAND_ROOT)
    if ack is None:
        raise ProtocolError(f"<{STATE_ROOT}> without <{COMMAND_ROOT}> acknowledgement")
    where = f"{STATE_ROOT}/{COMMAND_ROOT}"
    return RobotState(
        joints_deg=parse_attrs(root.find("Pos"), AXES, f"{STATE_ROOT}/Pos", ANGLE_LIMIT_DEG),
        command_id=parse_int(ack.get("ID"), f"{where}/@ID", 0, MAX_ID),
        done=parse_bool(ack.get("Done"), f"{where}/@Done"),
        error=parse_int(ack.get("Error"), f"{where}/@Error", 0, MAX_ID),
    )
