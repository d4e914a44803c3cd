"""The KRL tokenizer (KUKA System Software 5.x on the KR C2, 8.x on the KR C4): a program file's text as tokens with
their place, and its statements (KRL has one statement a line; comments and `&` header lines are no statement).

What it relies on (public material, not a controller):
- names are not case-sensitive, start with a letter, `_` or `$` (system variables: `$BASE`, `$BWDSTART`) and go on
  with letters, digits, `_` and `$`; `#NAME` is an ENUM value (`BAS(#TOOL,1)`, `IPO_FRAME #BASE`) (Wikipedia "KUKA
  Robot Language"; the KSS templates' `BAS (#INITMOV,0 )`);
- `;` starts a comment to the line's end: the inline forms' `;FOLD ...;%{PE}...` and `;ENDFOLD` lines are comments to
  the interpreter, which runs the lines between them (robot-forum.com threads on inline forms; OrangeEdit's folds);
- a line starting with `&` (`&ACCESS RVP`, `&REL 1`, `&PARAM TEMPLATE = ...`) is a header line for the editor;
- numbers: `12`, `-3.5`, `1.0E-3` (the sign is an operator token); strings in double quotes (no escapes), on one
  line; bit-pattern constants in single quotes: binary `'B1010'` and hexadecimal `'H1F'` (KSS "Operating and
  Programming Instructions for System Integrators", data types: the status is often written `S 'B010'`);
- operators and brackets: `{ } ( ) [ ] , : = == <> < > <= >= + - * / .` (`:` is the geometric operator).
Line ends are whatever the file holds (the KUKA editor writes CR LF): a CR before LF belongs to the line end.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from trackcal.drivers.program_text import ProgramReadError


@dataclass(frozen=True)
class Token:
    kind: str  # name, enum, number, string, bits, op, comment, header, eol
    text: str
    start: int  # text[start:end] of the file
    end: int
    line: int  # 1-based
    upper: str = ""  # text in upper case (KRL names are not case-sensitive)

    def __post_init__(self) -> None:
        object.__setattr__(self, "upper", self.text.upper())


_SPACE = " \t\r\f"
_OPS2 = ("==", "<>", "<=", ">=")
_OPS1 = "{}()[],:=<>+-*/."
_NAME = re.compile(r"[A-Za-z_$][A-Za-z0-9_$]*")
_NUMBER = re.compile(r"(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?")
_BITS = re.compile(r"'(?:[Bb][01]+|[Hh][0-9A-Fa-f]+)'")


def where(file: str, line: int) -> str:
    return f"{file}:{line}"


def _rest_of_line(text: str, i: int) -> int:
    """Index of the line end (the CR of CR LF, or the LF) from i, or the text's end."""
    n = text.find("\n", i)
    n = len(text) if n < 0 else n
    return n - 1 if n > i and text[n - 1] == "\r" else n


def _scan_one(file: str, text: str, i: int, line: int, line_start: bool) -> Token:
    """The token starting at text[i] (not a space)."""
    c = text[i]
    if c == "\n":
        return Token("eol", c, i, i + 1, line)
    if c == ";" or (c == "&" and line_start):
        end = _rest_of_line(text, i)
        return Token("comment" if c == ";" else "header", text[i:end], i, end, line)
    if c == '"':
        end = text.find('"', i + 1)
        stop = _rest_of_line(text, i)
        if end < 0 or end > stop:
            raise ProgramReadError(f'{where(file, line)}: a string opened with " is not closed on its line')
        return Token("string", text[i : end + 1], i, end + 1, line)
    if c == "'":
        m = _BITS.match(text, i)
        if not m:
            raise ProgramReadError(f"{where(file, line)}: expected a bit pattern like 'B0101' or 'H1F' after '")
        return Token("bits", m.group(), i, m.end(), line)
    m = _NUMBER.match(text, i) if c.isdigit() or (c == "." and text[i + 1 : i + 2].isdigit()) else None
    if m:
        return Token("number", m.group(), i, m.end(), line)
    m = _NAME.match(text, i + 1 if c == "#" else i)
    if m and (c == "#" or m.start() == i):
        return Token("enum" if c == "#" else "name", text[i : m.end()], i, m.end(), line)
    if text[i : i + 2] in _OPS2:
        return Token("op", text[i : i + 2], i, i + 2, line)
    if c in _OPS1:
        return Token("op", c, i, i + 1, line)
    shown = c if " " < c <= "~" else f"U+{ord(c):04X}"
    raise ProgramReadError(
        f"{where(file, line)}: unexpected character {shown!r} (KRL names, numbers, operators or a ; comment expected)"
    )


# one pattern for the tokens that need no check beyond their form; the others (a header line, an unclosed string or
# bit pattern, a character KRL does not have) go through _scan_one, which reads them or says what was expected
_FAST = re.compile(
    r"(?P<eol>\n)|(?P<space>[ \t\r\f]+)|(?P<comment>;[^\n]*)|(?P<string>\"[^\"\n]*\")"
    r"|(?P<bits>'(?:[Bb][01]+|[Hh][0-9A-Fa-f]+)')|(?P<number>(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?)"
    r"|(?P<enum>#[A-Za-z_$][A-Za-z0-9_$]*)|(?P<name>[A-Za-z_$][A-Za-z0-9_$]*)|(?P<op>==|<>|<=|>=|[{}()\[\],:=<>+\-*/.])"
)


def tokenize(file: str, text: str) -> list[Token]:
    """Every token of a file's text, comments and line ends included; ProgramReadError (file:line) otherwise."""
    out: list[Token] = []
    i, line, line_start = 0, 1, True
    while i < len(text):
        m = _FAST.match(text, i)
        kind = m.lastgroup if m else None
        if kind == "space":
            i = m.end()  # type: ignore[union-attr]
            continue
        if m is None or (line_start and text[i] == "&"):
            tok = _scan_one(file, text, i, line, line_start)
        else:
            end = m.end()
            if kind == "comment" and text[end - 1] == "\r":
                end -= 1  # the CR of CR LF belongs to the line end
            tok = Token(kind, text[i:end], i, end, line)  # type: ignore[arg-type]
        out.append(tok)
        i, line_start = tok.end, tok.kind == "eol"
        line += tok.kind == "eol"
    return out


def statements(tokens: list[Token]) -> list[list[Token]]:
    """The file's statements: the tokens of each line without comments and headers; lines with none left out."""
    out: list[list[Token]] = []
    current: list[Token] = []
    for tok in tokens:
        if tok.kind == "eol":
            if current:
                out.append(current)
            current = []
        elif tok.kind not in ("comment", "header"):
            current.append(tok)
    if current:
        out.append(current)
    return out
