"""KUKA RSI 2.x "Ethernet RSI XML" (ST_ETHERNET object, KR C2) frame codec: pure functions, no I/O.

Every interpolation cycle (12 ms on a KR C2, 4 ms on a KR C4: the cycle_time of ros-industrial/kuka_experimental
kuka_rsi_simulator; trackcal takes it from the hardware file) the controller - the UDP (default) or TCP *client* -
sends one document:

    <Rob TYPE="KUKA"><RIst X=".." Y=".." Z=".." A=".." B=".." C=".."/><RSol X=".." .. C=".."/>
     <AIPos A1=".." .. A6=".."/><ASPos A1=".." .. A6=".."/><Delay D="0"/><IPOC>123645634563</IPOC></Rob>

(RIst/RSol: actual/set Cartesian pose; AIPos/ASPos: actual/set axis positions in degrees, 4 decimals; Delay D:
late packets counted by the controller; IPOC: the controller's interpolation-cycle timestamp). The external
side must answer within about 10 ms with the same IPOC, unless the config says ONLYSEND TRUE (passive: the
controller expects no answer, "TRUE means the client don't expect answers", ros_rsi_ethernet.xml):

    <Sen Type="ImFree"><AK A1="0.0000" A2="0.0000" A3="0.0000" A4="0.0000" A5="0.0000" A6="0.0000"/>
     <IPOC>123645634563</IPOC></Sen>

Sources: ros-industrial/kuka_experimental, kuka_rsi_hw_interface/include/kuka_rsi_hw_interface/rsi_state.h
(reads RIst, RSol, AIPos, ASPos, IPOC out of <Rob>) and rsi_command.h (writes <Sen Type="ImFree"><AK
A1..A6/><IPOC/>); kuka_rsi_simulator/scripts/kuka_rsi_simulator (writes <Rob TYPE="KUKA"> with RIst, RSol,
AIPos, ASPos, <Delay D=..>, IPOC); kuka_rsi_hw_interface/krl/KR_C2/ros_rsi_ethernet.xml (the KR C2 config:
DEF_RIst, DEF_RSol, DEF_AIPos, DEF_ASPos, DEF_Delay sent, AK.A1..AK.A6 received, SENTYPE ImFree); the ~10 ms
answer budget is quoted from the "KUKA.Ethernet RSI XML" manual in kuka_rsi_hw_interface/krl/KR_C2/README.md.
KR C2 quirk (kuka_experimental pull request #74, "Support for KR C2 with RSI 2",
https://github.com/ros-industrial/kuka_experimental/pull/74): the first <Rob> after ST_ETHERNET holds only an
empty <IPOC/>; it parses here to a RobFrame with every field None.

The shipped configs/krc2/trackcal_rsi.xml is read at import (SHIPPED): protocol, SENTYPE, ONLYSEND, the SEND
tags (DEF_<element> -> the <Rob> elements) and the RECEIVE tags (<element>.<attribute> -> the <Sen> corrections):
the file is the one source of truth for the client's defaults and for the mock controller. `ipoc_of` finds the
IPOC of a frame without parsing it, for the thread that answers (it does nothing else).
The XML is parsed through drivers.kuka.eki_codec.parse_document (size cap, no DOCTYPE/entities).
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from itertools import repeat

from trackcal.drivers.errors import ProtocolError
from trackcal.drivers.kuka.eki_codec import (
    AXES,
    XmlStreamFramer,
    config_text,
    fmt4,
    parse_attrs,
    parse_document,
    parse_int,
)

CONFIG_FILE = "trackcal_rsi.xml"

ROB_ROOT = "Rob"
SEN_ROOT = "Sen"
CART = ("X", "Y", "Z", "A", "B", "C")
MAX_FRAME_BYTES = 2048  # a full <Rob> is ~450 bytes
TCP_TERMINATOR = b"\n\n"  # the KR C2 ends every <Rob> on TCP with two LF
MAX_IPOC = 2**63 - 1
CART_LIMIT = 1.0e6  # mm / deg, plausibility bound
AXIS_LIMIT = 1.0e4  # deg
KRC2_CYCLE_S = 0.012  # KR C2 interpolation cycle (the default of the hardware file's rsi.cycle_s)
_IPOC_RE = re.compile(rb"<IPOC>\s*([0-9]{1,19})\s*</IPOC>")


@dataclass(frozen=True)
class RsiConfig:
    """What an ST_ETHERNET config file says: protocol ("udp"/"tcp"), the <Sen Type>, whether the controller
    expects answers, the <Rob> elements it sends (SEND DEF_<name>) and the correction it reads (RECEIVE)."""

    protocol: str
    sen_type: str
    passive: bool
    rob_elements: tuple[str, ...]
    correction: str
    correction_axes: tuple[str, ...]


def read_config(xml: bytes, what: str = CONFIG_FILE) -> RsiConfig:
    root = ET.fromstring(xml)
    protocol = (root.findtext("CONFIG/PROTOCOL") or "").strip().lower()
    onlysend = (root.findtext("CONFIG/ONLYSEND") or "").strip().upper()
    sen_type = (root.findtext("CONFIG/SENTYPE") or "").strip()
    send = [e.get("TAG", "") for e in root.iterfind("SEND/ELEMENTS/ELEMENT")]
    receive = [e.get("TAG", "").split(".") for e in root.iterfind("RECEIVE/ELEMENTS/ELEMENT")]
    if protocol not in ("udp", "tcp") or onlysend not in ("TRUE", "FALSE") or not sen_type.isidentifier():
        raise ValueError(f"{what}: PROTOCOL {protocol!r}, ONLYSEND {onlysend!r}, SENTYPE {sen_type!r}")
    if not send or any(not t.startswith("DEF_") for t in send):
        raise ValueError(f"{what}: SEND tags must be DEF_<element>, got {send}")
    if not receive or any(len(r) != 2 or r[0] != receive[0][0] for r in receive):
        raise ValueError(f"{what}: RECEIVE tags must be one <element>.<attribute> family")
    return RsiConfig(
        protocol,
        sen_type,
        onlysend == "TRUE",
        tuple(t[4:] for t in send) + ("IPOC",),
        receive[0][0],
        tuple(r[1] for r in receive),
    )


SHIPPED = read_config(config_text(CONFIG_FILE).encode())
SEN_TYPE = SHIPPED.sen_type
ROB_ELEMENTS = SHIPPED.rob_elements  # in the order the controller writes them
CORRECTION_ELEMENT = SHIPPED.correction  # axis corrections, received as AK.A1..AK.A6
if SHIPPED.correction_axes != AXES or set(ROB_ELEMENTS) != {"RIst", "RSol", "AIPos", "ASPos", "Delay", "IPOC"}:
    raise ValueError(
        f"{CONFIG_FILE}: the codec reads RIst RSol AIPos ASPos Delay and answers "
        f"{CORRECTION_ELEMENT}.{'/'.join(AXES)}; the file declares {SHIPPED}"
    )


@dataclass(frozen=True)
class RobFrame:
    """One controller frame. `ipoc` None is the KR C2's first frame (empty <IPOC/>), with nothing else."""

    ipoc: int | None
    aipos: tuple[float, ...] | None = None
    aspos: tuple[float, ...] | None = None
    rist: tuple[float, ...] | None = None
    rsol: tuple[float, ...] | None = None
    delay: int | None = None


@dataclass(frozen=True)
class SenFrame:
    ipoc: int
    corrections: tuple[float, ...] = (0.0,) * 6
    sen_type: str = SEN_TYPE
    stop: bool = False  # KR C4 only: <Stop>1</Stop>, the RECEIVE element Stop of configs/krc4 (drivers.krc4.configs)


def _xml_attrs(tag: str, names: tuple[str, ...], values: tuple[float, ...]) -> str:
    if len(values) != len(names):
        raise ValueError(f"<{tag}> needs {len(names)} values, got {len(values)}")
    return f"<{tag} " + " ".join(f'{n}="{fmt4(float(v))}"' for n, v in zip(names, values, strict=True)) + "/>"


def _rob_layout(cart: str, axis: str, delay: str, ipoc: str) -> str:
    """The <Rob> document as encode_rob writes it, every value replaced by `cart` (RIst, RSol), `axis` (AIPos,
    ASPos), `delay` (Delay D) or `ipoc`: the one layout both the encoder's template and the parser's fast path are
    made from."""

    def attrs(tag: str, names: tuple[str, ...], number: str) -> str:
        return f"<{tag} " + " ".join(f'{n}="{number}"' for n in names) + "/>"

    return (
        f'<{ROB_ROOT} TYPE="KUKA">'
        + attrs("RIst", CART, cart)
        + attrs("RSol", CART, cart)
        + attrs("AIPos", AXES, axis)
        + attrs("ASPos", AXES, axis)
        + f'<Delay D="{delay}"/><IPOC>{ipoc}</IPOC></{ROB_ROOT}>'
    )


# One %-template for the whole frame (issue 41: the mock sends one per 12 ms cycle of every move; 24 f-strings of
# fmt4 cost 21 us a frame, the template 5 us). "%.4f" is the format of fmt4; its "-0.0000" becomes "0.0000" after.
_ROB_TEMPLATE = _rob_layout("%.4f", "%.4f", "%d", "%d")
_NEGATIVE_ZERO, _ZERO = '"-0.0000"', '"0.0000"'


def encode_rob(frame: RobFrame, tcp: bool = True) -> bytes:
    """The controller side (used by the mock). `tcp` appends the KR C2's two LF."""
    if frame.ipoc is None:
        text = f'<{ROB_ROOT} TYPE="KUKA"><IPOC/></{ROB_ROOT}>'
    else:
        if not 0 <= frame.ipoc <= MAX_IPOC:
            raise ValueError(f"IPOC {frame.ipoc} out of range")
        zero = (0.0,) * 6
        rist, rsol, aipos = frame.rist or zero, frame.rsol or zero, frame.aipos or zero
        aspos = frame.aspos or aipos
        if not len(rist) == len(rsol) == len(CART) or not len(aipos) == len(aspos) == len(AXES):
            tag, block = next(
                (t, b) for t, b in (("RIst", rist), ("RSol", rsol), ("AIPos", aipos), ("ASPos", aspos)) if len(b) != 6
            )
            raise ValueError(f"<{tag}> needs 6 values, got {len(block)}")
        text = _ROB_TEMPLATE % (
            *map(float, rist),
            *map(float, rsol),
            *map(float, aipos),
            *map(float, aspos),
            int(frame.delay or 0),
            int(frame.ipoc),
        )
        text = text.replace(_NEGATIVE_ZERO, _ZERO)
    return text.encode("ascii") + (TCP_TERMINATOR if tcp else b"")


def _ipoc(text: str | None, where: str) -> int | None:
    if text is None or not text.strip():
        return None
    return parse_int(text, f"{where}/IPOC", 0, MAX_IPOC)


# The parser's fast path: a frame laid out exactly as encode_rob writes it (the mock's, every cycle of a move) is
# read by one regular expression instead of an XML parse (issue 41: 49 us a frame with ElementTree, 8 us so). Its
# numbers are a subset of what parse_attrs and parse_int accept (no sign but "-", no exponent, no blanks), its
# limits are theirs, and a match yields the values the XML path reads from the same bytes
# (tests/drivers/kuka/test_rsi_codec_fast.py); anything else, a real controller's own layout included, takes the XML
# path with its checks and its messages.
_REAL, _INTEGER = "(-?[0-9]{1,12}\\.[0-9]{4})", "([0-9]{1,19})"
_FAST_ROB = re.compile(_rob_layout(_REAL, _REAL, _INTEGER, _INTEGER))


def _parse_rob_fast(data: bytes) -> RobFrame | None:
    """The frame when `data` (stripped) is in encode_rob's layout with every value in range, else None."""
    m = _FAST_ROB.fullmatch(data.decode("latin-1"))  # str: float() of a str is 3x faster than of bytes
    if m is None:
        return None
    v = tuple(map(float, m.groups()[:24]))
    delay, ipoc = int(m[25]), int(m[26])
    if ipoc > MAX_IPOC or delay > 2**31 - 1 or max(map(abs, v[:12])) > CART_LIMIT or max(map(abs, v[12:])) > AXIS_LIMIT:
        return None
    return RobFrame(ipoc=ipoc, aipos=v[12:18], aspos=v[18:], rist=v[:6], rsol=v[6:12], delay=delay)


def parse_rob(data: bytes) -> RobFrame:
    data = bytes(data).strip()
    if len(data) <= MAX_FRAME_BYTES:
        fast = _parse_rob_fast(data)
        if fast is not None:
            return fast
    root = parse_document(data, ROB_ROOT, MAX_FRAME_BYTES)
    ipoc_el = root.find("IPOC")
    if ipoc_el is None:
        raise ProtocolError("<Rob> without <IPOC>")
    ipoc = _ipoc(ipoc_el.text, ROB_ROOT)
    if ipoc is None:
        return RobFrame(ipoc=None)

    def opt(tag: str, names: tuple[str, ...], limit: float) -> tuple[float, ...] | None:
        el = root.find(tag)
        return None if el is None else parse_attrs(el, names, f"Rob/{tag}", limit)

    delay_el = root.find("Delay")
    return RobFrame(
        ipoc=ipoc,
        aipos=parse_attrs(root.find("AIPos"), AXES, "Rob/AIPos", AXIS_LIMIT),
        aspos=opt("ASPos", AXES, AXIS_LIMIT),
        rist=opt("RIst", CART, CART_LIMIT),
        rsol=opt("RSol", CART, CART_LIMIT),
        delay=None if delay_el is None else parse_int(delay_el.get("D"), "Rob/Delay/@D", 0, 2**31 - 1),
    )


# The client's reading of a frame (issue 41): it keeps the IPOC and the axis positions (AIPos, 4 decimals) of
# every frame of a move. A frame in encode_rob's layout whose every value is inside the limits by its digits alone
# (CART_LIMIT 1e6: six digits before the point, AXIS_LIMIT 1e4: four, the Delay nine, the IPOC eighteen) is valid
# without converting its other values, and its AIPos, written with four decimals, are already rounded to four
# (float() of such a string is the double round(, 4) gives); any other frame is read by parse_rob, and refused as
# it refuses it.
_JOINTS_ROB = re.compile(
    _rob_layout("-?[0-9]{1,6}\\.[0-9]{4}", "(-?[0-9]{1,4}\\.[0-9]{4})", "[0-9]{1,9}", "([0-9]{1,18})")
)


def rob_joints(data: bytes) -> tuple[int | None, tuple[float, ...] | None]:
    """(IPOC, AIPos rounded to 4 decimals) of a <Rob> frame, as parse_rob reads it (ProtocolError as it refuses
    it); (None, None) for the KR C2's first frame."""
    m = _JOINTS_ROB.fullmatch(bytes(data).strip().decode("latin-1"))
    if m is not None:
        values = m.groups()
        return int(values[12]), tuple(map(float, values[:6]))
    frame = parse_rob(data)
    return frame.ipoc, None if frame.aipos is None else tuple(map(round, frame.aipos, repeat(4)))


def ipoc_of(data: bytes) -> int | None:
    """The IPOC of a frame, without parsing it (None: no IPOC value, e.g. the KR C2's first frame). For the
    answering thread; the frame itself is parsed (and may be refused) afterwards, elsewhere."""
    m = _IPOC_RE.search(data, 0, MAX_FRAME_BYTES)
    if m is None:
        return None
    value = int(m[1])
    return value if value <= MAX_IPOC else None


# A plain RECEIVE element (TAG without a dot) is the element's text, as <IPOC> is; a BOOL is 0 or 1. Only a KR C4
# answer carries it (the motion guard's stop, drivers.krc4.client), and only when set: the KR C2's bytes are unchanged.
STOP_ELEMENT = "Stop"
_STOP_ON = f"<{STOP_ELEMENT}>1</{STOP_ELEMENT}>"


def encode_sen(frame: SenFrame) -> bytes:
    """The external side's answer: same IPOC, axis corrections (zero for a passive monitor)."""
    if not 0 <= frame.ipoc <= MAX_IPOC:
        raise ValueError(f"IPOC {frame.ipoc} out of range")
    if not frame.sen_type.isidentifier():
        raise ValueError(f"Sen Type {frame.sen_type!r} is not a plain name")
    text = (
        f'<{SEN_ROOT} Type="{frame.sen_type}">{_xml_attrs(CORRECTION_ELEMENT, AXES, frame.corrections)}'
        f"{_STOP_ON if frame.stop else ''}<IPOC>{int(frame.ipoc)}</IPOC></{SEN_ROOT}>"
    )
    return text.encode("ascii")


def parse_sen(data: bytes) -> SenFrame:
    root = parse_document(bytes(data).strip(), SEN_ROOT, MAX_FRAME_BYTES)
    sen_type = root.get("Type")
    if not sen_type:
        raise ProtocolError("<Sen> without Type attribute")
    ipoc_el = root.find("IPOC")
    ipoc = _ipoc(None if ipoc_el is None else ipoc_el.text, SEN_ROOT)
    if ipoc is None:
        raise ProtocolError("<Sen> without an IPOC value")
    stop_el = root.find(STOP_ELEMENT)
    stop = "0" if stop_el is None else (stop_el.text or "").strip()
    if stop not in ("0", "1"):
        raise ProtocolError(f"<Sen><{STOP_ELEMENT}> is {stop!r}, expected 0 or 1")
    return SenFrame(
        ipoc=ipoc,
        corrections=parse_attrs(root.find(CORRECTION_ELEMENT), AXES, "Sen/AK", AXIS_LIMIT),
        sen_type=sen_type,
        stop=stop == "1",
    )


def rob_framer() -> XmlStreamFramer:
    return XmlStreamFramer(ROB_ROOT, MAX_FRAME_BYTES)


def sen_framer() -> XmlStreamFramer:
    return XmlStreamFramer(SEN_ROOT, MAX_FRAME_BYTES)
