"""The <Rob> parser's fast path (issue 41): a frame in encode_rob's own layout is read by one regular expression
instead of ElementTree, with the values the XML path reads from the same bytes; anything else takes the XML path,
its checks and its messages. The encoder's one %-template writes the bytes the per-attribute formatting (fmt4:
4 decimals, never "-0.0000") wrote."""

import xml.etree.ElementTree as ET

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from trackcal.drivers.errors import ProtocolError
from trackcal.drivers.kuka import rsi_codec
from trackcal.drivers.kuka.eki_codec import AXES, fmt4
from trackcal.drivers.kuka.rsi_codec import CART, RobFrame, encode_rob, parse_rob

angles = st.floats(-1.0e4, 1.0e4, allow_nan=False)  # AXIS_LIMIT
carts = st.floats(-1.0e6, 1.0e6, allow_nan=False)  # CART_LIMIT
six_angles = st.tuples(*[angles] * 6)
six_carts = st.tuples(*[carts] * 6)
frames = st.builds(
    RobFrame,
    ipoc=st.integers(0, 2**63 - 1),
    aipos=six_angles,
    aspos=st.none() | six_angles,
    rist=st.none() | six_carts,
    rsol=st.none() | six_carts,
    delay=st.none() | st.integers(0, 2**31 - 1),
)


def attribute_by_attribute(frame: RobFrame) -> bytes:
    """encode_rob as written before the template: each element's attributes formatted by fmt4 one by one."""
    zero = (0.0,) * 6

    def attrs(tag, names, values):
        return f"<{tag} " + " ".join(f'{n}="{fmt4(float(v))}"' for n, v in zip(names, values, strict=True)) + "/>"

    return (
        f'<Rob TYPE="KUKA">{attrs("RIst", CART, frame.rist or zero)}{attrs("RSol", CART, frame.rsol or zero)}'
        f"{attrs('AIPos', AXES, frame.aipos or zero)}{attrs('ASPos', AXES, frame.aspos or frame.aipos or zero)}"
        f'<Delay D="{int(frame.delay or 0)}"/><IPOC>{frame.ipoc}</IPOC></Rob>'
    ).encode()


def through_xml(data: bytes) -> RobFrame:
    """parse_rob with the fast path switched off: the XML path alone."""
    with pytest.MonkeyPatch.context() as m:
        m.setattr(rsi_codec, "_parse_rob_fast", lambda data: None)
        return parse_rob(data)


@settings(max_examples=300, deadline=None)
@given(frame=frames)
def test_the_template_writes_the_bytes_of_the_attribute_by_attribute_encoder(frame):
    assert encode_rob(frame, tcp=False) == attribute_by_attribute(frame)


@settings(max_examples=300, deadline=None)
@given(frame=frames, tcp=st.booleans())
def test_a_frame_of_the_encoder_is_read_fast_with_the_values_of_the_xml_path(frame, tcp):
    data = encode_rob(frame, tcp=tcp)
    fast = rsi_codec._parse_rob_fast(data.strip())
    assert fast is not None
    assert fast == through_xml(data) == parse_rob(data)


def test_the_encoder_s_frame_is_read_without_an_xml_parse(monkeypatch):
    """Fails before issue 41: every frame went through ElementTree."""
    frame = RobFrame(ipoc=1000, aipos=(0.0, -90.0, 90.0, 0.0, 90.0, 0.0), delay=0)
    data = encode_rob(frame, tcp=False)

    def no_xml(*args, **kwargs):
        raise AssertionError("an XML parse")

    monkeypatch.setattr(ET, "fromstring", no_xml)
    assert parse_rob(data).aipos == (0.0, -90.0, 90.0, 0.0, 90.0, 0.0)


def read_alike_when_changed(frame: RobFrame, at: int, byte: int, reference, reader) -> None:
    """The encoder's frame with one byte changed: `reader` reads what `reference` reads, or refuses it as it does."""
    data = bytearray(encode_rob(frame, tcp=False))
    data[at % len(data)] = byte
    try:
        expected = reference(bytes(data))
    except ProtocolError:
        with pytest.raises(ProtocolError):
            reader(bytes(data))
        return
    assert reader(bytes(data)) == expected


@settings(max_examples=500, deadline=None)
@given(frame=frames, at=st.integers(0, 10**6), byte=st.integers(0, 255))
def test_a_frame_changed_anywhere_is_read_as_the_xml_path_reads_it_or_refused_as_it_refuses_it(frame, at, byte):
    read_alike_when_changed(frame, at, byte, through_xml, parse_rob)


@pytest.mark.parametrize("value, element", [(10000.0001, "AIPos"), (1000000.0001, "RIst")])
def test_a_value_past_the_limits_takes_the_xml_path_and_its_message(value, element):
    frame = RobFrame(
        ipoc=5,
        aipos=(value if element == "AIPos" else 0.0,) + (0.0,) * 5,
        rist=(value if element == "RIst" else 0.0,) + (0.0,) * 5,
    )
    with pytest.raises(ProtocolError, match=f"Rob/{element}/@"):
        parse_rob(encode_rob(frame, tcp=False))


def joints_of_parse_rob(data: bytes) -> tuple:
    """What the client kept of a frame before rob_joints: parse_rob's IPOC and its AIPos rounded to 4 decimals."""
    frame = parse_rob(data)
    return frame.ipoc, None if frame.aipos is None else tuple(round(v, 4) for v in frame.aipos)


@settings(max_examples=300, deadline=None)
@given(frame=frames, tcp=st.booleans())
def test_the_client_s_joints_of_an_encoder_frame_are_parse_rob_s_rounded(frame, tcp):
    data = encode_rob(frame, tcp=tcp)
    joints = rsi_codec.rob_joints(data)
    assert joints == joints_of_parse_rob(data)
    assert [str(v) for v in joints[1]] == [str(v) for v in joints_of_parse_rob(data)[1]]  # -0.0 stays -0.0


@settings(max_examples=500, deadline=None)
@given(frame=frames, at=st.integers(0, 10**6), byte=st.integers(0, 255))
def test_the_client_s_joints_of_a_changed_frame_are_parse_rob_s_or_refused_as_it_refuses_it(frame, at, byte):
    read_alike_when_changed(frame, at, byte, joints_of_parse_rob, rsi_codec.rob_joints)


@pytest.mark.parametrize("value, element", [(1000000.0, "RIst"), (10000.0, "AIPos"), (123.45678, "AIPos")])
def test_the_client_s_joints_past_the_digit_bounds_are_read_by_parse_rob(value, element):
    """1e6 and 1e4 are inside the limits but past the digits the joints' reading accepts alone; an AIPos of more
    than 4 decimals (another layout) is rounded."""
    aipos = (value if element == "AIPos" else 0.0,) + (1.5,) * 5
    rist = (value if element == "RIst" else 0.0,) + (0.0,) * 5
    data = encode_rob(RobFrame(ipoc=7, aipos=aipos, rist=rist), tcp=False).replace(b"123.4568", b"123.45678")
    assert rsi_codec._JOINTS_ROB.fullmatch(data.decode()) is None
    assert rsi_codec.rob_joints(data) == (7, (round(aipos[0], 4), 1.5, 1.5, 1.5, 1.5, 1.5))


def test_the_first_frame_of_the_kr_c2_has_no_joints():
    assert rsi_codec.rob_joints(encode_rob(RobFrame(ipoc=None), tcp=True)) == (None, None)
