"""Robot families: which driver a hardware file's `robot.protocol` selects.

Each driver package that drives a robot has a `family` module whose FAMILY is a RobotFamily: the keys of its
robot section (validated by campaign/cells/hardware.py with the kinds it knows), how to build the client from a
validated section and the cell's checks, and how to describe it to people. The packages are found by walking
drivers' sub-packages, so no code outside a family's own package names a controller, and a new family is a new
package with a `family` module.
"""

from __future__ import annotations

import importlib
import importlib.util
import pkgutil
import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

import trackcal.drivers as _drivers
from trackcal.drivers.errors import ProgramError
from trackcal.drivers.interfaces import Robot
from trackcal.drivers.program_text import ProgramRead

REQUIRED = ...  # the default of a key the hardware file must give


@dataclass(frozen=True)
class ProgramWriter:
    """The program of joint moves a family's controller runs (`trackcal compensate --program`), as text: files are
    written by the caller (atomically). `language` names it to people; `check_name(name)` returns the name or raises
    ProgramError; `labels(names, n)` are the rows' names in the program (from the targets' own names, or None);
    `texts(name, q_deg, speed_pct, labels, notes=None)` -> {file name: bytes}, q_deg (N, 6) degrees, speed_pct 1..100;
    `notes[i]`, when not None, is a comment the program carries above row i (e.g. why that target is its nominal one,
    not compensated): every row is a move of the program, none is left out."""

    language: str
    check_name: Callable[[str], str]
    labels: Callable[[list[str] | None, int], list[str]]
    texts: Callable[..., dict[str, bytes]]


def comment_text(text: str) -> str:
    """`text` for a program's comment line: printable ASCII (others -> _), one line."""
    return re.sub(r"[^ -~]", "_", str(text))


def program_notes(notes: list[str | None] | None, n: int, error: type[ProgramError]) -> list[str | None]:
    """One note (or None) per row of the program, each made a comment's text."""
    if notes is None:
        return [None] * n
    if len(notes) != n:
        raise error(f"one note (or none) per target expected, got {len(notes)} for {n}")
    return [None if t is None else comment_text(t) for t in notes]


def program_names(names: list[str] | None, n: int, prefix: str, unnamed: str, max_len: int) -> list[str]:
    """Identifiers of a program's n targets: `prefix` and the target's name made an identifier (other characters
    -> _, at most max_len characters, unique without regard to case: `_2`, `_3`... added), or `unnamed`1..n for
    targets without a name."""
    out: list[str] = []
    seen: set[str] = set()
    for k in range(n):
        raw = (names[k] if names else "").strip()
        base = (prefix + re.sub(r"[^A-Za-z0-9_]", "_", raw))[:max_len] if raw else f"{unnamed}{k + 1}"
        name, i = base, 2
        while name.upper() in seen:
            suffix = f"_{i}"
            name, i = base[: max_len - len(suffix)] + suffix, i + 1
        seen.add(name.upper())
        out.append(name)
    return out


def program_targets(
    q_deg, speed_pct, controller: str, axes: int, angles: str, speed: str, error: type[ProgramError]
) -> tuple[np.ndarray, int]:
    """(targets (N, axes) degrees, speed override %) of a `controller`'s program, or `error` saying what is wrong:
    rows of `axes` finite `angles` (as the controller names them), an integer `speed` override of 1..100 %."""
    q = np.atleast_2d(np.asarray(q_deg, dtype=float))
    if q.ndim != 2 or q.shape[1] != axes or len(q) == 0:
        raise error(f"a {controller} program needs rows of {axes} {angles}, got shape {q.shape}")
    if not np.all(np.isfinite(q)):
        raise error(f"{angles} must be finite numbers")
    if isinstance(speed_pct, bool) or int(speed_pct) != speed_pct or not 1 <= speed_pct <= 100:
        raise error(f"the {speed} speed override must be an integer percentage 1..100, got {speed_pct!r}")
    return q, int(speed_pct)


@dataclass(frozen=True)
class RobotFamily:
    """One controller family. `schemas`: section path below `robot` ("" the robot section itself, "eki" its eki
    sub-section ...) -> key -> (kind, default[, most]), kinds as campaign/cells/hardware.py validates them (host,
    port, timeout, positive with its upper bound `most` if any, bool, protocol, section); `protocols`: the choices
    of a `protocol` key of a sub-section.
    `build(section, joint_limits_deg=, cell_box_check=, motion_guard=)` makes the client without I/O; `claim` takes
    the cell's robot channel before any device is touched (DeviceError when it cannot); `describe` is the robot's
    line of `trackcal run`'s device list, `where` its address in a connection error, `waiting` the line shown while
    it connects."""

    name: str
    title: str
    dof: int
    schemas: dict[str, dict[str, tuple[str, Any]]]
    build: Callable[..., Robot]
    describe: Callable[[dict], str]
    where: Callable[[dict], str]
    waiting: Callable[[dict], str]
    claim: Callable[[Robot], None] | None = None
    protocols: dict[str, tuple[str, ...]] | None = None
    # the controller's own calibration, a standard DH table: factory_table(conf=PATH) -> the deltas of its
    # calibration file, factory_table(host=ADDRESS) -> the calibrated table the controller sends; each as
    # (theta rad, a mm, d mm, alpha rad, source, is_delta)
    factory_table: Callable[..., tuple] | None = None
    program: ProgramWriter | None = None  # the controller's program of joint moves (compensate --program)
    # native_output(path): what the driver's native library prints on the process's console by itself goes to
    # this file instead (a campaign's session folder), keeping trackcal's one line alone; returns whether it did
    native_output: Callable[..., bool] | None = None
    # the controller's programs read for filtering (`trackcal filter`): a file suffix (".src", ".script", ".mod")
    # -> reader(files) -> ProgramRead, files {name: text} (a KRL .src with its .dat and the cell's $config.dat)
    readers: dict[str, Callable[[dict[str, str]], ProgramRead]] | None = None


def families() -> dict[str, RobotFamily]:
    """Every family of the installed drivers, by name."""
    out: dict[str, RobotFamily] = {}
    for info in pkgutil.iter_modules(_drivers.__path__):
        name = f"{_drivers.__name__}.{info.name}.family"
        if info.ispkg and importlib.util.find_spec(name) is not None:
            family = importlib.import_module(name).FAMILY
            out[family.name] = family
    return dict(sorted(out.items()))


def program_readers() -> dict[str, Callable[[dict[str, str]], ProgramRead]]:
    """Every family's program readers by file suffix (lower case)."""
    return {suffix: reader for family in families().values() for suffix, reader in (family.readers or {}).items()}
