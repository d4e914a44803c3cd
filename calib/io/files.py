"""The files trackcal reads and writes: UTF-8 text, YAML and strict JSON documents, atomic writes.

Reading: every failure is the caller's error class with one line naming the file (and the line in it).
Writing: `atomic_open` is the one way an output file is made. The content goes to a temporary file in the
same directory, is flushed to the disk, then renamed over the target (a rename within a directory is atomic
on POSIX), so a crash, a full disk or a kill leaves the previous file or none, never a truncated one. A kill -9
leaves the temporary file itself: it is named `.NAME.PID.RANDOM.tmp` (the writer's process id), and the next write
into that directory removes every such file whose writer is dead, and nothing else.
JSON is strict (RFC 8259: no NaN or Infinity); a value that cannot be a number is null with a reason.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import re
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO

import yaml


def read_text(path: str | Path, error: type[Exception]) -> str:
    """The UTF-8 text of `path` (a leading BOM dropped)."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise error(f"{path}: no such file") from None
    except OSError as exc:
        raise error(f"{path}: cannot read ({exc.strerror or exc})") from None
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise error(
            f"{path}: line {line}: not UTF-8 text (byte 0x{data[exc.start]:02x}); save the file as UTF-8"
        ) from None


def read_yaml(path: str | Path, error: type[Exception], text: str | None = None) -> dict:
    """The mapping at the top of a YAML file (`text`: its content when the caller already read it)."""
    text = read_text(path, error) if text is None else text
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = f" (line {mark.line + 1})" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).replace("\n", " ")
        raise error(f"{path}: not valid YAML{line}: {problem}") from None
    if not isinstance(doc, dict):
        raise error(f"{path}: expected a mapping of keys at the top level, got {type(doc).__name__}")
    return doc


def read_json(path: str | Path, error: type[Exception]) -> dict:
    """The object of a strict JSON file: NaN and Infinity are refused."""
    text = read_text(path, error)

    def no_constant(name: str):
        raise error(f"{path}: {name} is not JSON (RFC 8259 has no NaN or Infinity)")

    try:
        doc = json.loads(text, parse_constant=no_constant)
    except json.JSONDecodeError as exc:
        raise error(f"{path}: line {exc.lineno}: not JSON ({exc.msg})") from None
    except RecursionError:  # the parser recurses per nested array or object; no document of ours nests 10 deep
        raise error(f"{path}: not a document of trackcal (arrays or objects nested too deeply)") from None
    if not isinstance(doc, dict):
        raise error(f"{path}: expected a JSON object at the top level, got {type(doc).__name__}")
    return doc


UNIT_SUFFIXES = ("_mm", "_mm2", "_um", "_deg", "_s")


def why_key(key: str) -> str:
    """The field that says why `key` is null: rho0_mm -> rho0_why."""
    stem = next((key[: -len(u)] for u in UNIT_SUFFIXES if key.endswith(u)), key)
    return f"{stem}_why"


def finite_or_null(doc: dict, why: str) -> dict:
    """`doc` with every non-finite number replaced by null and a `<name>_why` field saying `why` (JSON has no
    NaN or Infinity)."""
    out = {}
    for key, value in doc.items():
        if isinstance(value, float) and not math.isfinite(value):
            out[key], out[why_key(key)] = None, why
        else:
            out[key] = value
    return out


def dumps_json(doc) -> str:
    """Strict JSON text; a non-finite number is a programming error (ValueError): the writer of `doc` must
    have put null and a reason instead."""
    return json.dumps(doc, indent=2, allow_nan=False) + "\n"


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


# `.NAME.PID.RANDOM.tmp` as atomic_open makes it: RANDOM is mkstemp's 8 characters from "abcdefghijklmnopqrstuvwxyz
# 0123456789_" (CPython Lib/tempfile.py, _RandomNameSequence)
_TEMPORARY = re.compile(r"\.(?P<name>.+)\.(?P<pid>[1-9][0-9]{0,9})\.[a-z0-9_]{8}\.tmp")


def _writer_dead(pid: int) -> bool:
    """Whether no process `pid` exists (kill(pid, 0) checks without signalling; another user's process exists)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except OSError:  # PermissionError: it exists; anything else: do not guess
        return False
    return False


def remove_dead_temporaries(directory: str | Path) -> list[Path]:
    """Remove the temporary files atomic_open's killed writers left in `directory`: regular files named
    `.NAME.PID.RANDOM.tmp` whose process PID is gone. A live writer's file, a link and any other name are never
    touched; a file that cannot be removed stays (the write that asked goes on). Returns the files removed."""
    removed = []
    try:
        entries = list(os.scandir(directory))
    except OSError:
        return removed
    for entry in entries:
        match = _TEMPORARY.fullmatch(entry.name)
        if match is None or int(match["pid"]) == os.getpid():
            continue
        try:
            if not stat.S_ISREG(entry.stat(follow_symlinks=False).st_mode) or not _writer_dead(int(match["pid"])):
                continue
            os.unlink(entry.path)
        except OSError:
            continue
        removed.append(Path(entry.path))
    return removed


@contextlib.contextmanager
def atomic_open(path: str | Path, mode: str = "w", **kwargs) -> Iterator[IO]:
    """A file object ("w": text, UTF-8 unless told; "wb": bytes) whose content replaces `path` only when the
    block ends without an exception; on failure the temporary file is removed and `path` is untouched. What killed
    writers left in the directory goes first (remove_dead_temporaries)."""
    path = Path(path)
    remove_dead_temporaries(path.parent)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.{os.getpid()}.", suffix=".tmp")
    try:
        os.fchmod(fd, 0o666 & ~_umask())  # what open() would have made, not mkstemp's 0600
        if "b" not in mode:
            kwargs.setdefault("encoding", "utf-8")
        with os.fdopen(fd, mode, **kwargs) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    dirfd = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(dirfd)  # the rename itself reaches the disk
    finally:
        os.close(dirfd)


@contextlib.contextmanager
def writing(path: str | Path, error: type[Exception]) -> Iterator[None]:
    """An OSError in the block (a full disk, a read-only directory) is `error` with one line naming `path`."""
    try:
        yield
    except OSError as exc:
        raise error(f"{path}: cannot write ({exc.strerror or exc})") from None


def write_text(path: str | Path, text: str, error: type[Exception] | None = None) -> None:
    """`text` as the UTF-8 content of `path`, atomically; with `error`, a failed write is that error."""
    with writing(path, error) if error is not None else contextlib.nullcontext(), atomic_open(path) as fh:
        fh.write(text)


def write_json(path: str | Path, doc, error: type[Exception] | None = None) -> None:
    write_text(path, dumps_json(doc), error)


def write_bytes(path: str | Path, data: bytes, error: type[Exception] | None = None) -> None:
    """`data` as the content of `path`, atomically (a file whose bytes the caller also hashes)."""
    with writing(path, error) if error is not None else contextlib.nullcontext(), atomic_open(path, "wb") as fh:
        fh.write(data)
