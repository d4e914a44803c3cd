"""KUKA KR C2 codecs: golden bytes from public material, round trips, fuzzing, framing, config agreement."""

from __future__ import annotations

import contextlib
import xml.etree.ElementTree as ET

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from trackcal.drivers.errors import ProtocolError
from trackcal.drivers.kuka.eki_codec import (
    AXES,
    COMMAND,
    KIND_MOVE,
    KIND_RESET,
    KIND_STOP,
    MAX_DOC_BYTES,
    STATE,
    Command,
    RobotState,
    XmlStreamFramer,
    config_text,
    encode_command,
    encode_state,
    parse_attrs,
    parse_command,
    parse_real,
    parse_state,
    read_elements,
    read_template,
)
from trackcal.drivers.kuka.rsi_codec import (
    SHIPPED,
    RobFrame,
    SenFrame,
    encode_rob,
    encode_sen,
    ipoc_of,
    parse_rob,
    parse_sen,
    read_config,
    rob_framer,
)

# --- golden bytes -------------------------------------------------------------------------------------------

# The command/state documents of configs/krc2/README.md (ID 17, angles in degrees); the KR C2 start pose
# {A1 0, A2 -90, A3 90, A4 0, A5 90, A6 0} is the HOME of kuka_experimental
# kuka_rsi_hw_interface/krl/KR_C2/ros_rsi.src.
GOLDEN_COMMAND = (
    b'<RobotCommand ID="17" Kind="1" Speed="20"><Pos A1="0.0000" A2="-90.0000" A3="90.0000" A4="0.0000" A5="90.0000" '
    b'A6="0.0000"/></RobotCommand>'
)
GOLDEN_STATE = (
    b'<RobotState><Pos A1="0.0001" A2="-90.0000" A3="90.0000" A4="0.0000" A5="89.9999" A6="0.0000"/>'
    b'<RobotCommand ID="17" Done="1" Error="0"/></RobotState>'
)
# <Rob> as written by kuka_experimental kuka_rsi_simulator/scripts/kuka_rsi_simulator (RIst, RSol, AIPos,
# ASPos, Delay D, IPOC) with the RSI 2 4-decimal values; two LF end it on TCP (KR C2).
GOLDEN_ROB = (
    b'<Rob TYPE="KUKA"><RIst X="1050.0000" Y="0.0000" Z="1360.0000" A="0.0000" B="90.0000" C="0.0000"/>'
    b'<RSol X="1050.0000" Y="0.0000" Z="1360.0000" A="0.0000" B="90.0000" C="0.0000"/>'
    b'<AIPos A1="0.0000" A2="-90.0000" A3="90.0000" A4="0.0000" A5="90.0000" A6="0.0000"/>'
    b'<ASPos A1="0.0000" A2="-90.0000" A3="90.0000" A4="0.0000" A5="90.0000" A6="0.0000"/>'
    b'<Delay D="0"/><IPOC>4208163</IPOC></Rob>\n\n'
)
# KR C2 first frame: only an empty IPOC (kuka_experimental pull request #74).
GOLDEN_FIRST_ROB = b'<Rob TYPE="KUKA"><IPOC/></Rob>\n\n'
# <Sen Type="ImFree"><AK A1..A6/><IPOC/></Sen>: kuka_experimental kuka_rsi_hw_interface rsi_command.h.
GOLDEN_SEN = (
    b'<Sen Type="ImFree"><AK A1="0.0000" A2="0.0000" A3="0.0000" A4="0.0000" A5="0.0000" A6="0.0000"/>'
    b"<IPOC>4208163</IPOC></Sen>"
)
HOME = (0.0, -90.0, 90.0, 0.0, 90.0, 0.0)


def test_golden_command():
    assert encode_command(Command(17, KIND_MOVE, HOME, 20)) == GOLDEN_COMMAND
    assert parse_command(GOLDEN_COMMAND) == Command(17, KIND_MOVE, HOME, 20)


def test_golden_state():
    state = RobotState((0.0001, -90.0, 90.0, 0.0, 89.9999, 0.0), 17, True, 0)
    assert encode_state(state) == GOLDEN_STATE
    assert parse_state(GOLDEN_STATE) == state
    # KRL may write booleans as TRUE/FALSE: accepted too
    assert parse_state(GOLDEN_STATE.replace(b'Done="1"', b'Done="TRUE"')).done is True


def test_golden_rob_and_first_frame():
    frame = parse_rob(GOLDEN_ROB)
    assert frame.ipoc == 4208163
    assert frame.aipos == HOME and frame.aspos == HOME
    assert frame.rist == (1050.0, 0.0, 1360.0, 0.0, 90.0, 0.0)
    assert frame.delay == 0
    assert encode_rob(frame, tcp=True) == GOLDEN_ROB
    assert parse_rob(GOLDEN_FIRST_ROB) == RobFrame(ipoc=None)
    assert encode_rob(RobFrame(ipoc=None), tcp=True) == GOLDEN_FIRST_ROB


def test_golden_sen():
    assert encode_sen(SenFrame(4208163)) == GOLDEN_SEN
    assert parse_sen(GOLDEN_SEN) == SenFrame(4208163)


def test_negative_zero_is_written_as_zero():
    assert b'A1="0.0000"' in encode_command(Command(1, KIND_MOVE, (-0.00001, 0, 0, 0, 0, 0), 5))


@pytest.mark.parametrize(
    "data",
    [
        b'<!DOCTYPE r [<!ENTITY a "aaaa">]><RobotState>&a;</RobotState>',  # entity definition
        b'<?xml version="1.0"?><!DOCTYPE r SYSTEM "file:///etc/passwd"><RobotState/>',  # XXE
        b"<RobotState><!-- c --><Pos/></RobotState>",
        b"<RobotState>&undefined;</RobotState>",
        b"<RobotState>" + b"<x>" * 20 + b"</RobotState>",
        b"<Other/>",
        b"",
        b"\xff\xfe<",
        b'<RobotState><Pos A1="nan" A2="0" A3="0" A4="0" A5="0" A6="0"/>'
        b'<RobotCommand ID="1" Done="1" Error="0"/></RobotState>',
        b'<RobotState><Pos A1="1e999" A2="0" A3="0" A4="0" A5="0" A6="0"/>'
        b'<RobotCommand ID="1" Done="1" Error="0"/></RobotState>',
        b'<RobotState><Pos A1="0" A2="0" A3="0" A4="0" A5="0" A6="0"/>'
        b'<RobotCommand ID="1" Done="maybe" Error="0"/></RobotState>',
        b"<RobotState>" + b" " * MAX_DOC_BYTES + b"</RobotState>",
    ],
)
def test_bad_state_documents_are_protocol_errors(data):
    with pytest.raises(ProtocolError):
        parse_state(data)


def test_billion_laughs_is_refused_before_parsing():
    lol = b'<!DOCTYPE lolz [<!ENTITY lol "lol">' + b"".join(
        b'<!ENTITY lol%d "%s">' % (i, (b"&lol%d;" % (i - 1) if i > 1 else b"&lol;") * 10) for i in range(1, 10)
    )
    with pytest.raises(ProtocolError, match="DOCTYPE"):
        parse_rob(lol + b"]><Rob><IPOC>&lol9;</IPOC></Rob>")


def test_bad_command_values():
    with pytest.raises(ProtocolError, match="Speed"):
        parse_command(GOLDEN_COMMAND.replace(b'Speed="20"', b'Speed="101"'))
    with pytest.raises(ProtocolError, match="ID"):
        parse_command(GOLDEN_COMMAND.replace(b'ID="17"', b'ID="0"'))
    with pytest.raises(ProtocolError, match="A6"):
        parse_command(GOLDEN_COMMAND.replace(b' A6="0.0000"', b""))
    with pytest.raises(ProtocolError, match="Kind"):
        parse_command(GOLDEN_COMMAND.replace(b'Kind="1"', b'Kind="4"'))
    with pytest.raises(ValueError):
        encode_command(Command(1, KIND_MOVE, HOME, 0))  # a move needs a speed
    with pytest.raises(ValueError):
        encode_command(Command(1, 7))


def test_stop_and_reset_carry_every_element():
    # every declared element in every document (configs/krc2/TrackcalEki.xml): a stop names the move it stops
    for kind in (KIND_STOP, KIND_RESET):
        doc = encode_command(Command(17, kind))
        assert doc.startswith(f'<RobotCommand ID="17" Kind="{kind}" Speed="0"><Pos A1="0.0000"'.encode())
        assert parse_command(doc) == Command(17, kind)


def test_rob_needs_aipos_when_ipoc_given():
    with pytest.raises(ProtocolError, match="AIPos"):
        parse_rob(b'<Rob TYPE="KUKA"><IPOC>12</IPOC></Rob>')
    with pytest.raises(ProtocolError, match="IPOC"):
        parse_sen(b'<Sen Type="ImFree"><AK A1="0" A2="0" A3="0" A4="0" A5="0" A6="0"/><IPOC/></Sen>')


# --- round trips and fuzz -----------------------------------------------------------------------------------

angles = st.floats(-400.0, 400.0, allow_nan=False)
joints = st.tuples(angles, angles, angles, angles, angles, angles)


def rounded(q):
    return tuple(round(v, 4) + 0.0 for v in q)


@given(st.integers(1, 2**31 - 1), joints, st.integers(1, 100))
def test_command_round_trip(cid, q, speed):
    back = parse_command(encode_command(Command(cid, KIND_MOVE, q, speed)))
    assert back.command_id == cid and back.speed_pct == speed
    assert all(abs(a - b) <= 0.00005 + 1e-9 for a, b in zip(back.target_deg, q, strict=True))


@given(joints, st.integers(0, 2**31 - 1), st.booleans(), st.integers(0, 99))
def test_state_round_trip(q, cid, done, err):
    state = RobotState(rounded(q), cid, done, err)
    assert parse_state(encode_state(state)) == state


@given(st.integers(0, 2**63 - 1), joints, joints, st.integers(0, 10**6), st.booleans())
def test_rob_round_trip(ipoc, q, qs, delay, tcp):
    frame = RobFrame(ipoc, rounded(q), rounded(qs), (0.0,) * 6, (0.0,) * 6, delay)
    assert parse_rob(encode_rob(frame, tcp=tcp)) == frame


@given(st.binary(max_size=600))
@settings(max_examples=300)
def test_parsers_are_total_on_random_bytes(data):
    for parse in (parse_command, parse_state, parse_rob, parse_sen):
        with contextlib.suppress(ProtocolError):
            parse(data)


xml_ish = st.lists(
    st.sampled_from(
        [
            b"<",
            b">",
            b"/",
            b'"',
            b"'",
            b"=",
            b" ",
            b"\n",
            b"Rob",
            b"IPOC",
            b"AIPos",
            b"A1",
            b"1.5",
            b"<?xml",
            b"?>",
            b"<!",
            b"&",
            b"TYPE",
            b"Sen",
            b"RobotState",
            b"\x00",
            b"</Rob>",
        ]
    ),
    max_size=60,
).map(b"".join)


@given(xml_ish)
@settings(max_examples=300)
def test_parsers_are_total_on_xml_like_bytes(data):
    for parse in (parse_command, parse_state, parse_rob, parse_sen):
        with contextlib.suppress(ProtocolError):
            parse(data)


@given(st.one_of(st.binary(max_size=3000), xml_ish), st.lists(st.integers(1, 64), max_size=20))
@settings(max_examples=200)
def test_framer_is_total_and_bounded(data, cuts):
    framer = XmlStreamFramer("Rob", max_doc_bytes=512)
    pos = 0
    try:
        for size in [*cuts, len(data)]:
            for doc in framer.feed(data[pos : pos + size]):
                assert len(doc) <= 512
            pos += size
            assert framer.pending <= 512 + 64 + len(data)
    except ProtocolError:
        pass


@given(
    st.lists(st.tuples(st.integers(0, 10**12), joints), min_size=1, max_size=5),
    st.lists(st.integers(1, 200), max_size=30),
)
def test_framer_reassembles_documents_across_arbitrary_cuts(frames, cuts):
    docs = [RobFrame(ipoc, rounded(q), rounded(q), (0.0,) * 6, (0.0,) * 6, 0) for ipoc, q in frames]
    stream = GOLDEN_FIRST_ROB + b"".join(encode_rob(f, tcp=True) for f in docs)
    framer = rob_framer()
    out, pos = [], 0
    for size in [*cuts, len(stream)]:
        out += framer.feed(stream[pos : pos + size])
        pos += size
    assert [parse_rob(d) for d in out] == [RobFrame(None), *docs]
    assert framer.pending == 0


def test_framer_several_documents_in_one_read_and_declaration():
    framer = XmlStreamFramer("RobotState")
    two = GOLDEN_STATE + b"\r\n" + b'<?xml version="1.0"?>\n' + GOLDEN_STATE
    assert framer.feed(two[:10]) == []
    docs = framer.feed(two[10:])
    assert len(docs) == 2 and all(parse_state(d).command_id == 17 for d in docs)


def test_framer_rejects_garbage_and_oversize_and_stays_failed():
    framer = XmlStreamFramer("Rob", max_doc_bytes=200)
    with pytest.raises(ProtocolError, match="expected <Rob>"):
        framer.feed(b"HELLO")
    with pytest.raises(ProtocolError):
        framer.feed(GOLDEN_FIRST_ROB)
    framer = XmlStreamFramer("Rob", max_doc_bytes=200)
    with pytest.raises(ProtocolError, match="200"):
        framer.feed(b"<Rob " + b"x" * 300)
    with pytest.raises(ProtocolError):
        XmlStreamFramer("Rob").feed(b"<Robot/>")
    with pytest.raises(ProtocolError):
        XmlStreamFramer("Rob").feed(b"<!DOCTYPE x><Rob/>")


def test_framer_quoted_gt_and_self_closing_root():
    framer = XmlStreamFramer("RobotState")
    assert framer.feed(b'<RobotState a="x>y"/><RobotState></RobotState >') == [
        b'<RobotState a="x>y"/>',
        b"<RobotState></RobotState >",
    ]


# --- the shipped controller configs are the codecs' source of truth ---------------------------------------


def test_the_codec_reads_its_names_from_the_channel_files():
    assert COMMAND.tags == tuple(e.get("Tag") for e in _elements() if e.get("Type") != "STRUCTTAG")
    assert STATE.tags == (
        *(f"RobotState.Pos.A{i}" for i in range(1, 7)),
        "RobotState.RobotCommand.ID",
        "RobotState.RobotCommand.Done",
        "RobotState.RobotCommand.Error",
    )
    # a renamed attribute in the file renames it on the wire: the file, not the code, holds the names
    renamed = config_text("TrackcalEki.xml").replace("RobotCommand.Speed", "RobotCommand.Override")
    assert read_elements(renamed.encode()).attrs == ("ID", "Kind", "Override")


def _elements():
    return list(ET.fromstring(config_text("TrackcalEki.xml")).iter("Element"))


@pytest.mark.parametrize(
    "xml, why",
    [
        (b'<Elements><Element Tag="A.B" Type="REAL"/></Elements>', "no declared STRUCTTAG"),
        (b'<Elements><Element Tag="A" Type="STRUCTTAG"/><Element Tag="A.B" Type="TEXT"/></Elements>', "type"),
        (b"<Other/>", "expected <Elements>"),
    ],
)
def test_bad_element_files_are_refused(xml, why):
    with pytest.raises(ValueError, match=why):
        read_elements(xml)
    with pytest.raises(ValueError, match="two levels"):
        read_template(b'<R><P><Q a=""/></P></R>')


def test_the_shipped_rsi_config():
    # UDP as ros-industrial/kuka_experimental KR_C2/ros_rsi_ethernet.xml; passive by default (configs/krc2/README.md)
    assert (SHIPPED.protocol, SHIPPED.passive, SHIPPED.sen_type) == ("udp", True, "ImFree")
    assert SHIPPED.rob_elements == ("RIst", "RSol", "AIPos", "ASPos", "Delay", "IPOC")
    answered = config_text("trackcal_rsi.xml").replace("<ONLYSEND>TRUE", "<ONLYSEND>FALSE")
    assert read_config(answered.encode()).passive is False
    with pytest.raises(ValueError, match="PROTOCOL"):
        read_config(config_text("trackcal_rsi.xml").replace("<PROTOCOL>UDP", "<PROTOCOL>SCTP").encode())


def test_ipoc_of_finds_the_frames_ipoc_without_parsing():
    assert ipoc_of(GOLDEN_ROB) == 4208163
    assert ipoc_of(GOLDEN_FIRST_ROB) is None
    assert ipoc_of(b"<Rob><IPOC> 12 </IPOC>garbage") == 12  # the answer thread answers; the monitor refuses


@given(st.binary(max_size=600))
def test_ipoc_of_never_raises(data):
    value = ipoc_of(data)
    assert value is None or 0 <= value <= 2**63 - 1


@given(st.integers(0, 2**63 - 1), joints)
def test_ipoc_of_agrees_with_the_parser(ipoc, q):
    frame = encode_rob(RobFrame(ipoc=ipoc, aipos=rounded(q)), tcp=False)
    assert ipoc_of(frame) == parse_rob(frame).ipoc == ipoc


def _per_attribute(element, names, what, limit):
    """parse_attrs as it was: parse_real on every attribute, each named (the reference of the fast path)."""
    if element is None:
        raise ProtocolError(f"<{what}> is missing")
    return tuple(parse_real(element.get(n), f"{what}/@{n}", limit) for n in names)


def _outcome(parse, *args):
    try:
        return parse(*args)
    except ProtocolError as exc:
        return f"ProtocolError: {exc}"


attribute_text = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.floats(-1e5, 1e5).map(lambda v: f"{v:.4f}"),
    st.text(alphabet=" +-.0123456789eEinfa", max_size=45),
)


@given(st.lists(st.one_of(st.none(), attribute_text), min_size=6, max_size=6), st.sampled_from([1e4, 1e6]))
def test_parse_attrs_equals_parse_real_of_each_attribute(texts, limit):
    element = ET.Element("AIPos", {n: t for n, t in zip(AXES, texts, strict=True) if t is not None})
    assert _outcome(parse_attrs, element, AXES, "Rob/AIPos", limit) == _outcome(
        _per_attribute, element, AXES, "Rob/AIPos", limit
    )
