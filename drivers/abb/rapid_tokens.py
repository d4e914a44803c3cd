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
- punctuation and operators: `:=` `<>` `<=` `>=` and the single characters of PUNCT;
- a byte order mark opening the file (RobotStudio may save UTF-8 with one) is white space, whether the bytes were
  decoded as UTF-8 ("\\ufeff") or byte for byte as Latin-1 (the three characters of EF BB BF, as `trackcal filter`
  reads files);
- the `%%%` header of an S4C `.prg` file (`%%% VERSION:1 LANGUAGE:ENGLISH %%%`, RAPID kernel "Program
  modules") is skipped as a whole.
Any other character outside a string or a comment is an error naming the file, the line and the character.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from trackcal.drivers.program_text import ProgramReadError

BOMS = ("\ufeff", "\xef\xbb\xbf")  # a UTF-8 byte order mark decoded as UTF-8, and as Latin-1
PUNCT = "[](){},;\\:+-*/<>=.%?|"
TWO_CHAR = (":=", "<>", "<=", ">=")
_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]*")
_NUMBER = re.compile(r"0[xX][0-9A-Fa-f]+|0[bB][01]+|0[oO][0-7]+|(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")
_SPACE = re.compile(r"[ \t\r\n\f\v]+")


@dataclass(frozen=True)
class Token:
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


def tokenize(file: str, text: str) -> list[Token]:
    """The tokens of one file's text, comments and white space left out."""
    tokens: list[Token] = []
    pos, line = _header_end(file, text), 1
    if pos == 0:
        pos = next((len(bom) for bom in BOMS if text.startswith(bom)), 0)
    line += text.count("\n", 0, pos)
    n = len(text)
    while pos < n:
        c = text[pos]
        m = _SPACE.match(text, pos)
        if m:
            line += text.count("\n", pos, m.end())
            pos = m.end()
            continue
        if c == "!":
            eol = text.find("\n", pos)
            pos = n if eol < 0 else eol
            continue
        token = _one_token(file, text, pos, line)
        tokens.append(token)
        pos = token.end
    return tokens


def _one_token(file: str, text: str, pos: int, line: int) -> Token:
    """The token starting at `pos` (not white space or a comment)."""
    c = text[pos]
    if c == '"':
        return Token("str", _string_text(file, text, pos, line), pos, _string_end(file, text, pos, line), line)
    for kind, pattern in (("name", _NAME), ("num", _NUMBER)):
        m = pattern.match(text, pos)
        if m:
            after = _NAME.match(text, m.end()) if kind == "num" else None
            if after:  # 12abc: no RAPID token
                raise fail(file, line, f"a number followed by a name: {text[pos : after.end()]!r}")
            return Token(kind, m.group(), pos, m.end(), line)
    two = text[pos : pos + 2]
    if two in TWO_CHAR:
        return Token("punct", two, pos, pos + 2, line)
    if c in PUNCT:
        return Token("punct", c, pos, pos + 1, line)
    raise fail(file, line, f"unexpected character {c!r} outside a string or a comment")


def _string_end(file: str, text: str, pos: int, line: int) -> int:
    """The index after the closing quote of the string literal opening at `pos` (a `""` inside is one quote)."""
    i = pos + 1
    while True:
        j = text.find('"', i)
        eol = text.find("\n", i)
        if j < 0 or (0 <= eol < j):
            raise fail(file, line, "a string not closed on its line (expected '\"')")
        if text.startswith('""', j):
            i = j + 2
            continue
        return j + 1


def _string_text(file: str, text: str, pos: int, line: int) -> str:
    """The string literal's value (quotes removed, `""` as one quote; backslash codes kept as written)."""
    return text[pos + 1 : _string_end(file, text, pos, line) - 1].replace('""', '"')


def _header_end(file: str, text: str) -> int:
    """Where the text starts after an S4C `.prg` file's `%%% ... %%%` header (0 when it has none)."""
    m = re.match(r"(?:\ufeff|\xef\xbb\xbf)?[ \t\r\n]*%%%", text)
    if not m:
        return 0
    close = text.find("%%%", m.end())
    if close < 0:
        raise fail(file, 1 + text.count("\n", 0, m.end()), "a '%%%' header not closed (expected '%%%')")
    return close + 3
