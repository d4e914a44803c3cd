"""The tokens of an ABB RAPID module (RobotWare 6 and 7, files .mod, .modx, .prg), with where each sits in its file.

The lexical rules followed (ABB, "Technical reference manual - RAPID kernel", 3HAC050946-001, section 2 "Lexical
elements", and "RAPID Overview", 3HAC050947-001, "Basic RAPID programming: program structure"):
- identifiers: a letter, then letters, digits and underscores (up to 32 characters); case-insensitive, so the names
  and reserved words are compared in upper case (`upper`);
- numeric literals: an integer, a decimal (`1.5`, `.5`, `5.`) with an optional exponent (`1.5E-3`, `9E+09`), and
  the hexadecimal, binary and octal integers of RobotWare 6.x+ (`0xFF`, `0b101`, `0o17`); the sign is the unary
  operator before it (a separate token);
- string literals: between double quotes on one line, a quote inside written `""`, a backslash `\\` (and `\\hh` a
  character by its hex code);
- comments: from `!` to the end of the line;
- punctuation and operators: `:=` `<>` `<=` `>=` and the single characters `[](){},;\\:+-*/<>=.%?|`;
- a byte order mark opening the file (RobotStudio may save UTF-8 with one) is white space, whether the bytes were
  decoded as UTF-8 ("\\ufeff") or byte for byte as Latin-1 (the three characters of EF BB BF, as `trackcal filter`
  reads files);
- the `%%%` header of an S4C `.prg` file (`%%% VERSION:1 LANGUAGE:ENGLISH %%%`, RAPID kernel "Program
  modules") is skipped as a whole.
Any other character outside a string or a comment is an error naming the file, the line and the character.
"""

from __future__ import annotations

import re
from typing import NamedTuple

from trackcal.drivers.program_text import ProgramReadError

BOMS = ("\ufeff", "\xef\xbb\xbf")  # a UTF-8 byte order mark decoded as UTF-8, and as Latin-1
_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]*")
_NUMBER = re.compile(r"0[xX][0-9A-Fa-f]+|0[bB][01]+|0[oO][0-7]+|(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")


class Token(NamedTuple):
    """One token: kind "name", "num", "str" or "punct"; `text` as written; text[start:end] of its file; 1-based line."""

    kind: str
    text: str
    start: int
    end: int
    line: int

    @property
    def upper(self) -> str:
        """The token's text in upper case: RAPID's names and reserved words are case-insensitive."""
        return self.text.upper()


def number_value(text: str) -> float:
    """The value of a numeric literal token (a decimal, or a 0x / 0b / 0o integer)."""
    if text[:2].lower() not in ("0x", "0b", "0o"):
        return float(text)
    try:
        return float(int(text, 0))
    except OverflowError:  # beyond a double: out of range like 1E999 (the readers refuse it where they need it)
        return float("inf")


def fail(file: str, line: int, what: str) -> ProgramReadError:
    """The one-line error every RAPID reading problem raises: FILE:LINE: WHAT."""
    return ProgramReadError(f"{file}:{line}: {what}")


_TOKEN = re.compile(
    r"(?P<space>[ \t\r\n\f\v]+)|(?P<comment>![^\n]*)|(?P<str>\"(?:[^\"\n]|\"\")*\")"
    r"|(?P<name>[A-Za-z][A-Za-z0-9_]*)|(?P<num>" + _NUMBER.pattern + ")"
    r"|(?P<punct>:=|<>|<=|>=|[\[\](){},;\\:+\-*/<>=.%?|])"
)  # one pattern, the alternatives tried in this order at each position


def tokenize(file: str, text: str) -> list[Token]:
    """The tokens of one file's text, comments and white space left out."""
    tokens: list[Token] = []
    pos = _header_end(file, text)
    if pos == 0:
        pos = next((len(bom) for bom in BOMS if text.startswith(bom)), 0)
    line = 1 + text.count("\n", 0, pos)
    n = len(text)
    match = _TOKEN.match
    while pos < n:
        m = match(text, pos)
        if m is None:
            if text[pos] == '"':
                raise fail(file, line, "a string not closed on its line (expected '\"')")
            raise fail(file, line, f"unexpected character {text[pos]!r} outside a string or a comment")
        kind, end = m.lastgroup, m.end()
        if kind == "space":
            line += text.count("\n", pos, end)
        elif kind == "str":
            tokens.append(Token("str", text[pos + 1 : end - 1].replace('""', '"'), pos, end, line))
        elif kind == "num" and (after := _NAME.match(text, end)):  # 12abc: no RAPID token
            raise fail(file, line, f"a number followed by a name: {text[pos : after.end()]!r}")
        elif kind != "comment":
            tokens.append(Token(str(kind), m.group(), pos, end, line))
        pos = end
    return tokens


def _header_end(file: str, text: str) -> int:
    """Where the text starts after an S4C `.prg` file's `%%% ... %%%` header (0 when it has none)."""
    m = re.match(r"(?:\ufeff|\xef\xbb\xbf)?[ \t\r\n]*%%%", text)
    if not m:
        return 0
    close = text.find("%%%", m.end())
    if close < 0:
        raise fail(file, 1 + text.count("\n", 0, m.end()), "a '%%%' header not closed (expected '%%%')")
    return close + 3
