"""A block of plain CSV lines parsed as one grid of cells by whole-array numpy operations, for the tables
trackcal writes; the measurement-table reader (calib.table) falls back to its general parser for any other block.

Plain means: no quote, NUL or CR byte, and every line the same number of fields. Then the cells are cut at the
comma and newline bytes, and each column is parsed at once:
- a number is [+-]digits[.digits] of up to 16 bytes after the sign whose digits, the dot read as a zero digit,
  are below 2**53 (so any of up to 15 bytes; no exponent, space, "nan" or "inf");
- an id is 1 to 64 bytes of printable ASCII without space (nothing to strip, never empty);
- a text cell is up to 64 bytes, kept as written.
A column with any other cell is None, and the caller gives the block to the general parser, which then reads
it or names the bad cell; so the plain parser decides nothing and only has to agree with the general one.

Numbers are exact: the digits, the dot read as a zero digit, form an integer S below 2**53 (so exact as a
double), from which the true mantissa M follows in exact integer steps, and the value is M / 10**k for k
fraction digits: one IEEE division of two exact doubles, so the correctly rounded double of the decimal text,
as float() and numpy.loadtxt give (Clinger, "How to read floating point numbers accurately", PLDI 1990: the
fast path of every correct strtod).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

import numpy as np

WIDE = 16  # bytes a number may have after its sign: two 64-bit words
TEXT_BYTES = 64  # longest id or text cell parsed here
_POW10 = 10.0 ** np.arange(WIDE + 1)  # exact doubles (every power of ten up to 1e22 is one)
# _KEEP[w]: the last w of WIDE bytes set; masks a window of WIDE bytes ending a cell down to its w digits
_KEEP = ((np.arange(WIDE) >= WIDE - np.arange(WIDE + 1)[:, None]) * np.uint8(255)).view(f"V{WIDE}")[:, 0]
_DOT = np.uint8(ord(".") - ord("0") + 256)  # a dot after subtracting "0" from every byte
TEXT = np.dtypes.StringDType()


@dataclass
class Grid:
    """The cells of a plain block: the offset into `buf` of the comma or newline ending each, (fields, rows)."""

    buf: np.ndarray  # uint8: WIDE newlines, the block, TEXT_BYTES NULs (so every window stays inside)
    end: np.ndarray

    def __len__(self) -> int:
        return self.end.shape[1]

    def bounds(self, c: int) -> tuple[np.ndarray, np.ndarray]:
        """Start and end (exclusive) offsets of the cells of column c: a cell starts after the one before it."""
        before = self.end[c - 1] if c else np.concatenate(([WIDE - 1], self.end[-1][:-1]))
        return before + 1, self.end[c]

    def window(self, at: np.ndarray, width: int) -> np.ndarray:
        """(rows, width) uint8: the `width` bytes from each offset in `at`."""
        view = np.ndarray((len(self.buf) - width + 1,), f"V{width}", self.buf, strides=(1,))
        return view[at].view(np.uint8).reshape(-1, width)

    def numbers(self, c: int) -> np.ndarray | None:
        """Column c as float64, or None when a cell is not a plain decimal number."""
        s, e = self.bounds(c)
        first = self.buf[s]
        neg = first == ord("-")
        digits = e - s - (neg | (first == ord("+")))
        if digits.min() < 1 or digits.max() > WIDE:
            return None
        b = self.window(e - WIDE, WIDE) - np.uint8(ord("0"))
        b &= _KEEP[digits].view(np.uint8).reshape(-1, WIDE)  # the bytes before the digits become zero digits
        dot = b == _DOT
        is_digit = b < 10
        if not (is_digit | dot).all():
            return None
        b *= is_digit
        d = np.packbits(dot.reshape(-1)).view(">u2").astype(np.int64)  # bit k set: k fraction digits
        has_dot = d > 0
        if (d & (d - 1)).any():  # two dots
            return None
        k = np.where(has_dot, np.frexp(d)[1] - 1, 0)
        if (has_dot & ((k == 0) | (k >= digits - 1))).any():  # "5." or ".5": a digit must be on each side
            return None
        s_dot = _value(b)
        if s_dot.max() >= 2.0**53:
            return None
        # S = L * 10**(k+1) + R with the dot as a zero digit; M = L * 10**k + R (all exact below 2**53)
        left = np.floor(s_dot / _POW10[k + 1])
        m = np.where(has_dot, s_dot - 9 * left * _POW10[k], s_dot)
        value = m / _POW10[k]
        return np.where(neg, -value, value)

    def cells(self, c: int, ids: bool) -> np.ndarray | None:
        """Column c as (rows, width) NUL-padded bytes, or None when a cell is too long (or, for ids, empty or
        not printable ASCII)."""
        s, e = self.bounds(c)
        w = e - s
        width = int(w.max())
        if width > TEXT_BYTES or (ids and w.min() < 1):
            return None
        width = max(width, 1)
        keep = np.arange(width) < w[:, None]
        b = self.window(s, width) * keep
        if ids and not (((b - np.uint8(ord("!"))) < ord("~") - ord("!") + 1) == keep).all():
            return None
        return b

    def ids(self, c: int) -> list[str] | None:
        """Column c as strings, one string object per distinct id."""
        b = self.cells(c, ids=True)
        if b is None:
            return None
        if b.shape[1] <= 8:  # compared as one 64-bit integer each: a faster sort
            b = np.pad(b, ((0, 0), (0, 8 - b.shape[1]))).view(np.uint64)[:, 0]
            distinct, inverse = np.unique(b, return_inverse=True)
            names = distinct.view("S8")
        else:
            names, inverse = np.unique(b.view(f"S{b.shape[1]}")[:, 0], return_inverse=True)
        strings = np.array(list(map(sys.intern, names.astype(str).tolist())), dtype=object)
        return strings[inverse].tolist()

    def text(self, c: int) -> np.ndarray | None:
        """Column c as numpy strings, as written."""
        b = self.cells(c, ids=False)
        return None if b is None else b.view(f"S{b.shape[1]}")[:, 0].astype(TEXT)


def _value(b: np.ndarray) -> np.ndarray:
    """(rows, WIDE) decimal digits, most significant first -> their values (float64): neighbouring digits are
    joined in place through ever wider views of the same bytes (2, 4, then 8 digits a word, little-endian)."""
    x = b.view("<u2")
    x = ((x & 0xFF) * 10 + (x >> 8)).astype("<u2", copy=False).view("<u4")
    x = ((x & 0xFFFF) * 100 + (x >> 16)).astype("<u4", copy=False).view("<u8")
    x = (x & 0xFFFFFFFF) * 10000 + (x >> 32)
    return x[:, 0] * 1e8 + x[:, 1]


def split(data: bytes, fields: int) -> Grid | None:
    """The grid of a block of whole lines (the last may lack its newline), or None when it is not plain."""
    if b'"' in data or b"\0" in data or b"\r" in data:
        return None
    ending = b"" if data.endswith(b"\n") else b"\n"
    buf = np.frombuffer(b"\n" * WIDE + data + ending + b"\0" * TEXT_BYTES, np.uint8)
    body = buf[WIDE : len(buf) - TEXT_BYTES]
    newline = body == ord("\n")
    ends = np.flatnonzero(newline | (body == ord(","))) + WIDE
    rows = len(ends) // fields
    if len(ends) != rows * fields or rows != np.count_nonzero(newline):
        return None
    grid = ends.reshape(rows, fields)
    if not (buf[grid[:, -1]] == ord("\n")).all():  # so every other separator is a comma
        return None
    return Grid(buf, np.ascontiguousarray(grid.T))
