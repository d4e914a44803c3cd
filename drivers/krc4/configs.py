"""What the KR C4 configuration files in configs/krc4 declare, read at import and bound to the shared codecs.

The documents on the wire are the KR C2's (drivers.kuka.eki_codec builds and parses them from configs/krc2's
declarations; drivers.kuka.rsi_codec the <Rob>/<Sen> frames), so the KSS 8 files must declare exactly those: this
module refuses to import otherwise, and the files stay the one source of truth for the family, the mock and the KRL.

- configs/krc4/TrackcalEki.xml, an EthernetKRL 3.x file (<ETHERNETKRL><CONFIGURATION><EXTERNAL><TYPE>Client ...
  <INTERNAL>...<PORT>...<PROTOCOL>... <RECEIVE><XML><ELEMENT Tag="RobotCommand/Pos/@A1" Type="REAL"/>...
  <SEND><XML><ELEMENT Tag="RobotState/Pos/@A1"/>...), the layout of ros-industrial/kuka_experimental
  kuka_eki_hw_interface/krl/EkiHwInterface.xml (commit 8824b8a). A Tag "Root/Child/@Attr" is the KR C2's
  "Root.Child.Attr"; Type INT is its INTEGER.
- configs/krc4/trackcal_rsi_ethernet.xml, the RSI ETHERNET object's file (<ROOT><CONFIG><IP_NUMBER>..<PORT>..
  <SENTYPE>..<ONLYSEND>..</CONFIG><SEND><ELEMENTS><ELEMENT TAG="DEF_RIst" .../>...<RECEIVE>... AK.A1..AK.A6), the
  layout of kuka_rsi_hw_interface/krl/KR_C4_RSI_4+/ros_rsi_ethernet.xml (commit 249eb36): no PROTOCOL element,
  RSI Ethernet on a KR C4 is UDP. Beside the AK corrections it receives one BOOL, Stop (the motion guard's stop,
  answered within the RSI cycle: drivers.krc4.client; the KR C2 file has none).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from importlib import resources

from trackcal.drivers.kuka.eki_codec import COMMAND, CONFIG_PACKAGE, STATE
from trackcal.drivers.kuka.rsi_codec import ROB_ELEMENTS, SEN_TYPE, STOP_ELEMENT
from trackcal.drivers.kuka.rsi_codec import SHIPPED as KRC2_RSI

EKI_FILE = "TrackcalEki.xml"
RSI_FILE = "trackcal_rsi_ethernet.xml"
CHANNEL = EKI_FILE.removesuffix(".xml")  # EKI_Init("TrackcalEki"): the file's name is the channel's
RSI_CONTEXT = "trackcal_rsi"  # RSI_CREATE("trackcal_rsi", ...) in configs/krc4/trackcal_eki.src
EKI_TYPES = {"INT": "INTEGER", "REAL": "REAL"}  # EthernetKRL 3.x type -> the KR C2 declaration's


def config_text(name: str) -> str:
    """A shipped file of configs/krc4 (package data)."""
    return resources.files(CONFIG_PACKAGE).joinpath("krc4", name).read_text(encoding="utf-8")


@dataclass(frozen=True)
class EkiConfig:
    """An EthernetKRL 3.x channel: who connects (external_type "Client": trackcal connects, the controller
    serves on port), the protocol, and the element paths received (with their KR C2 type) and sent."""

    external_type: str
    port: int
    protocol: str
    received: tuple[tuple[str, str], ...]
    sent: tuple[str, ...]


def _dotted(tag: str, what: str) -> str:
    """A Tag "Root/Child/@Attr" as the path "Root.Child.Attr" (ValueError for anything else)."""
    parts = tag.split("/")
    if len(parts) < 2 or not parts[-1].startswith("@") or any(not p.lstrip("@").isidentifier() for p in parts):
        raise ValueError(f"{what}: element Tag {tag!r} is not Root/.../@Attribute")
    return ".".join(p.lstrip("@") for p in parts)


def read_eki(xml: bytes, what: str = EKI_FILE) -> EkiConfig:
    root = ET.fromstring(xml)
    if root.tag != "ETHERNETKRL":
        raise ValueError(f"{what}: root <{root.tag}>, expected <ETHERNETKRL>")
    kind = (root.findtext("CONFIGURATION/EXTERNAL/TYPE") or "").strip()
    port_text = (root.findtext("CONFIGURATION/INTERNAL/PORT") or "").strip()
    protocol = (root.findtext("CONFIGURATION/INTERNAL/PROTOCOL") or "").strip().lower()
    if kind not in ("Client", "Server") or not port_text.isdigit() or protocol not in ("tcp", "udp"):
        raise ValueError(f"{what}: EXTERNAL/TYPE {kind!r}, INTERNAL/PORT {port_text!r}, PROTOCOL {protocol!r}")
    received = []
    for el in root.iterfind("RECEIVE/XML/ELEMENT"):
        kind_of = el.get("Type", "")
        if kind_of not in EKI_TYPES:
            raise ValueError(f"{what}: received element {el.get('Tag')!r} of Type {kind_of!r}, expected INT or REAL")
        received.append((_dotted(el.get("Tag", ""), what), EKI_TYPES[kind_of]))
    sent = tuple(_dotted(el.get("Tag", ""), what) for el in root.iterfind("SEND/XML/ELEMENT"))
    return EkiConfig(kind, int(port_text), protocol, tuple(received), sent)


@dataclass(frozen=True)
class RsiConfig:
    """An RSI ETHERNET object's file: SENTYPE, whether the controller expects answers, the <Rob> elements sent
    (DEF_<name>, then IPOC), the correction received (AK.A1..) and the plain elements received (TAG without a
    dot: Stop, the motion guard's stop, drivers.krc4.client)."""

    sen_type: str
    passive: bool
    port: int
    rob_elements: tuple[str, ...]
    correction: str
    correction_axes: tuple[str, ...]
    flags: tuple[str, ...] = ()


def read_rsi(xml: bytes, what: str = RSI_FILE) -> RsiConfig:
    root = ET.fromstring(xml)
    if root.tag != "ROOT" or root.find("CONFIG/PROTOCOL") is not None:
        raise ValueError(f"{what}: expected <ROOT><CONFIG> without PROTOCOL (RSI Ethernet on KSS 8 is UDP)")
    sen_type = (root.findtext("CONFIG/SENTYPE") or "").strip()
    onlysend = (root.findtext("CONFIG/ONLYSEND") or "").strip().upper()
    port = (root.findtext("CONFIG/PORT") or "").strip()
    send = [e.get("TAG", "") for e in root.iterfind("SEND/ELEMENTS/ELEMENT")]
    tags = [e.get("TAG", "") for e in root.iterfind("RECEIVE/ELEMENTS/ELEMENT")]
    receive = [t.split(".") for t in tags if "." in t]
    flags = tuple(t for t in tags if "." not in t)
    if not sen_type.isidentifier() or onlysend not in ("TRUE", "FALSE") or not port.isdigit():
        raise ValueError(f"{what}: SENTYPE {sen_type!r}, ONLYSEND {onlysend!r}, PORT {port!r}")
    if not send or any(not t.startswith("DEF_") for t in send):
        raise ValueError(f"{what}: SEND tags must be DEF_<element>, got {send}")
    if not receive or any(len(r) != 2 or r[0] != receive[0][0] for r in receive):
        raise ValueError(f"{what}: RECEIVE tags must be one <element>.<attribute> family")
    return RsiConfig(
        sen_type,
        onlysend == "TRUE",
        int(port),
        tuple(t[4:] for t in send) + ("IPOC",),
        receive[0][0],
        tuple(r[1] for r in receive),
        flags,
    )


def _bind(eki: EkiConfig, rsi: RsiConfig) -> None:
    """ValueError unless the KSS 8 files declare the documents the shared codecs speak."""
    if eki.external_type != "Client" or eki.protocol != "tcp":
        raise ValueError(f"{EKI_FILE}: trackcal connects over TCP (EXTERNAL/TYPE Client, PROTOCOL TCP)")
    if dict(eki.received) != dict(COMMAND.types) or len(eki.received) != len(COMMAND.types):
        raise ValueError(f"{EKI_FILE}: RECEIVE declares {eki.received}, the codec speaks {COMMAND.types}")
    if set(eki.sent) != set(STATE.tags) or len(eki.sent) != len(STATE.tags):
        raise ValueError(f"{EKI_FILE}: SEND declares {eki.sent}, the codec answers {STATE.tags}")
    if (
        set(rsi.rob_elements) != set(ROB_ELEMENTS)
        or rsi.sen_type != SEN_TYPE
        or (rsi.correction, rsi.correction_axes) != (KRC2_RSI.correction, KRC2_RSI.correction_axes)
        or rsi.flags != (STOP_ELEMENT,)
    ):
        raise ValueError(
            f"{RSI_FILE}: declares {rsi}, the codec reads {ROB_ELEMENTS} and answers "
            f"<Sen Type={SEN_TYPE!r}> {KRC2_RSI.correction} and <{STOP_ELEMENT}>"
        )


EKI = read_eki(config_text(EKI_FILE).encode())
RSI = read_rsi(config_text(RSI_FILE).encode())
_bind(EKI, RSI)
