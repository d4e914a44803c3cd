"""Writing the files a command produces: a write that fails is one line naming the file."""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from pathlib import Path

from calib.table import MeasurementTable, write_table
from campaign.errors import InputError


def write_json(path: str | Path, doc: dict) -> None:
    try:
        Path(path).write_text(json.dumps(doc, indent=2) + "\n")
    except OSError as exc:
        raise InputError(f"{path}: cannot write ({exc.strerror})") from None


def write_output_table(table: MeasurementTable, path: str | Path) -> None:
    try:
        write_table(table, path)
    except OSError as exc:
        raise InputError(f"{path}: cannot write ({exc.strerror})") from None


def write_atomically(path: Path, text: str) -> None:
    """Whoever waits for the file never reads half of it."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
