"""The operator at the cell PLC: request on the HMI, request lamp, acknowledge button (the console's operator:
campaign/cli/console.py)."""

from __future__ import annotations

import time
from collections.abc import Callable

from trackcal.drivers.errors import ProtocolError


class PlcOperator:
    """The request on the cell HMI (the PLC's request registers) and the request lamp on, the text on the
    console; when the acknowledge button is pressed: lamp off, request cleared; then wait for the button's
    release (one press, one acknowledgement). The lamp going out while the button is held is the operator's
    feedback, and a press is never missed however slowly the button is polled, as long as it is held until
    the lamp goes out.

    Nothing waits forever unnoticed: every `remind_s` the request is repeated on the console. A PLC program
    without the request registers (it answers with a Modbus exception) still gets lamp and button: the HMI
    display is dropped with one warning. `say` shows a line (rich markup) on the console of whoever runs the
    campaign."""

    def __init__(self, cellio, say: Callable[[str], None], poll_s: float = 0.1, remind_s: float = 60.0,
                 sleep=time.sleep):  # fmt: skip
        self.cellio, self.say, self.poll_s, self.remind_s, self.sleep = cellio, say, poll_s, remind_s, sleep
        self.hmi = hasattr(cellio, "show_request")

    def ask(self, kind: str, target: str, text: str) -> str:
        self._hmi(self.cellio.show_request if self.hmi else None, kind, target)
        try:
            self.cellio.set_request_lamp(True)
            self.say(f"[bold yellow]OPERATOR[/]: {text} (press the acknowledge button)")
            waited = 0.0
            while not self.cellio.acknowledge_pressed():
                self.sleep(self.poll_s)
                waited += self.poll_s
                if waited >= self.remind_s:
                    self.say(f"[yellow]still waiting[/]: {text}")
                    waited = 0.0
        finally:
            try:
                self.cellio.set_request_lamp(False)  # the lamp going out tells the operator he was heard
            finally:
                self._hmi(self.cellio.clear_request if self.hmi else None)
        while self.cellio.acknowledge_pressed():  # released: one press, one acknowledgement
            self.sleep(self.poll_s)
        return "plc"

    def _hmi(self, fn, *args) -> None:
        if fn is None:
            return
        try:
            fn(*args)
        except ProtocolError as exc:
            self.hmi = False
            self.say(f"[yellow]warning[/]: the cell HMI shows no requests ({exc}); "
                               "lamp and acknowledge button only")  # fmt: skip
