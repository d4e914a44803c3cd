"""The operator in the loop: console prompts, and the cell PLC (request lamp, acknowledge button)."""

from __future__ import annotations

import time

from rich.console import Console


class ConsoleOperator:
    """Shows the request and waits for Enter (the operator's acknowledgement)."""

    def __init__(self, console: Console):
        self.console = console

    def ask(self, kind: str, target: str, text: str) -> str:
        self.console.print(f"[bold yellow]OPERATOR[/]: {text}")
        self.console.input("press Enter when done ")
        return "console"


class PlcOperator:
    """Request lamp on, the text on the console, wait for the acknowledge button, lamp off.

    Nothing waits forever unnoticed: every `remind_s` the request is repeated on the console."""

    def __init__(self, cellio, console: Console, poll_s: float = 0.1, remind_s: float = 60.0, sleep=time.sleep,
                 display=None):  # fmt: skip
        self.cellio, self.console, self.poll_s, self.remind_s, self.sleep = cellio, console, poll_s, remind_s, sleep
        self.display = display  # another place the request is shown (the simulated operator reads it there)

    def ask(self, kind: str, target: str, text: str) -> str:
        if self.display is not None:
            self.display(kind, target, text)
        self.cellio.set_request_lamp(True)
        self.console.print(f"[bold yellow]OPERATOR[/]: {text} (press the acknowledge button)")
        waited = 0.0
        try:
            while not self.cellio.acknowledge_pressed():
                self.sleep(self.poll_s)
                waited += self.poll_s
                if waited >= self.remind_s:
                    self.console.print(f"[yellow]still waiting[/]: {text}")
                    waited = 0.0
            while self.cellio.acknowledge_pressed():  # released: one press, one acknowledgement
                self.sleep(self.poll_s)
        finally:
            self.cellio.set_request_lamp(False)
        return "plc"
