"""The measurement table of DESIGN.md: read, validate, write.

seq,t_s,pose,station,point,q1_deg..qn_deg,x_mm,y_mm,z_mm[,extra columns ignored by readers]
Every bad input is reported as one line naming the file, the row (1-based, header = row 1) and the column.

Reading streams the file in blocks of whole lines, so memory is the table itself plus one block, and no Python
code runs per cell. A plain block (every table trackcal writes) is parsed as one grid of cells by whole-array
operations (calib.csv_grid); any other block, and any block with a bad cell, goes to the general parser, numpy's
C tokenizer (loadtxt), which reads it or names the first bad cell. Ids are interned (a pose id is one string
however many rows share it) and extra columns are numpy variable-width strings.
"""

from __future__ import annotations

import codecs
import csv
import dataclasses
import io
import itertools
import math
import re
import sys
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np

from trackcal.calib.errors import CalibError
from trackcal.calib.io import csv_grid
from trackcal.calib.io.csv_grid import TEXT
from trackcal.calib.io.files import atomic_open


class JointLimits(Protocol):
    """What a table is checked against: a robot's joint count and limits (calib.model.chain.Chain is one). Declared
    here, on the floor below the model, which reads its files with calib.io (issue 37: no circle of types)."""

    @property
    def dof(self) -> int: ...

    def limits_array(self) -> np.ndarray: ...  # (dof, 2): each joint's (low, high), rad


XYZ = ("x_mm", "y_mm", "z_mm")
IDS = ("pose", "station", "point")

BLOCK_BYTES = 1 << 23  # 8 MiB of whole lines per parse: ~80k rows of the DESIGN layout
MAX_LINE_BYTES = 1 << 20  # no table row is a megabyte; a longer "line" is not a table (and would fill memory)
# At most 8 bytes per float cell and 16 per id or extra cell (a numpy string of up to 15 bytes is stored in
# place; longer ones add their own bytes), so 30 M cells keep a table under 0.5 GB, 1 GB with the parse
# temporaries; that is 2.1 M rows of the 14-column layout (58 hours of measurements at 10 Hz).
MAX_CELLS = 30_000_000
# Joint values are controller readings at rest, inside its software limits; the limits in the robot files
# are datasheet figures in whole degrees (paper Table 4), so a reading may lie up to 0.5 deg past the
# rounded figure. 1 deg covers that with room, and the mistakes this check is for (a shifted column, a
# value in the wrong unit, 1e300) are far larger.
JOINT_LIMIT_MARGIN_DEG = 1.0


class TableError(CalibError):
    """A measurement table that cannot be used; the message names file, row and column."""


@dataclass
class MeasurementTable:
    seq: np.ndarray  # (N,) int
    t_s: np.ndarray  # (N,)
    pose: list[str]
    station: list[str]
    point: list[str]
    q_deg: np.ndarray  # (N, n)
    xyz: np.ndarray | None  # (N, 3) or None when the table has no measurements (predict input)
    extra: dict[str, np.ndarray] = field(default_factory=dict)  # name -> (N,) strings, as written
    source: str = "table"

    def __post_init__(self) -> None:
        self.extra = {k: np.asarray(v, dtype=TEXT) for k, v in self.extra.items()}

    def __len__(self) -> int:
        return len(self.seq)

    @property
    def n_joints(self) -> int:
        return self.q_deg.shape[1]

    def subset(self, rows: np.ndarray) -> MeasurementTable:
        """The table of `rows` (indices), in that order."""
        rows = np.asarray(rows)
        at = rows.tolist()  # Python ints index the label lists faster than numpy's
        # increasing rows (a fold's, a diagnosis's) taken by a mask from the text columns: the same strings, 5x faster
        # than by indices (numpy's StringDType; 70 ms of a diagnosis of Series B, issue 41)
        text_rows = rows
        if len(rows) > 1 and bool(np.all(rows[1:] > rows[:-1])):
            text_rows = np.zeros(len(self), dtype=bool)
            text_rows[rows] = True
        return MeasurementTable(
            seq=self.seq[rows],
            t_s=self.t_s[rows],
            pose=[self.pose[i] for i in at],
            station=[self.station[i] for i in at],
            point=[self.point[i] for i in at],
            q_deg=self.q_deg[rows],
            xyz=None if self.xyz is None else self.xyz[rows],
            extra={k: v[text_rows] for k, v in self.extra.items()},
            source=self.source,
        )


def label_codes(labels: list[str]) -> tuple[np.ndarray, list[str]]:
    """(an integer per label: its rank among the distinct labels in order of first appearance; those labels), by a
    dict (a third of the time of np.unique of the labels as numpy strings at 100k rows: issue 41)."""
    distinct = list(dict.fromkeys(labels))
    index = dict(zip(distinct, range(len(distinct)), strict=True))
    return np.fromiter(map(index.__getitem__, labels), dtype=np.intp, count=len(labels)), distinct


def joint_columns(n: int) -> list[str]:
    return [f"q{j + 1}_deg" for j in range(n)]


def read_blocks(path: Path, error: type[TableError] = TableError) -> Iterator[tuple[int, bytes]]:
    """(row number of the first line, whole lines) blocks of a UTF-8 text file (a leading BOM dropped, CRLF line
    ends made LF; the last line may lack its newline), in bounded memory; an unreadable or non-UTF-8 file or an
    overlong line is `error` naming the file and the row."""
    try:
        fh = path.open("rb")
    except OSError as exc:
        raise error(f"{path}: cannot read ({exc.strerror or exc})") from None
    with fh:
        row, rest, first = 1, b"", True
        while True:
            try:
                chunk = fh.read(BLOCK_BYTES)
            except OSError as exc:
                raise error(f"{path}: cannot read ({exc.strerror or exc})") from None
            data = rest + chunk
            if first:
                data, first = data.removeprefix(codecs.BOM_UTF8), False
            end = len(data) if not chunk else data.rfind(b"\n") + 1
            whole, rest = data[:end], data[end:]
            if len(rest) > MAX_LINE_BYTES:
                r = row + whole.count(b"\n")
                raise error(f"{path}: row {r}: longer than {MAX_LINE_BYTES} bytes, not a table row")
            if not whole.isascii():
                try:
                    whole.decode("utf-8")
                except UnicodeDecodeError as exc:
                    r = row + whole.count(b"\n", 0, exc.start)
                    bad = whole[exc.start]
                    raise error(f"{path}: row {r}: not UTF-8 text (byte 0x{bad:02x}); save the file as UTF-8") from None
            if b"\r" in whole:
                whole = whole.replace(b"\r\n", b"\n")
            if whole:
                yield row, whole
                row += whole.count(b"\n") + (not whole.endswith(b"\n"))
            if not chunk:
                return


def split_lines(data: bytes) -> list[str]:
    """The lines of a block from read_blocks, line ends removed."""
    lines = data.decode("utf-8").split("\n")
    if lines[-1] == "":
        lines.pop()
    return lines


# separators a spreadsheet writes instead of the comma (Excel in a locale with decimal commas writes ';')
OTHER_SEPARATORS = {";": "';'", "\t": "tabs", "|": "'|'"}
DECIMAL_COMMA = re.compile(r"(?:^|[;\t|])\s*[-+]?\d+,\d+\s*(?=$|[;\t|])")


def separator_note(line: str, delimiter: str, sample: str | None = None) -> str | None:
    """Why a header without `delimiter` that another separator splits into names is no table of ours (and
    whether its first data row `sample` writes decimal commas); None for any other header."""
    if delimiter in line:
        return None
    for sep, name in OTHER_SEPARATORS.items():
        if sep in line:
            commas = " with decimal commas" if sample and DECIMAL_COMMA.search(sample) else ""
            return (
                f"this table is separated by {name}{commas}, not by {delimiter!r}: save it as comma-separated "
                f"values with decimal points (a spreadsheet's CSV export in an English locale)"
            )
    return None


def split_header(
    path: Path, line: str, delimiter: str, error: type[TableError], sample: str | None = None
) -> list[str]:
    """Row 1: distinct column names, stripped. A header another separator splits (a spreadsheet's ';') is
    refused saying so (`sample`: the first data row, to tell decimal commas too)."""
    note = separator_note(line, delimiter, sample)
    if note is not None:
        raise error(f"{path}: row 1: {note}")
    try:
        header = [h.strip() for h in next(csv.reader([line], delimiter=delimiter))]
    except csv.Error as exc:
        raise error(f"{path}: row 1: not a {delimiter!r}-separated header ({exc})") from None
    if len(set(header)) != len(header):
        raise error(f"{path}: row 1: duplicate column names")
    return header


def read_csv(path: Path, delimiter: str = ",", error: type[TableError] = TableError) -> list[list[str]]:
    """The rows of a small delimited text file whose first row is a header of distinct names (stripped);
    every failure is `error` naming the file (and the row)."""
    lines = [line for _, block in read_blocks(path, error) for line in split_lines(block)]
    if not lines:
        raise error(f"{path}: empty file, expected a header row")
    try:
        rows = list(csv.reader(lines, delimiter=delimiter))
    except csv.Error as exc:
        raise error(f"{path}: not a {delimiter!r}-separated text file ({exc})") from None
    rows[0] = split_header(path, lines[0], delimiter, error, lines[1] if len(lines) > 1 else None)
    return rows


def _fields(line: str) -> list[str]:
    try:
        return next(csv.reader([line]), [])
    except csv.Error:
        return line.split(",")


def _parse(lines: list[str], cols: list[int], dtype) -> np.ndarray:
    return np.loadtxt(lines, delimiter=",", quotechar='"', comments=None, usecols=cols, dtype=dtype, ndmin=2)


def _first_bad_cell(lines: list[str], cols: list[int], dtype) -> tuple[int, int]:
    """(line index, index into cols) of the first cell that does not parse (the block is known to fail)."""
    lo, hi = 0, len(lines)  # the first bad line is in [lo, hi)
    while hi - lo > 1:
        mid = (lo + hi) // 2
        try:
            _parse(lines[lo:mid], cols, dtype)
        except ValueError:
            hi = mid
        else:
            lo = mid
    for k, c in enumerate(cols):
        try:
            _parse(lines[lo : lo + 1], [c], dtype)
        except ValueError:
            return lo, k
    return lo, 0  # the line as a whole does not tokenize (a stray quote)


# A measured coordinate farther than this from its tracker is no measurement: the AT901-LR reaches 80 m (Leica
# Absolute Tracker AT901 product brochure: measuring range 160 m diameter), any laser tracker tens of metres. A table
# in the wrong unit or with a corrupt cell (1e300 mm) is refused here, in one line, not by the fit's numerics.
MAX_COORDINATE_MM = 1.0e6


class _Columns:
    """Where each required column is, and the growing result."""

    def __init__(self, path: Path, header: list[str], qcols: list[str], has_xyz: bool):
        self.path, self.header = path, header
        col = {h: i for i, h in enumerate(header)}
        self.numeric = ["seq", "t_s", *qcols, *(XYZ if has_xyz else ())]
        self.num_idx = [col[c] for c in self.numeric]
        self.extra = [h for h in header if h not in self.numeric and h not in IDS]
        self.text = [*IDS, *self.extra]
        self.text_idx = [col[c] for c in self.text]
        self.xyz = slice(len(self.numeric) - len(XYZ), None) if has_xyz else slice(0, 0)  # the coordinates' columns
        self.numbers: list[np.ndarray] = []
        self.texts: list[np.ndarray] = []
        self.ids: list[list[str]] = [[] for _ in IDS]

    def add_plain(self, data: bytes) -> int | None:
        """Add a block through the grid parser: its row count, or None (nothing added) when a cell is not
        plain or not valid, for `add` to read the block or name the cell."""
        grid = csv_grid.split(data, len(self.header))
        if grid is None:
            return None
        num = np.empty((len(grid), len(self.numeric)))
        for k, c in enumerate(self.num_idx):
            column = grid.numbers(c)
            if column is None:
                return None
            num[:, k] = column
        if (np.abs(num[:, 0]) > 2**53).any() or (num[:, 0] != np.rint(num[:, 0])).any():
            return None  # seq not an integer
        if (np.abs(num[:, self.xyz]) > MAX_COORDINATE_MM).any():
            return None  # a coordinate no tracker measures
        ids = [grid.ids(c) for c in self.text_idx[: len(IDS)]]
        texts = [grid.text(c) for c in self.text_idx[len(IDS) :]]
        if any(column is None for column in [*ids, *texts]):
            return None
        for dst, column in zip(self.ids, ids, strict=True):
            dst.extend(column)
        self.numbers.append(num)
        self.texts.append(np.stack(texts, axis=1) if texts else np.empty((len(grid), 0), dtype=TEXT))
        return len(grid)

    def add(self, row: int, lines: list[str]) -> None:
        path = self.path
        joined = "\n".join(lines)
        if '"' in joined or joined.count(",") != len(lines) * (len(self.header) - 1):
            self.check_counts(row, lines)
        try:
            num = _parse(lines, self.num_idx, np.float64)
        except ValueError:
            self.check_counts(row, lines)  # a short row and a long one leave the comma count right
            k, c = _first_bad_cell(lines, self.num_idx, np.float64)
            text = _fields(lines[k])[self.num_idx[c]].strip()
            raise TableError(f"{path}: row {row + k}: column {self.numeric[c]}: not a number: {text!r}") from None
        try:
            # Read as Python strings, then made numpy strings: loadtxt straight into StringDType loses cells of 16
            # bytes or more (numpy 2.4.6: MemoryError "Failed to load string" reading them back; shorter strings
            # are stored inline and survive; found by tests/test_table_grid.py).
            txt = _parse(lines, self.text_idx, object).astype(TEXT)
        except ValueError:
            self.check_counts(row, lines)
            k, c = _first_bad_cell(lines, self.text_idx, object)
            raise TableError(f"{path}: row {row + k}: column {self.text[c]}: not a CSV field") from None
        finite = np.isfinite(num)
        if not finite.all():
            k, c = np.argwhere(~finite)[0]
            text = _fields(lines[k])[self.num_idx[c]].strip()
            raise TableError(f"{path}: row {row + k}: column {self.numeric[c]}: not a finite number: {text!r}")
        far = np.argwhere(np.abs(num[:, self.xyz]) > MAX_COORDINATE_MM)
        if far.size:
            k, c = far[0]
            text = _fields(lines[k])[self.num_idx[self.xyz][c]].strip()
            raise TableError(
                f"{path}: row {row + k}: column {self.numeric[self.xyz][c]}: {text} mm is beyond "
                f"{MAX_COORDINATE_MM / 1e6:g} km from the tracker: no tracker measures there (a wrong unit or a "
                "corrupt cell?)"
            )
        seq = num[:, 0]
        not_int = np.flatnonzero((seq != np.rint(seq)) | (np.abs(seq) > 2**53))
        if not_int.size:
            k = not_int[0]
            text = _fields(lines[k])[self.num_idx[0]].strip()
            raise TableError(f"{path}: row {row + k}: column seq: not an integer: {text!r}")
        ids = np.strings.strip(txt[:, : len(IDS)])
        empty = np.argwhere(np.strings.str_len(ids) == 0)
        if empty.size:
            k, c = empty[0]
            raise TableError(f"{path}: row {row + k}: column {IDS[c]}: empty id")
        for dst, column in zip(self.ids, ids.T, strict=True):
            dst.extend(map(sys.intern, column.tolist()))  # one string per distinct id, however many rows
        self.numbers.append(num)
        self.texts.append(txt[:, len(IDS) :])

    def check_counts(self, row: int, lines: list[str]) -> None:
        n = len(self.header)
        counts = [len(_fields(line)) for line in lines]
        bad = next((k for k, c in enumerate(counts) if c != n), None)
        if bad is not None and not lines[bad].strip():
            raise TableError(f"{self.path}: row {row + bad}: empty row")
        if bad is not None:
            raise TableError(f"{self.path}: row {row + bad}: {counts[bad]} fields, the header has {n}")

    def check_repeats(self, seq: np.ndarray) -> None:
        """The first row that repeats an earlier row's seq is an error naming both rows."""
        order = np.argsort(seq, kind="stable")
        repeat = np.flatnonzero(seq[order][1:] == seq[order][:-1])
        if repeat.size:
            later = order[repeat + 1]
            k = int(np.argmin(later))
            first = int(order[repeat[k]])
            raise TableError(
                f"{self.path}: row {later[k] + 2}: column seq: {seq[first]} already used in row {first + 2}"
            )

    def table(self, n_joints: int, has_xyz: bool) -> MeasurementTable:
        num = np.concatenate(self.numbers)
        txt = np.concatenate(self.texts)
        seq = num[:, 0].astype(np.int64)
        if not (seq[1:] > seq[:-1]).all():  # not in order (as tables are written): look for a repeat
            self.check_repeats(seq)
        return MeasurementTable(
            seq=seq,
            t_s=num[:, 1].copy(),
            pose=self.ids[0],
            station=self.ids[1],
            point=self.ids[2],
            q_deg=num[:, 2 : 2 + n_joints].copy(),
            xyz=num[:, 2 + n_joints :].copy() if has_xyz else None,
            extra={h: txt[:, k] for k, h in enumerate(self.extra)},
            source=str(self.path),
        )


def read_table(
    path: str | Path, require_xyz: bool = True, n_joints: int | None = None, chain: JointLimits | None = None
) -> MeasurementTable:
    """The table at `path`; with the robot's `chain`, its joint count is required and joint values more than
    JOINT_LIMIT_MARGIN_DEG outside its limits are refused."""
    path = Path(path)
    if chain is not None:
        n_joints = chain.dof
    blocks = read_blocks(path)
    first = next(blocks, None)
    if first is None:
        raise TableError(f"{path}: empty file, expected a header row")
    line, _, body = first[1].partition(b"\n")
    sample = body.partition(b"\n")[0].decode("utf-8", errors="replace")
    header = split_header(path, line.decode("utf-8"), ",", TableError, sample)
    qcols = []
    while f"q{len(qcols) + 1}_deg" in header:
        qcols.append(f"q{len(qcols) + 1}_deg")
    if n_joints is not None and len(qcols) != n_joints:
        raise TableError(f"{path}: row 1: expected joint columns q1_deg..q{n_joints}_deg, found {len(qcols)}")
    required = ["seq", "t_s", *IDS, *qcols] + (list(XYZ) if require_xyz else [])
    missing = [c for c in required if c not in header]
    if not qcols:
        missing.append("q1_deg")
    if missing:
        raise TableError(f"{path}: row 1: missing column(s) {', '.join(missing)}")
    has_xyz = all(c in header for c in XYZ)
    columns = _Columns(path, header, qcols, has_xyz)
    max_rows = row_limit(len(header))

    def check_rows(rows: int) -> None:
        if rows > max_rows:
            raise TableError(
                f"{path}: more than {max_rows} rows, the limit for {len(header)} columns ({MAX_CELLS} cells, "
                "to stay under 1 GB of memory); split the table"
            )

    trailing_blank: int | None = None  # the first row of the blank rows seen last: allowed only at the end
    rows = 0
    for row, data in itertools.chain([(2, body)], blocks):
        if not data:
            continue
        n = columns.add_plain(data)
        if n is not None:  # no blank row in it
            if trailing_blank is not None:
                raise TableError(f"{path}: row {trailing_blank}: empty row")
            rows += n
            check_rows(rows)
            continue
        block = split_lines(data)
        n = len(block)
        while n and not block[n - 1].strip():
            n -= 1
        if n and trailing_blank is not None:
            raise TableError(f"{path}: row {trailing_blank}: empty row")
        if n < len(block) and trailing_blank is None:
            trailing_blank = row + n
        block = block[:n]
        if "" in block:
            raise TableError(f"{path}: row {row + block.index('')}: empty row")
        if not block:
            continue
        rows += len(block)
        check_rows(rows)
        columns.add(row, block)
    if not rows:
        raise TableError(f"{path}: no data rows")
    table = columns.table(len(qcols), has_xyz)
    if chain is not None:
        check_limits(table, np.degrees(chain.limits_array()), qcols)
    return table


def check_limits(table: MeasurementTable, limits_deg: np.ndarray, qcols: list[str]) -> None:
    lo = limits_deg[:, 0] - JOINT_LIMIT_MARGIN_DEG
    hi = limits_deg[:, 1] + JOINT_LIMIT_MARGIN_DEG
    outside = np.argwhere((table.q_deg < lo) | (table.q_deg > hi))
    if outside.size:
        k, j = outside[0]
        raise TableError(
            f"{table.source}: row {k + 2}: column {qcols[j]}: {table.q_deg[k, j]:g} deg is outside the joint's "
            f"limits [{limits_deg[j, 0]:g}, {limits_deg[j, 1]:g}] deg (+-{JOINT_LIMIT_MARGIN_DEG:g} deg margin)"
        )


def _fmt(v: float, digits: int) -> str:
    return f"{v:.{digits}f}"


def table_csv(table: MeasurementTable) -> str:
    """The text of the table's file in the DESIGN.md layout (q to 1e-4 deg as the controller reports, xyz to
    1e-4 mm, t to 1e-3 s), rows ending in LF."""
    header = ["seq", "t_s", *IDS, *joint_columns(table.n_joints)]
    if table.xyz is not None:
        header += list(XYZ)
    header += list(table.extra)
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow(header)
    for i in range(len(table)):
        row = [str(int(table.seq[i])), _fmt(table.t_s[i], 3), table.pose[i], table.station[i], table.point[i]]
        row += [_fmt(v, 4) for v in table.q_deg[i]]
        if table.xyz is not None:
            row += [_fmt(v, 4) for v in table.xyz[i]]
        row += [table.extra[h][i] for h in table.extra]
        w.writerow(row)
    return out.getvalue()


def as_written(table: MeasurementTable) -> MeasurementTable:
    """The table as its file (`table_csv`) holds it: the numbers rounded as written, what read_table would give."""

    def rounded(values: np.ndarray, digits: int) -> np.ndarray:
        return np.vectorize(lambda v: float(_fmt(v, digits)), otypes=[float])(values)

    return dataclasses.replace(
        table,
        t_s=rounded(table.t_s, 3),
        q_deg=rounded(table.q_deg, 4),
        xyz=None if table.xyz is None else rounded(table.xyz, 4),
    )


def row_limit(columns: int) -> int:
    """The most rows a table of `columns` columns may hold (MAX_CELLS cells)."""
    return MAX_CELLS // columns


def write_table(table: MeasurementTable, path: str | Path) -> None:
    """Write `table_csv(table)` to `path`, atomically."""
    with atomic_open(path, "w", newline="") as fh:
        fh.write(table_csv(table))


def read_joint_rows(path: str | Path, dof: int, what: str = "rows") -> tuple[np.ndarray, dict[str, list[str]]]:
    """Joint rows (N, dof) in degrees from a CSV with columns q1_deg..q{dof}_deg (a plan's poses, compensation
    targets), and its other columns as text; blank lines are skipped. A q{dof+1}_deg column is refused: the
    file was written for another robot."""
    path = Path(path)
    rows = read_csv(path)
    header, cols = rows[0], joint_columns(dof)
    missing = [c for c in cols if c not in header]
    if missing:
        raise TableError(f"{path}: row 1: missing column(s) {', '.join(missing)} (the robot has {dof} joints)")
    if f"q{dof + 1}_deg" in header:
        raise TableError(f"{path}: row 1: column q{dof + 1}_deg: the robot has only {dof} joints")
    idx = [header.index(c) for c in cols]
    others = {h: [] for h in header if h not in cols}
    q = []
    for k, row in enumerate(rows[1:]):
        if not any(cell.strip() for cell in row):
            continue
        r = k + 2
        if len(row) != len(header):
            raise TableError(f"{path}: row {r}: {len(row)} fields, the header has {len(header)}")
        values = []
        for c, i in zip(cols, idx, strict=True):
            try:
                v = float(row[i])
            except ValueError:
                raise TableError(f"{path}: row {r}: column {c}: not a number: {row[i]!r}") from None
            if not math.isfinite(v):
                raise TableError(f"{path}: row {r}: column {c}: not a finite number: {row[i]!r}")
            values.append(v)
        q.append(values)
        for h in others:
            others[h].append(row[header.index(h)].strip())
    if not q:
        raise TableError(f"{path}: no {what}")
    return np.array(q), others
