"""A MATLAB .mat file (format v4 to v7, scipy.io.loadmat) as the columns of a table, for the import map.

Each variable is one column per matrix column, named as MATLAB indexes it: a vector `t` (N x 1 or 1 x N) is the
column `t`, a matrix `q` (N x 6) the columns `q(:,1)` ... `q(:,6)`, in the file's order (positions count them so);
a 1 x N variable is both the column `t` and N one-row columns `t(:,j)` (one pose's joints), the map says which. A
char matrix or a cell array of strings is a column of ids. Rows are the first dimension. Other variables (structs,
3-D arrays, complex numbers) are no columns, and are named with what they are when a map asks for them. Numbers
become their shortest repr (NaN as `nan`), so the map's reader treats them as a text export's.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.io
from scipy.io.matlab import MatReadError

MAT_SUFFIX = ".mat"


@dataclass
class MatColumns:
    header: list[str]  # column names
    cells: list[list[str]]  # per column, its cells as text
    holds: str  # what the file holds, for an error: `q (100x6 double), P1 (100x3 double)`
    matrices: dict[str, int]  # a matrix variable's name -> its column count (for a map naming it bare)


def is_mat(path: Path) -> bool:
    return path.suffix.lower() == MAT_SUFFIX


def _shape(v: np.ndarray) -> str:
    return "x".join(str(n) for n in v.shape)


def _strings(v: np.ndarray) -> list[str] | None:
    """The ids of a char array (one string per row) or a cell array of strings; None for anything else."""
    if v.dtype.kind == "U":
        return [str(s).strip() for s in v.ravel()] if v.ndim <= 1 or min(v.shape) == 1 else None
    if v.dtype == object and v.ndim <= 2 and (v.ndim < 2 or min(v.shape) == 1):
        out = []
        for e in v.ravel():
            e = np.asarray(e)
            if e.dtype.kind != "U" or e.size > 1:
                return None
            out.append(str(e.ravel()[0]).strip() if e.size else "")
        return out
    return None


def read_mat(path: Path, error: type[Exception]) -> MatColumns:
    """The columns of the .mat file at `path`; a file loadmat cannot read is `error` in one line saying why."""
    try:
        doc = scipy.io.loadmat(str(path), chars_as_strings=True)
    except NotImplementedError:  # scipy: "Please use HDF reader for matlab v7.3 files"
        raise error(
            f"{path}: a MATLAB v7.3 (HDF5) file, which this reader cannot open: save it in MATLAB with "
            "save(FILE, ..., '-v7')"
        ) from None
    except OSError as exc:
        raise error(f"{path}: cannot read ({exc.strerror or exc})") from None
    except (
        MatReadError,
        ValueError,
        TypeError,
        KeyError,
        IndexError,
        EOFError,
        AttributeError,
        UnicodeDecodeError,
        MemoryError,
        OverflowError,
    ) as exc:
        text = " ".join(str(exc).split())[:120] or type(exc).__name__
        raise error(f"{path}: not a MATLAB .mat file that can be read ({text})") from None
    header: list[str] = []
    cells: list[list[str]] = []
    holds: list[str] = []
    matrices: dict[str, int] = {}
    for name, v in doc.items():
        if name.startswith("__"):  # loadmat's own: __header__, __version__, __globals__
            continue
        v = np.asarray(v)
        ids = _strings(v)
        if ids is not None:
            header.append(name)
            cells.append(ids)
            holds.append(f"{name} ({len(ids)} ids)")
            continue
        if v.dtype.kind not in "biuf" or v.ndim > 2 or v.size == 0:
            kind = {"c": "complex", "V": "struct", "O": "cell"}.get(v.dtype.kind, str(v.dtype))
            holds.append(f"{name} ({_shape(v)} {kind}, not a column)")
            continue
        a = v.astype(float).reshape(v.shape[0], -1) if v.ndim == 2 else v.astype(float).reshape(-1, 1)
        holds.append(f"{name} ({_shape(a)} {'double' if v.dtype.kind == 'f' else str(v.dtype)})")
        if a.shape[1] == 1 or a.shape[0] == 1:  # a vector, as a column or as a row: the column `name`
            header.append(name)
            cells.append([repr(float(x)) for x in a.ravel()])
        if a.shape[1] == 1:
            continue
        matrices[name] = a.shape[1]  # also one row of columns name(:,j): a one-row matrix
        for j in range(a.shape[1]):
            header.append(f"{name}(:,{j + 1})")
            cells.append([repr(float(x)) for x in a[:, j]])
    return MatColumns(header, cells, ", ".join(holds) or "no variables", matrices)
