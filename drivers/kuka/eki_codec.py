"""KUKA KR C2 "Ethernet KRL XML 1.2" (KRL API EKX_*) codec of trackcal's requests and the controller's answers.

Pure functions, no I/O. The documents are the ones configs/krc2 declares, read from there at import (xml.etree,
importlib.resources): what the controller receives from configs/krc2/TrackcalEki.xml (typed <Elements>, one
STRUCTTAG root, a STRUCTTAG is an element and every other type an attribute of its prefix), what it sends from
the template configs/krc2/TrackcalEki+.xml. That layout is the one of ros-industrial/kuka_experimental pull
request #205 ("KRC2 port for kuka_eki_hw_interface", commit fb5999d, kuka_eki_hw_interface/krl/EkiHwInterface.xml
and EkiHwInterface+.xml), whose KRL addresses values as "Channel.Element.Attribute". The codec binds its fields
to the declared names (COMMAND_FIELDS, STATE_FIELDS) and refuses to import if the files declare anything it does
not bind or miss anything it does: the files are the one source of truth, for the KRL program
(tests/test_krl_static.py), this codec and the mock controller. trackcal -> robot, every element always present:

    <RobotCommand ID="17" Kind="1" Speed="20"><Pos A1="0.0000" A2="-90.0000" A3="90.0000" A4="0.0000"
     A5="90.0000" A6="0.0000"/></RobotCommand>

Kind 1 = PTP move to Pos at Speed % axis override; 2 = stop the running move with this ID (the KRL brakes; the
move's answer then says Error 6); 3 = reset the fault flags. robot -> trackcal, once per move or reset:

    <RobotState><Pos A1=".." ... A6=".."/><RobotCommand ID="17" Done="1" Error="0"/></RobotState>

Safety of the XML parsing (every parser here and in drivers.kuka.rsi_codec goes through `parse_document`):
- a size cap per document (MAX_DOC_BYTES) before anything is parsed;
- any markup declaration "<!" (DOCTYPE, ENTITY, comments, CDATA) is refused outright, so no entity can be
  defined: no XXE, no "billion laughs" (Python docs, "XML vulnerabilities": xml.etree does not fetch external
  entities but expands internal ones; refusing the DOCTYPE removes both);
- every failure of the stdlib parser becomes drivers.errors.ProtocolError; nothing else escapes.
The shipped configuration files are trusted input (package data), parsed with xml.etree directly.
"""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from importlib import resources

from trackcal.drivers.errors import ProtocolError

CONFIG_PACKAGE = "trackcal.configs"  # configs/krc2 is package data
CHANNEL = "TrackcalEki"  # the channel name: EKX_Open("TrackcalEki") and every path's first part
ELEMENTS_FILE = f"{CHANNEL}.xml"
TEMPLATE_FILE = f"{CHANNEL}+.xml"
MAX_DOC_BYTES = 4096  # a command or a state is ~250 bytes; the cap bounds parsing time and memory
MAX_ID = 2**31 - 1  # a KRL INT is a 32-bit signed integer
ANGLE_LIMIT_DEG = 10_000.0  # plausibility bound on the wire (KRL axis values are a few hundred degrees at most)

# RobotCommand/@Kind, as configs/krc2/trackcal_eki.src serves it
KIND_MOVE = 1
KIND_STOP = 2
KIND_RESET = 3
KINDS = (KIND_MOVE, KIND_STOP, KIND_RESET)

# Error codes of RobotState/RobotCommand/@Error, set by configs/krc2/trackcal_eki.src.
ERR_NONE = 0
ERR_ESTOP = 1  # an emergency stop was seen and no reset has found it released
ERR_DRIVES_OFF = 2  # drives not ready ($PERI_RDY false)
ERR_SOFT_LIMIT = 3  # target outside $SOFTN_END/$SOFTP_END, or a software limit switch reached
ERR_RSI_STOPPED = 4  # the RSI monitor stopped the robot (more than eERXmaxLatePackages late answers)
ERR_BAD_COMMAND = 5  # the command could not be read (unknown kind, speed out of range)
ERR_STOPPED = 6  # the move was stopped by a Kind 2 request (BRAKE)
ERROR_TEXT = {
    ERR_ESTOP: "emergency stop",
    ERR_DRIVES_OFF: "drives off",
    ERR_SOFT_LIMIT: "software limit switch / target outside the axis limits",
    ERR_RSI_STOPPED: "RSI stopped the robot (too many late answers)",
    ERR_BAD_COMMAND: "command rejected by the robot program",
    ERR_STOPPED: "stopped on request (BRAKE)",
}

# Numbers on the wire: a decimal with an optional exponent, at most 40 characters; no nan/inf/underscores.
_REAL_RE = re.compile(r"[-+]?(?:[0-9]{1,12}(?:\.[0-9]{0,12})?|\.[0-9]{1,12})(?:[eE][-+]?[0-9]{1,3})?")
_INT_RE = re.compile(r"[-+]?[0-9]{1,19}")
_WS = b" \t\r\n"


# --- the channel TrackcalEki, as configs/krc2 declares it ---------------------------------------------------


@dataclass(frozen=True)
class Structure:
    """One XML document of the channel: its root element, the root's attributes and its child elements with
    theirs (two levels, as both of trackcal's documents), each attribute's type ("" in a send template)."""

    root: str
    attrs: tuple[str, ...]
    children: tuple[tuple[str, tuple[str, ...]], ...]
    types: tuple[tuple[str, str], ...]

    @property
    def tags(self) -> tuple[str, ...]:
        """Every value of the document as an EKX path without the channel: "Root.Attr", "Root.Child.Attr"."""
        return tuple(tag for tag, _ in self.types)

    def child(self, name: str) -> tuple[str, ...]:
        return dict(self.children)[name]


def read_elements(xml: bytes, what: str = "elements") -> Structure:
    """The typed <Elements> list of what the controller receives (configs/krc2/TrackcalEki.xml)."""
    root = ET.fromstring(xml)
    if root.tag != "Elements":
        raise ValueError(f"{what}: root <{root.tag}>, expected <Elements>")
    name, attrs, children, types = "", [], {}, []
    for el in root.iter("Element"):
        tag, kind = el.get("Tag", ""), el.get("Type", "")
        parts = tag.split(".")
        if kind == "STRUCTTAG":
            if len(parts) == 1 and not name:
                name = tag
            elif len(parts) == 2 and parts[0] == name and parts[1] not in children:
                children[parts[1]] = []
            else:
                raise ValueError(f"{what}: STRUCTTAG {tag!r} is not the one root or a child of it")
        elif kind in ("INTEGER", "REAL"):
            if len(parts) == 2 and parts[0] == name:
                attrs.append(parts[1])
            elif len(parts) == 3 and parts[0] == name and parts[1] in children:
                children[parts[1]].append(parts[2])
            else:
                raise ValueError(f"{what}: {tag!r} belongs to no declared STRUCTTAG")
            types.append((tag, kind))
        else:
            raise ValueError(f"{what}: {tag!r} has type {kind!r}, expected STRUCTTAG, INTEGER or REAL")
    if not name:
        raise ValueError(f"{what}: no root STRUCTTAG")
    return Structure(name, tuple(attrs), tuple((c, tuple(a)) for c, a in children.items()), tuple(types))


def read_template(xml: bytes, what: str = "template") -> Structure:
    """The document the controller sends, as a template with empty values (configs/krc2/TrackcalEki+.xml)."""
    root = ET.fromstring(xml)
    children, types = [], [(f"{root.tag}.{a}", "") for a in root.attrib]
    for el in root:
        if len(el):
            raise ValueError(f"{what}: <{el.tag}> has children: two levels only")
        children.append((el.tag, tuple(el.attrib)))
        types += [(f"{root.tag}.{el.tag}.{a}", "") for a in el.attrib]
    return Structure(root.tag, tuple(root.attrib), tuple(children), tuple(types))


def config_text(name: str) -> str:
    """A shipped file of configs/krc2 (package data)."""
    return resources.files(CONFIG_PACKAGE).joinpath("krc2", name).read_text(encoding="utf-8")


# The codec's fields, bound to the declared names (the files hold the names, the order and the types).
AXES_ELEMENT = "Pos"  # the STRUCTTAG child whose REAL attributes are the axis values, in both documents
COMMAND_FIELDS = ("ID", "Kind", "Speed")  # RobotCommand's INTEGER attributes
STATE_ANSWER = "RobotCommand"  # RobotState's child echoing the request
STATE_FIELDS = ("ID", "Done", "Error")


def _bind(command: Structure, state: Structure) -> tuple[str, ...]:
    """The axis names; ValueError if a file and the codec's fields disagree."""
    axes = command.child(AXES_ELEMENT) if AXES_ELEMENT in dict(command.children) else ()
    want = {f"{command.root}.{f}": "INTEGER" for f in COMMAND_FIELDS}
    want |= {f"{command.root}.{AXES_ELEMENT}.{a}": "REAL" for a in axes}
    if len(axes) != 6 or dict(command.types) != want or len(command.types) != len(want):
        raise ValueError(
            f"{ELEMENTS_FILE}: expected INTEGER {COMMAND_FIELDS} and 6 REAL {AXES_ELEMENT} axes, "
            f"declared {command.types}"
        )
    if state.attrs or dict(state.children) != {AXES_ELEMENT: axes, STATE_ANSWER: STATE_FIELDS}:
        raise ValueError(
            f"{TEMPLATE_FILE}: expected <{AXES_ELEMENT} {' '.join(axes)}> and "
            f"<{STATE_ANSWER} {' '.join(STATE_FIELDS)}>, found {state.children}"
        )
    return axes


COMMAND = read_elements(config_text(ELEMENTS_FILE).encode(), ELEMENTS_FILE)
STATE = read_template(config_text(TEMPLATE_FILE).encode(), TEMPLATE_FILE)
AXES = _bind(COMMAND, STATE)
COMMAND_ROOT = COMMAND.root
STATE_ROOT = STATE.root


@dataclass(frozen=True)
class Command:
    command_id: int
    kind: int = KIND_MOVE
    target_deg: tuple[float, ...] = (0.0,) * 6
    speed_pct: int = 0  # 1..100 for a move; 0 for a stop or a reset


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


def parse_attrs(element: ET.Element | None, names: tuple[str, ...], what: str, limit: float) -> tuple[float, ...]:
    """parse_real of each attribute. A plain value (no blanks) is taken here without naming it first: the RSI
    monitor reads 24 of them every cycle; anything else goes through parse_real, which says what is wrong."""
    if element is None:
        raise ProtocolError(f"<{what}> is missing")
    values = []
    for n in names:
        text = element.get(n)
        if text is not None and len(text) <= 40 and _REAL_RE.fullmatch(text) and abs(value := float(text)) <= limit:
            values.append(value)
        else:
            values.append(parse_real(text, f"{what}/@{n}", limit))
    return tuple(values)


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


def _speed_range(kind: int) -> tuple[int, int]:
    return (1, 100) if kind == KIND_MOVE else (0, 100)


def encode_command(cmd: Command) -> bytes:
    if isinstance(cmd.command_id, bool) or not 1 <= int(cmd.command_id) <= MAX_ID:
        raise ValueError(f"command id {cmd.command_id!r} outside 1..{MAX_ID}")
    if cmd.kind not in KINDS:
        raise ValueError(f"command kind {cmd.kind!r} is not one of {KINDS}")
    low, high = _speed_range(cmd.kind)
    if isinstance(cmd.speed_pct, bool) or int(cmd.speed_pct) != cmd.speed_pct or not low <= cmd.speed_pct <= high:
        raise ValueError(f"speed override {cmd.speed_pct!r} is not an integer percentage {low}..{high}")
    target = _check_axes(cmd.target_deg, "target")
    values = dict(zip(COMMAND_FIELDS, (int(cmd.command_id), cmd.kind, int(cmd.speed_pct)), strict=True))
    attrs = " ".join(f'{name}="{values[name]}"' for name in COMMAND.attrs)
    return f"<{COMMAND_ROOT} {attrs}>{_axes_xml(AXES_ELEMENT, target)}</{COMMAND_ROOT}>".encode("ascii")


def parse_command(data: bytes) -> Command:
    root = parse_document(data, COMMAND_ROOT)
    where = COMMAND_ROOT
    command_id = parse_int(root.get("ID"), f"{where}/@ID", 1, MAX_ID)
    kind = parse_int(root.get("Kind"), f"{where}/@Kind", min(KINDS), max(KINDS))
    return Command(
        command_id=command_id,
        kind=kind,
        target_deg=parse_attrs(root.find(AXES_ELEMENT), AXES, f"{where}/{AXES_ELEMENT}", ANGLE_LIMIT_DEG),
        speed_pct=parse_int(root.get("Speed"), f"{where}/@Speed", *_speed_range(kind)),
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
    values = dict(zip(STATE_FIELDS, (int(state.command_id), 1 if state.done else 0, int(state.error)), strict=True))
    parts = []
    for child, attrs in STATE.children:
        if child == AXES_ELEMENT:
            parts.append(_axes_xml(AXES_ELEMENT, joints))
        else:
            parts.append(f"<{child} " + " ".join(f'{a}="{values[a]}"' for a in attrs) + "/>")
    return f"<{STATE_ROOT}>{''.join(parts)}</{STATE_ROOT}>".encode("ascii")


def parse_state(data: bytes) -> RobotState:
    root = parse_document(data, STATE_ROOT)
    ack = root.find(STATE_ANSWER)
    if ack is None:
        raise ProtocolError(f"<{STATE_ROOT}> without <{STATE_ANSWER}> acknowledgement")
    where = f"{STATE_ROOT}/{STATE_ANSWER}"
    return RobotState(
        joints_deg=parse_attrs(root.find(AXES_ELEMENT), AXES, f"{STATE_ROOT}/{AXES_ELEMENT}", ANGLE_LIMIT_DEG),
        command_id=parse_int(ack.get("ID"), f"{where}/@ID", 0, MAX_ID),
        done=parse_bool(ack.get("Done"), f"{where}/@Done"),
        error=parse_int(ack.get("Error"), f"{where}/@Error", 0, MAX_ID),
    )
