"""ProgramRead.write: only the targets' text changes; notes go to the end of the target's line."""

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from trackcal.drivers.program_text import ProgramRead, ProgramTarget


def _target(text: str, start: int, end: int) -> ProgramTarget:
    return ProgramTarget(
        file="a.src",
        start=start,
        end=end,
        line=text.count("\n", 0, start) + 1,
        name="P1",
        joint=True,
        value=np.zeros(1),
        base=np.eye(4),
        tool=np.eye(4),
        config=(),
        accepts=lambda q: True,
        render=lambda v: f"{{A1 {v[0]:.1f}}}",
        motion="PTP",
    )


@given(st.text(alphabet=st.characters(min_codepoint=9, max_codepoint=126), max_size=200))
def test_no_change_is_byte_identical(text):
    program = ProgramRead(language="KRL", files={"a.src": text}, targets=[_target(text, 0, 0)], comment=";")
    assert program.write({}, {}) == {"a.src": text}


def test_value_replaced_and_note_at_line_end_before_crlf():
    text = "PTP {A1 0.0} C_PTP\r\nLIN P2\r\n"
    program = ProgramRead(language="KRL", files={"a.src": text}, targets=[_target(text, 4, 12)], comment=";")
    out = program.write({0: np.array([1.25])}, {0: "not compensated: outside\tlimits"})
    # the value's text replaced, the motion's other words and the next line untouched, the note before CR LF
    assert out["a.src"] == "PTP {A1 1.2} C_PTP ; not compensated: outside_limits\r\nLIN P2\r\n"
