"""Typed values of YAML and JSON documents (cells, robots, tools, hardware, models, plans).

`where` names the file and the key path ("configs/cells/kr270.yaml: stations.S1.yaw_deg"); every mistake is
the caller's error class with one line: where, what was expected, what was found.
"""

from __future__ import annotations

import math
import re

import numpy as np


def _got(value) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def mapping(value, where: str, error: type[Exception]) -> dict:
    if not isinstance(value, dict):
        raise error(f"{where}: expected a mapping of keys, got {_got(value)}")
    return value


def sequence(value, where: str, error: type[Exception]) -> list:
    if not isinstance(value, list):
        raise error(f"{where}: expected a list, got {_got(value)}")
    return value


def text(value, where: str, error: type[Exception]) -> str:
    if not isinstance(value, str | int | float) or isinstance(value, bool):
        raise error(f"{where}: expected a name, got {_got(value)}")
    return str(value)


def number(value, where: str, error: type[Exception]) -> float:
    """A finite number; a numeric string is taken too (YAML 1.1 reads `1e3` as a string)."""
    if isinstance(value, bool) or not isinstance(value, int | float | str):
        raise error(f"{where}: expected a number, got {_got(value)}")
    try:
        v = float(value)
    except (ValueError, OverflowError):
        raise error(f"{where}: expected a number, got {_got(value)}") from None
    if not math.isfinite(v):
        raise error(f"{where}: expected a finite number, got {_got(value)}")
    return v


# What PyYAML (YAML 1.1) leaves a string although YAML 1.2 reads it as a number: an exponent without a dot (`1e3`)
_YAML11_FLOAT = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)[eE][-+]?\d+")


def yaml_number(value, where: str, error: type[Exception]) -> float:
    """A finite number of a YAML document, never text: a quoted "12" is refused (a number in quotes is a slip the file
    should not hide), `1e3`, which PyYAML reads as a string, is taken."""
    if isinstance(value, str) and not _YAML11_FLOAT.fullmatch(value.strip()):
        raise error(f"{where}: expected a number, got the string {_got(value)}")
    return number(value, where, error)


def bounded(value: float, limit: float, unit: str, where: str, error: type[Exception], why: str) -> float:
    """`value` when |value| <= limit, else `error` saying the range and `why` it is the range."""
    if abs(value) > limit:
        raise error(f"{where}: {value:g} {unit} is outside +-{limit:g} {unit} ({why})")
    return value


def json_number(value, where: str, error: type[Exception]) -> float:
    """A finite JSON number: a string, even a numeric one, is refused (plans and models are JSON, whose numbers
    are typed and written by trackcal or a program; `number` takes numeric strings for YAML's sake)."""
    if isinstance(value, str):
        raise error(f"{where}: expected a number, got the string {_got(value)}")
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise error(f"{where}: expected a number, got {_got(value)}")
    return number(value, where, error)


def rows(value, where: str, error: type[Exception]) -> np.ndarray:
    """A non-empty list of rows of finite JSON numbers, every row as long as the first: (n, m) floats."""
    items = sequence(value, where, error)
    if not items:
        raise error(f"{where}: expected at least one row, got []")
    width = len(sequence(items[0], f"{where}[0]", error))
    out = []
    for i, row in enumerate(items):
        row = sequence(row, f"{where}[{i}]", error)
        if not row or len(row) != width:
            raise error(f"{where}[{i}]: expected {width or 'some'} numbers as in row 0, got {len(row)}")
        out.append([json_number(v, f"{where}[{i}][{k}]", error) for k, v in enumerate(row)])
    return np.array(out)


def integer(value, where: str, error: type[Exception]) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise error(f"{where}: expected an integer, got {_got(value)}")
    return value


def vector(value, where: str, error: type[Exception], n: int = 3) -> np.ndarray:
    """A list of n finite numbers."""
    if not isinstance(value, list | tuple) or len(value) != n:
        raise error(f"{where}: expected a list of {n} numbers, got {_got(value)}")
    return np.array([number(v, f"{where}[{k}]", error) for k, v in enumerate(value)])


def matrix(value, where: str, error: type[Exception], shape: tuple[int, int]) -> np.ndarray:
    if not isinstance(value, list | tuple) or len(value) != shape[0]:
        raise error(f"{where}: expected {shape[0]} rows of {shape[1]} numbers, got {_got(value)}")
    return np.array([vector(row, f"{where}[{k}]", error, shape[1]) for k, row in enumerate(value)])
