"""The operator at the cell PLC: request on the HMI, request lamp, acknowledge button (the console's operator:
campaign/cli/console.py)."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

from rich.text import Text

from trackcal.drivers.errors import ConnectionLost, DeviceError, ProtocolError
from trackcal.drivers.interfaces import SharedOperator


class PlcOperator:
    """The request on the cell HMI (the PLC's request registers) and the request lamp on, the text on the
    console; when the acknowledge button is pressed: lamp off, request cleared; then wait for the button's
    release (one press, one acknowledgement). The lamp going out while the button is held is the operator's
    feedback, and a press is never missed however slowly the button is polled, as long as it is held until
    the lamp goes out.

    Nothing waits forever unnoticed: every `remind_s` the request is repeated on the console. A PLC program
    without the request registers (it answers with a Modbus exception) still gets lamp and button: the HMI
    display is dropped with one warning. `say` shows a line on the console of whoever runs the campaign, as it is
    (a rich Text carries the colour: the target's name is data, never markup)."""

    def __init__(
        self, cellio, say: Callable[[str | Text], None], poll_s: float = 0.1, remind_s: float = 60.0, sleep=time.sleep
    ):
        self.cellio, self.say, self.poll_s, self.remind_s, self.sleep = cellio, say, poll_s, remind_s, sleep
        self.hmi = hasattr(cellio, "show_request")

    def ask(self, kind: str, target: str, text: str) -> str:
        self._hmi(self.cellio.show_request if self.hmi else None, kind, target)
        try:
            self.cellio.set_request_lamp(True)
            self.say(Text.assemble(("OPERATOR", "bold yellow"), f": {text} (press the acknowledge button)"))
            waited = 0.0
            while not self.cellio.acknowledge_pressed():
                self.sleep(self.poll_s)
                waited += self.poll_s
                if waited >= self.remind_s:
                    self.say(Text.assemble(("still waiting", "yellow"), f": {text}"))
                    waited = 0.0
        finally:
            try:
                self.cellio.set_request_lamp(False)  # the lamp going out tells the operator he was heard
            finally:
                self._hmi(self.cellio.clear_request if self.hmi else None)
        while self.cellio.acknowledge_pressed():  # released: one press, one acknowledgement
            self.sleep(self.poll_s)
        return "plc"

    # The same request shared with other operators (FirstAnswer): no reminders, the others show it too.
    def offer(self, kind: str, target: str, text: str) -> None:
        self._hmi(self.cellio.show_request if self.hmi else None, kind, target)
        self.cellio.set_request_lamp(True)
        self.say(Text.assemble(("OPERATOR", "bold yellow"), f": {text} (press the acknowledge button)"))

    def poll(self) -> str | None:
        if not self.cellio.acknowledge_pressed():
            return None
        self.withdraw()
        while self.cellio.acknowledge_pressed():  # released: one press, one acknowledgement
            self.sleep(self.poll_s)
        return "plc"

    def withdraw(self) -> None:
        try:
            self.cellio.set_request_lamp(False)
        finally:
            self._hmi(self.cellio.clear_request if self.hmi else None)

    def _hmi(self, fn, *args) -> None:
        if fn is None:
            return
        try:
            fn(*args)
        except ProtocolError as exc:
            self.hmi = False
            self.say(
                Text.assemble(
                    ("warning", "yellow"), f": the cell HMI shows no requests ({exc}); lamp and acknowledge button only"
                )
            )


class FirstAnswer:
    """One prompt offered to several operators at once (console, cell button, the operator's page): the first
    answer wins and is what `ask` returns (who gave it, recorded by the engine as every answer is); the request
    is then withdrawn from the others. An operator that can no longer answer (a console at the end of its
    input, a page whose server stopped) drops out with one line and leaves the others in charge; when none is
    left, ConnectionLost, as for a single operator who does not answer.

    Everything runs in the caller's thread (the engine's): `watch`, when given, is called about every
    `watch_s` while a prompt waits (the page shows the door and the E-stop from it: reading them here keeps
    each device client in one thread)."""

    def __init__(
        self,
        operators: Sequence[SharedOperator],
        say: Callable[[str | Text], None],
        poll_s: float = 0.02,
        watch: Callable[[], None] | None = None,
        watch_s: float = 0.25,
        sleep=time.sleep,
    ):
        self.operators, self.say, self.poll_s = list(operators), say, poll_s
        self.watch, self.watch_s, self.sleep = watch, watch_s, sleep

    def ask(self, kind: str, target: str, text: str) -> str:
        offered = []
        try:
            for op in list(self.operators):
                self._guard(op, op.offer, kind, target, text)
                if op in self.operators:
                    offered.append(op)
            last_watch = None
            while True:
                if not self.operators:
                    raise ConnectionLost(
                        "no operator can answer (console, button and page all gone)", device="operator"
                    )
                for op in list(self.operators):
                    answer = self._guard(op, op.poll)
                    if answer is not None:
                        offered.remove(op)
                        return answer
                if self.watch is not None and (last_watch is None or time.monotonic() - last_watch >= self.watch_s):
                    last_watch = time.monotonic()
                    self.watch()
                self.sleep(self.poll_s)
        finally:
            for op in offered:
                if op in self.operators:
                    self._guard(op, op.withdraw)

    def _guard(self, op, fn, *args):
        try:
            return fn(*args)
        except DeviceError as exc:
            if op in self.operators:
                self.operators.remove(op)
                left = len(self.operators)
                ways = "way" if left == 1 else "ways"
                self.say(Text.assemble(("note", "yellow"), f": {exc}; {left} other {ways} to answer left"))
            return None
