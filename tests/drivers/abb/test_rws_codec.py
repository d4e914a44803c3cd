"""The RWS client's pure parts (drivers/abb/rws.py, program.py): HTTP digest against the RFC's own worked example,
the challenge parser and the JSON answer's items fuzzed, and the RAPID module's text."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from trackcal.drivers.abb.program import MODULE, joint_value, module_text, symbol_path
from trackcal.drivers.abb.rws import digest_response, parse_challenge, states

# RFC 2617 section 3.5, the worked example: user Mufasa, password "Circle Of Life", GET /dir/index.html
RFC2617_CHALLENGE = (
    'Digest realm="testrealm@host.com", qop="auth,auth-int", '
    'nonce="dcd98b7102dd2f0e8b11d0f600bfb0c093", '
    'opaque="5ccc069c403ebaf9f0171e9517f40e41"'
)
RFC2617_RESPONSE = "6629fae49393a05397450978507c4ef1"  # the example's response field


def test_digest_answers_the_rfc_2617_example():
    challenge = parse_challenge(RFC2617_CHALLENGE)
    assert challenge["realm"] == "testrealm@host.com" and challenge["qop"] == "auth,auth-int"
    header = digest_response("Mufasa", "Circle Of Life", "GET", "/dir/index.html", challenge, 1, "0a4f113b")
    fields = parse_challenge(header)
    assert fields["response"] == RFC2617_RESPONSE
    assert fields["nc"] == "00000001" and fields["cnonce"] == "0a4f113b" and fields["qop"] == "auth"
    assert fields["opaque"] == "5ccc069c403ebaf9f0171e9517f40e41"


def test_a_challenge_of_another_scheme_is_no_digest_challenge():
    assert parse_challenge('Basic realm="x"') == {}


@given(st.text(max_size=200))
def test_the_challenge_parser_takes_any_header(text):
    assert isinstance(parse_challenge(text), dict)


def test_state_items_of_an_rws_json_answer():
    # the shape of the Robot Web Services manual's JSON answers: _embedded._state, one item per XHTML li
    doc = {
        "_links": {},
        "_embedded": {"_state": [{"_type": "pnl-ctrlstate", "_title": "ctrlstate", "ctrlstate": "motoron"}]},
    }
    assert states(doc)[0]["ctrlstate"] == "motoron"


@given(
    st.recursive(
        st.none() | st.booleans() | st.integers() | st.text(max_size=5),
        lambda c: st.lists(c, max_size=3) | st.dictionaries(st.text(max_size=10), c, max_size=3),
    )
)
def test_any_json_is_items_or_a_value_error(doc):
    try:
        items = states(doc)
    except ValueError:
        return
    assert all(isinstance(i, dict) for i in items)


def test_the_rapid_module_declares_its_variables_and_moves_absolutely():
    text = module_text()
    assert text.startswith(f"MODULE {MODULE}\r\n") and text.endswith("ENDMODULE\r\n")
    for decl in (
        "PERS jointtarget trackcal_target :=",
        "PERS num trackcal_speed :=",
        "PERS num trackcal_move :=",
        "PERS num trackcal_done :=",
    ):
        assert decl in text
    assert "MoveAbsJ trackcal_target, v5000, fine, tool0;" in text
    assert "trackcal_done := trackcal_move;" in text


@pytest.mark.parametrize(
    ("q", "text"),
    [
        (
            (0, -0.00001, 12.34567, -165, 30, 400),
            "[[0.0000,0.0000,12.3457,-165.0000,30.0000,400.0000],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]]",
        ),
    ],
)
def test_a_jointtarget_value_has_six_axes_at_four_decimals_and_no_external_axes(q, text):
    assert joint_value(q) == text


def test_the_symbols_are_the_modules_in_t_rob1():
    assert symbol_path("trackcal_done") == "rw/rapid/symbol/data/RAPID/T_ROB1/TrackcalRws/trackcal_done"
