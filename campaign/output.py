"""Writing the files a command produces: atomically (calib.files.atomic_open), JSON strict, and a write that
fails (a full disk, a read-only directory) as one line naming the file."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path
from typing import IO

from trackcal.calib.io.files import atomic_open, dumps_json
from trackcal.calib.io.table import MeasurementTable, write_table
from trackcal.campaign.errors import InputError


@contextlib.contextmanager
def writing(path: str | Path) -> Iterator[None]:
    """An OSError in the block is an InputError naming `path`."""
    try:
        yield
    except OSError as exc:
        raise InputError(f"{path}: cannot write ({exc.strerror or exc})") from None


@contextlib.contextmanager
def output_file(path: str | Path, mode: str = "w", **kwargs) -> Iterator[IO]:
    """atomic_open for a command's output (figures: mode "wb")."""
    with writing(path), atomic_open(path, mode, **kwargs) as fh:
        yield fh


def write_text(path: str | Path, text: str) -> None:
    with output_file(path) as fh:
        fh.write(text)


def write_json(path: str | Path, doc: dict) -> None:
    write_text(path, dumps_json(doc))


def write_output_table(table: MeasurementTable, path: str | Path) -> None:
    with writing(path):
        write_table(table, path)
