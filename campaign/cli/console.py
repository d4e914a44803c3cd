"""The one rich console of the command line, and the operator who answers on it."""

from rich.console import Console

from trackcal.drivers.errors import ConnectionLost

console = Console(highlight=False)


class ConsoleOperator:
    """Shows the request and waits for Enter (the operator's acknowledgement). A console at the end of its
    input (stdin closed, or a file that ran out) has no operator behind it: the campaign stops safely there,
    as for a lost device, and `trackcal resume` asks again."""

    def __init__(self, console: Console = console):
        self.console = console

    def ask(self, kind: str, target: str, text: str) -> str:
        self.console.print(f"[bold yellow]OPERATOR[/]: {text}")
        try:
            self.console.input("press Enter when done ")
        except EOFError:
            raise ConnectionLost("end of input, nobody can acknowledge", device="operator console") from None
        return "console"
