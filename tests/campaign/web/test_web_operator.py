"""One prompt, several operators (issue 22): the console, the cell's button and the operator's page are offered
the same prompt; the first answer wins, the others are withdrawn; one that can no longer answer drops out and
leaves the others in charge; the page's server dying leaves the console in charge."""

import io
import queue
import threading
import time

import pytest
from rich.console import Console

from trackcal.campaign.cells.operator import FirstAnswer, PlcOperator
from trackcal.campaign.cli.console import ConsoleOperator
from trackcal.campaign.web.hub import PageOperator
from trackcal.drivers.errors import ConnectionLost
from trackcal.drivers.interfaces import SharedOperator


class Scripted:
    """An operator that answers `answer` at its `at`-th poll (never: None), or loses its link there."""

    def __init__(self, name, at=None, lost_at=None):
        self.name, self.at, self.lost_at, self.polls, self.log = name, at, lost_at, 0, []

    def offer(self, kind, target, text):
        self.polls = 0
        self.log.append(("offer", kind, target))

    def poll(self):
        self.polls += 1
        if self.lost_at is not None and self.polls >= self.lost_at:
            raise ConnectionLost(f"{self.name} gone", device=self.name)
        return self.name if self.at is not None and self.polls >= self.at else None

    def withdraw(self):
        self.log.append(("withdraw",))


def first_answer(ops, **kw):
    lines = []
    return FirstAnswer(ops, lines.append, poll_s=0.0, sleep=lambda s: None, **kw), lines


def test_the_first_answer_wins_and_the_others_are_withdrawn():
    console, page, button = Scripted("console", at=5), Scripted("page", at=2), Scripted("plc")
    op, _ = first_answer([button, console, page])
    assert isinstance(page, SharedOperator)
    assert op.ask("move_reflector", "P2", "put the reflector on P2") == "page"
    assert console.log == [("offer", "move_reflector", "P2"), ("withdraw",)]
    assert button.log[-1] == ("withdraw",) and page.log == [("offer", "move_reflector", "P2")]


def test_an_operator_that_is_gone_drops_out_and_the_others_answer():
    console, page = Scripted("console", lost_at=1), Scripted("page", at=3)
    op, lines = first_answer([console, page])
    assert op.ask("resume", "", "resume") == "page"
    assert op.operators == [page] and "console gone" in lines[0] and "1 other way to answer left" in lines[0]
    assert op.ask("resume", "", "again") == "page"  # the console stays out


def test_when_every_operator_is_gone_the_campaign_stops_as_for_one_that_does_not_answer():
    op, _ = first_answer([Scripted("console", lost_at=1), Scripted("page", lost_at=2)])
    with pytest.raises(ConnectionLost, match="no operator can answer"):
        op.ask("resume", "", "resume")


def test_the_cell_is_watched_while_a_prompt_waits():
    seen = []
    op, _ = first_answer([Scripted("page", at=4)], watch=lambda: seen.append(1), watch_s=0.0)
    op.ask("resume", "", "resume")
    assert len(seen) == 3  # between the polls, in the caller's thread


class FakeHub:
    def __init__(self):
        self.lock, self.events, self.live, self._answer, self.up = threading.Lock(), [], {}, None, True

    def set_live(self, **kw):
        self.live.update(kw)

    def alive(self):
        return self.up


def test_a_page_whose_server_died_leaves_the_console_in_charge():
    hub = FakeHub()
    page, console = PageOperator(hub), Scripted("console", at=3)
    op, lines = first_answer([console, page])
    hub.up = False  # the server thread ended
    assert op.ask("resume", "", "resume") == "console"
    assert op.operators == [console] and "operator's page stopped" in lines[0]


def shared_console():
    """A console whose keyboard is a queue: lines typed once the prompt is shown ("" is the end of input)."""
    keys = queue.SimpleQueue()
    out = io.StringIO()
    return ConsoleOperator(Console(file=out, width=200), readline=keys.get), keys, out


def poll_until(op, stop, n=100000):
    for _ in range(n):
        answer = op.poll()
        if stop(answer):
            return answer
        time.sleep(0.0005)
    raise AssertionError("no answer")


def test_the_console_shares_a_prompt_and_asks_for_its_word():
    op, keys, out = shared_console()
    op.offer("resume", "", "Leave the cell")
    keys.put("done\n")  # the word of the other prompts
    poll_until(op, lambda a: "not an acknowledgement" in out.getvalue())
    keys.put(" Resume \n")
    assert poll_until(op, lambda a: a is not None) == "console"
    assert "expected 'resume'" in out.getvalue()


def test_the_console_at_the_end_of_its_input_drops_out():
    op, keys, _ = shared_console()
    op.offer("change_station", "S1", "move the tracker to S1")
    keys.put("")
    with pytest.raises(ConnectionLost, match="end of input"):
        poll_until(op, lambda a: False)


class Button:
    def __init__(self, presses):
        self.presses, self.lamp, self.requests = list(presses), False, []

    def show_request(self, kind, target=""):
        self.requests.append((kind, target))

    def clear_request(self):
        self.requests.append(None)

    def set_request_lamp(self, on):
        self.lamp = on

    def acknowledge_pressed(self):
        return self.presses.pop(0) if self.presses else False


def test_the_cell_button_shares_a_prompt_and_a_withdrawn_one_puts_its_lamp_out():
    cellio = Button([False, True, True, False])
    plc = PlcOperator(cellio, say=lambda text: None, poll_s=0.0, sleep=lambda s: None)
    plc.offer("move_reflector", "P1", "put the reflector on P1")
    assert cellio.lamp and cellio.requests == [("move_reflector", "P1")]
    assert plc.poll() is None
    assert plc.poll() == "plc" and not cellio.lamp and cellio.requests[-1] is None
    plc.offer("resume", "", "resume")
    plc.withdraw()
    assert not cellio.lamp and cellio.requests[-1] is None
