"""The one rich console of the command line, and the operator who answers on it."""

import contextlib
import queue
import sys
import threading

from rich.console import Console
from rich.table import Table
from rich.text import Text

from trackcal.drivers.errors import ConnectionLost

# Markup off: whatever is printed is shown as it is, so a point, station, file or folder name holding rich markup
# (`P2[/bold]`, `m[red]x`) is data, never a style nor a MarkupError; colour is asked for with a rich Text.
# Into a pipe or a file (a log, a test) a line is written whole, never folded at 80 columns: a path or a command
# the user copies from it stays one word; on a terminal, rich fits the text to its width.
console = Console(highlight=False, markup=False, soft_wrap=not sys.stdout.isatty())


def labelled(label: str, style: str, text: str) -> Text:
    """`label: text`, the label in `style` (rich's style syntax), the text shown as it is."""
    return Text.assemble((label, style), ": ", text)


def print_table(table: Table) -> None:
    """A table whose cells are never cut: rich shortens a column to fit the console's width (80 when the output is
    no terminal: "cycli…"), so each column is at least as wide as its widest cell, headers fold, and a table
    wider than the console is printed whole (the terminal wraps its lines) rather than cropped."""
    cells = [list(column.cells) for column in table.columns]
    for column, texts in zip(table.columns, cells, strict=True):
        column.overflow = "fold"
        column.min_width = max((len(str(t)) for t in texts), default=0)
    # the narrowest width that holds every cell: each column plus its padding (1 each side) and the borders
    needed = sum(column.min_width + 2 for column in table.columns) + len(table.columns) + 1
    console.print(table, width=max(console.width, needed), crop=False)


# The word each prompt asks for: one that no stray key, paste or cat on the keyboard types by accident. The
# resume prompt, after which the robot moves, has its own word; a prompt kind not listed asks for "done".
ANSWERS = {"change_station": "done", "move_reflector": "done", "resume": "resume"}


class ConsoleOperator:
    """Shows the request and waits for the exact word it asks for (`ANSWERS`, case and surrounding spaces
    aside): anything else repeats the prompt with the word expected. `max_wrong` wrong answers in a row, or a
    console at the end of its input (stdin closed, or a file that ran out), mean no operator is answering:
    the campaign stops safely there, as for a lost device, and `trackcal resume` asks again. Five: a person
    mistyping gets four more tries, while garbage (random bytes, a file piped by mistake) stops within five
    lines instead of scrolling forever. The answer recorded is "console"."""

    def __init__(self, console: Console = console, max_wrong: int = 5, readline=None):
        self.console, self.max_wrong = console, max_wrong
        self._readline = readline or sys.stdin.readline
        self._lines: queue.SimpleQueue | None = None
        self._word, self._wrong = "done", 0

    def ask(self, kind: str, target: str, text: str) -> str:
        word = ANSWERS.get(kind, "done")
        self.console.print(labelled("OPERATOR", "bold yellow", text))
        for _ in range(self.max_wrong):
            try:
                line = self.console.input(f"type {word} and press Enter when done: ")
            except EOFError:
                raise ConnectionLost("end of input, nobody can acknowledge", device="operator console") from None
            except UnicodeDecodeError:  # bytes that are no text: no word at all
                line = "(not text)"
            if line.strip().lower() == word:
                return "console"
            self.console.print(labelled("not an acknowledgement", "yellow", f"{line[:40]!r}; expected {word!r}"))
        raise ConnectionLost(
            f"{self.max_wrong} answers in a row were not {word!r}, nobody acknowledges", device="operator console"
        )

    # Shared with other operators (campaign.cells.operator.FirstAnswer, e.g. the operator's page): the console
    # cannot stop waiting for a line, so a thread reads lines into a queue and the prompt polls it; a line typed
    # before the prompt was shown is no answer to it.
    def offer(self, kind: str, target: str, text: str) -> None:
        if self._lines is None:
            self._lines = queue.SimpleQueue()
            threading.Thread(target=self._read, name="console-lines", daemon=True).start()
        while not self._lines.empty():
            if self._lines.get() is None:
                self._lines.put(None)  # the end of input stays the end
                break
        self._word, self._wrong = ANSWERS.get(kind, "done"), 0
        self.console.print(labelled("OPERATOR", "bold yellow", f"{text} (type {self._word} and press Enter)"))

    def poll(self) -> str | None:
        while self._lines is not None and not self._lines.empty():
            line = self._lines.get()
            if line is None:
                self._lines.put(None)
                raise ConnectionLost("end of input, the console cannot acknowledge", device="operator console")
            if line.strip().lower() == self._word:
                return "console"
            self._wrong += 1
            if self._wrong >= self.max_wrong:
                raise ConnectionLost(
                    f"{self.max_wrong} answers in a row were not {self._word!r} on the console",
                    device="operator console",
                )
            self.console.print(labelled("not an acknowledgement", "yellow", f"{line[:40]!r}; expected {self._word!r}"))
        return None

    def withdraw(self) -> None:
        self.console.print(Text("(answered elsewhere)", style="dim"))

    def _read(self) -> None:
        with contextlib.suppress(OSError, ValueError):  # stdin closed or not readable here (a test's captured stdin)
            while True:
                try:
                    line = self._readline()
                except UnicodeDecodeError:
                    line = "(not text)\n"
                if not line:
                    break
                self._lines.put(line)
        self._lines.put(None)
