"""Robot programs read for filtering (`trackcal filter`): the targets a controller's program holds, where their text
sits, and how a corrected value is written back in the language's own form.

Each language's reader (KRL: drivers/kuka, URScript: drivers/ur, RAPID: drivers/abb) tokenizes the program and returns
a ProgramRead. Everything but the targets' text is kept byte for byte: `ProgramRead.write` with no replacement returns
the files exactly as read. A target that is not corrected keeps its text and gets the language's end-of-line comment
saying why (never dropped, never silently moved).

Units at this boundary: millimetres and 4 x 4 homogeneous transforms for poses, degrees for joint values in the
controller's own convention (the robot configs' joints are the controller's, one to one).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from trackcal.drivers.errors import ProgramError


class ProgramReadError(ProgramError):
    """A program that cannot be read; the message names the file, the line and what was expected there."""


@dataclass(frozen=True)
class ProgramTarget:
    """One target of a program: a Cartesian pose or a set of joint values, where its text sits, and its frames."""

    file: str  # the name of the program file it sits in (a key of ProgramRead.files)
    start: int  # files[file][start:end] is the value's text, replaced when the target is corrected
    end: int
    line: int  # 1-based line of `start`
    name: str  # the variable's name, or "line N" for an inline value
    joint: bool  # True: `value` holds joint values; False: a Cartesian pose
    value: np.ndarray  # joint: (n,) deg; Cartesian: 4 x 4 pose of the TCP in `base`, mm
    base: np.ndarray  # 4 x 4 user frame (KRL $BASE, URScript feature, RAPID wobj) in the robot's base frame, mm
    tool: np.ndarray  # 4 x 4 TCP in the flange frame, mm (identity: the flange itself)
    config: tuple[int, ...]  # the language's configuration of a Cartesian target: KRL (S, T), RAPID (cf1, cf4, cf6,
    # cfx); () when the language carries none (URScript: the controller takes the solution nearest the current joints)
    accepts: Callable[[np.ndarray], bool]  # joint values (deg) -> True when they are in this target's configuration
    render: Callable[[np.ndarray], str]  # a corrected value (same kind and units as `value`) -> the replacement text
    motion: str  # the moves that use it ("PTP", "LIN", "CIRC", "movel", "MoveL", ...), "" if no move uses it


@dataclass(frozen=True)
class ProgramRead:
    """A program as read: its files' texts, its targets in the order they appear, its comment syntax."""

    language: str  # "KRL", "URScript", "RAPID"
    files: dict[str, str]  # file name -> text as read (line ends kept)
    targets: list[ProgramTarget]
    comment: str  # the language's end-of-line comment marker: ";" (KRL), "#" (URScript), "!" (RAPID)

    def write(self, values: dict[int, np.ndarray], notes: dict[int, str]) -> dict[str, str]:
        """The files with target i's text replaced by its `render(values[i])`, and `notes[i]` appended as an
        end-of-line comment on target i's line. Targets in neither dict keep their text byte for byte."""
        out = {}
        for name, text in self.files.items():
            edits = []  # (start, end, replacement) in this file
            for i, t in enumerate(self.targets):
                if t.file != name:
                    continue
                if i in values:
                    edits.append((t.start, t.end, t.render(values[i])))
                if i in notes:
                    eol = _line_end(text, t.end)
                    edits.append((eol, eol, f" {self.comment} {_one_line(notes[i])}"))
            for start, end, new in sorted(edits, key=lambda e: (e[0], e[1]), reverse=True):
                text = text[:start] + new + text[end:]
            out[name] = text
        return out


def _line_end(text: str, pos: int) -> int:
    """Index of the line end (before CR LF / LF) of the line holding `pos`."""
    n = text.find("\n", pos)
    n = len(text) if n < 0 else n
    return n - 1 if n > 0 and text[n - 1] == "\r" else n


def _one_line(note: str) -> str:
    """A note as one printable ASCII line (others -> _)."""
    return "".join(c if " " <= c <= "~" else "_" for c in str(note))
