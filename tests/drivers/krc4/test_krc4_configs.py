"""configs/krc4 (KSS 8) against the shared codecs: the EthernetKRL 3.x file and the RSI ETHERNET file declare the
documents drivers/kuka's codecs speak, and the KRL program reads and writes only what the EKI file declares, on the
channel and RSI context the files name."""

from __future__ import annotations

import re

import pytest

from trackcal.drivers.krc4.configs import CHANNEL, EKI, EKI_FILE, RSI, RSI_CONTEXT, config_text, read_eki, read_rsi
from trackcal.drivers.krc4.configs import _bind as bind
from trackcal.drivers.kuka.eki_codec import COMMAND, STATE

SRC = config_text("trackcal_eki.src")
DAT = config_text("trackcal_eki.dat")


def test_the_eki_file_declares_the_kr_c2_documents_with_kss8_paths():
    # kuka_eki_hw_interface/krl/EkiHwInterface.xml: EXTERNAL/TYPE Client, INTERNAL/PORT in 54600..54615
    assert EKI.external_type == "Client" and 54600 <= EKI.port <= 54615 and EKI.protocol == "tcp"
    assert dict(EKI.received) == dict(COMMAND.types)
    assert set(EKI.sent) == set(STATE.tags)


def test_the_rsi_file_is_a_kss8_ethernet_object_answered_with_ak_corrections():
    # KR_C4_RSI_4+/ros_rsi_ethernet.xml: SENTYPE ImFree, ONLYSEND FALSE, AK.A1..AK.A6 received, no PROTOCOL
    assert RSI.sen_type == "ImFree" and RSI.passive is False
    assert RSI.correction == "AK" and RSI.correction_axes == ("A1", "A2", "A3", "A4", "A5", "A6")
    assert set(RSI.rob_elements) == {"RIst", "RSol", "AIPos", "ASPos", "Delay", "IPOC"}


@pytest.mark.parametrize(
    "old, new, message",
    [
        ("<TYPE>Client</TYPE>", "<TYPE>Server</TYPE>", "trackcal connects"),
        ('Tag="RobotCommand/@Speed" Type="INT"', 'Tag="RobotCommand/@Speed" Type="REAL"', "RECEIVE declares"),
        ('<ELEMENT Tag="RobotState/RobotCommand/@Error" />', "", "SEND declares"),
    ],
)
def test_a_file_that_declares_another_document_is_refused(old, new, message):
    text = config_text(EKI_FILE)
    assert old in text
    with pytest.raises(ValueError, match=message):
        bind(read_eki(text.replace(old, new).encode()), RSI)


def test_an_rsi_file_with_a_protocol_element_is_a_kr_c2_file():
    text = config_text("trackcal_rsi_ethernet.xml").replace("<CONFIG>", "<CONFIG><PROTOCOL>TCP</PROTOCOL>")
    with pytest.raises(ValueError, match="without PROTOCOL"):
        read_rsi(text.encode())


def _code(text: str) -> str:
    return "\n".join(line.split(";", 1)[0] for line in text.splitlines())


def test_the_krl_reads_and_writes_only_declared_elements_of_its_channel():
    code = _code(SRC)
    received = {path for path, _ in EKI.received}
    calls = re.findall(r'EKI_(\w+)\("([^"]*)"(?:,\s*"([^"]*)")?', code)
    assert {name for name, _, _ in calls} >= {
        "Init",
        "Open",
        "CheckBuffer",
        "GetInt",
        "GetReal",
        "SetReal",
        "SetInt",
        "Send",
        "Clear",
    }
    for name, channel, path in calls:
        assert channel == CHANNEL, (name, channel)
        dotted = path.replace("/@", ".").replace("/", ".")
        if name in ("GetInt", "GetReal", "CheckBuffer"):
            assert dotted in received, path
        elif name in ("SetInt", "SetReal"):
            assert dotted in EKI.sent, path
        elif name == "Send":
            assert path == STATE.root
    # every value the program reads or writes, once each
    assert {p.replace("/@", ".").replace("/", ".") for n, _, p in calls if n.startswith("Get")} == received
    assert {p.replace("/@", ".").replace("/", ".") for n, _, p in calls if n.startswith("Set")} == set(EKI.sent)


def test_the_krl_uses_kss8_declarations_and_the_rsi_context():
    # kuka_eki_hw_interface.src: "decl eki_status eki_ret", "eki_ret = eki_init(...)";
    # KR_C4_RSI_4+/ros_rsi.src: "ret = RSI_CREATE("ros_rsi",CONTID,TRUE)", "ret = RSI_ON(#ABSOLUTE)"
    assert re.search(r"^DECL EKI_STATUS RET$", _code(DAT), re.M)
    assert f'RSI_CREATE("{RSI_CONTEXT}", nContId, TRUE)' in SRC and "RSI_ON(#ABSOLUTE)" in SRC
    assert "EKX_" not in _code(SRC) and "ST_ETHERNET" not in _code(SRC)  # no KR C2 (KSS 5) call is left
    declared = set()
    for names in re.findall(r"^\s*DECL \w+ (.+)$", _code(SRC) + "\n" + _code(DAT), re.M):
        declared |= {re.match(r"\s*(\w+)", part)[1] for part in names.split(",")}
    used = set(re.findall(r"\b([nrbx][A-Z]\w*)\b", _code(SRC)))
    assert used <= declared, used - declared  # every variable of the program is declared (.dat or its routine)
