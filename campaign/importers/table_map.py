"""Another tool's tracker export as a measurement table, through a map that says where everything is.

The map (YAML; docs/import-map.md documents every key with two examples):

    separator: ";"            # one character (default ","); "\\t" for tabs
    decimal: ","              # "." (default) or ","
    skip_rows: 0              # lines before the header row (an export's preamble)
    header: true              # the first row after skip_rows names the columns (default true)
    positions: 1-based        # how a column given as a number counts: 1-based or 0-based (required then)
    layout: point_rows        # point_rows: one row per point; pose_rows: one row per pose, a column group per point
    units: {joints: deg, length: mm}          # joints deg | rad, length mm | m | in
    columns:
      joints: [A1, A2, A3, A4, A5, A6]        # names (header) or positions
      xyz: [X, Y, Z]                          # point_rows: the reflector position
      point: SMR                              # point_rows: the point id column (or a fixed `point: P1` below)
      pose: Pose                              # optional: pose ids (default: sequential, see below)
      time: Time                              # optional: seconds (default: the row index, not a time)
      station: Station                        # optional (default: the fixed `station` below)
      load: Load                              # optional: the payload mounted (kg), table column load_kg
    points:                                   # pose_rows: point id -> its x, y, z columns
      P1: [P1 X, P1 Y, P1 Z]
    station: T1                               # the station id when there is no station column (default T1)
    point: P1                                 # point_rows without a point column: the one reflector's id, or
                                              # "{file}": each file's name (one file per point)

Rows are numbered as in the file (its first line is row 1, preamble and header included), columns named by their
header name and position; every bad cell is one line naming both. Without a pose column, rows with the same joint
values share a pose, in every file of one import: ids P0001, P0002, ... in order of first appearance. In pose_rows
a point whose three cells are all empty was not measured at that pose and gives no row. A position with a NaN (or,
in point_rows, three empty cells) is a row where the tracker had no reading: skipped and counted (MAX_MISSING).
A file ending in .mat is read as MATLAB's (campaign/importers/mat_file.py); with a joints file, the positions files
are joined to it by row.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from trackcal.calib.diagnose.extensions import LOAD_COLUMN
from trackcal.calib.io import fields
from trackcal.calib.io.files import read_yaml
from trackcal.calib.io.table import MeasurementTable, TableError, read_blocks, split_lines
from trackcal.campaign.importers.mat_file import MatColumns, is_mat, read_mat

LAYOUTS = ("point_rows", "pose_rows")
JOINT_UNITS = {"deg": 1.0, "rad": 180.0 / math.pi}
LENGTH_UNITS = {"mm": 1.0, "m": 1000.0, "in": 25.4}  # the inch is 25.4 mm exactly (NIST SP 811, B.6)
POSITIONS = {"1-based": 1, "0-based": 0}
SEPARATORS = {",": "','", ";": "';'", "\t": "tabs", "|": "'|'"}
KEYS = (
    "separator",
    "decimal",
    "skip_rows",
    "header",
    "positions",
    "layout",
    "units",
    "columns",
    "points",
    "station",
    "point",
)
COLUMN_KEYS = ("joints", "xyz", "point", "pose", "time", "station", "load")
ROBOT_KEYS = ("joints", "pose", "time", "station", "load")  # joined by row: the joints file's columns
POSITION_KEYS = ("xyz", "point")  # joined by row: each positions file's columns
# A point with more than this share of its rows without a reading is refused: the tracker loses the beam at some
# poses (a link in the line of sight, a nest turned past its acceptance angle), but when the rows without a reading
# outnumber those with one, the map more likely names the wrong columns (another reflector's, a status column), or
# the tracker did not follow that reflector: the campaign the export describes is not the one measured.
MAX_MISSING = 0.5


FILE_POINT = "{file}"  # the fixed point id that is each file's name without its extension (one file per point)


class ImportMapError(TableError):
    """A map that cannot be used, or a file that does not follow it; the message names the key or the cell."""


@dataclass(frozen=True)
class Column:
    index: int  # 0-based position in a row
    label: str  # how an error names it: column 'X' (position 12), or column 12


@dataclass
class TableMap:
    """A map read and checked (column references still unresolved: names need the header)."""

    source: str
    separator: str = ","
    decimal: str = "."
    skip_rows: int = 0
    header: bool = True
    base: int | None = None  # 1 or 0 (positions), None when no column is given by position
    layout: str = "point_rows"
    joint_factor: float = 1.0  # to degrees
    length_factor: float = 1.0  # to mm
    columns: dict | None = None  # key -> reference (name or position) or list of references
    points: dict | None = None  # pose_rows: point id -> [x, y, z] references
    station: str = "T1"
    point: str = "P1"


def _ref(value, where: str, path: str) -> str | int:
    if isinstance(value, bool) or not isinstance(value, str | int):
        raise ImportMapError(f"{path}: {where}: expected a column name or position, got {value!r}")
    return value


def _refs(value, where: str, path: str, n: int | None = None) -> list[str | int]:
    items = fields.sequence(value, f"{path}: {where}", ImportMapError)
    if n is not None and len(items) != n:
        raise ImportMapError(f"{path}: {where}: expected {n} columns (x, y, z), got {len(items)}")
    if not items:
        raise ImportMapError(f"{path}: {where}: expected at least one column")
    return [_ref(v, f"{where}[{i}]", path) for i, v in enumerate(items)]


def load_map(path: str | Path) -> TableMap:
    """The map at `path`, every key checked (one line naming the key when wrong)."""
    path = str(path)
    doc = read_yaml(path, ImportMapError)
    unknown = [k for k in doc if k not in KEYS]
    if unknown:
        raise ImportMapError(f"{path}: {unknown[0]}: unknown key; the keys are {', '.join(KEYS)}")
    m = TableMap(source=path)
    _read_text_format(m, doc, path)
    _read_units(m, doc, path)
    _read_columns(m, doc, path)
    m.station = fields.text(doc.get("station", "T1"), f"{path}: station", ImportMapError)
    m.point = fields.text(doc.get("point", "P1"), f"{path}: point", ImportMapError)
    _read_positions(m, doc, path)
    return m


def _read_text_format(m: TableMap, doc: dict, path: str) -> None:
    """load_map's separator, decimal mark, rows skipped, header and layout, into `m`."""
    m.separator = fields.text(doc.get("separator", ","), f"{path}: separator", ImportMapError)
    if m.separator in ("\\t", "tab"):
        m.separator = "\t"
    if len(m.separator) != 1 or m.separator in "\"'\n" or m.separator.isalnum():
        raise ImportMapError(f"{path}: separator: expected one character such as ',' ';' '\\t', got {m.separator!r}")
    m.decimal = fields.text(doc.get("decimal", "."), f"{path}: decimal", ImportMapError)
    if m.decimal not in (".", ","):
        raise ImportMapError(f"{path}: decimal: expected '.' or ',', got {m.decimal!r}")
    if m.decimal == "," == m.separator:
        raise ImportMapError(f"{path}: decimal ',' needs another separator than ',' (set separator: ';')")
    m.skip_rows = fields.integer(doc.get("skip_rows", 0), f"{path}: skip_rows", ImportMapError)
    if m.skip_rows < 0:
        raise ImportMapError(f"{path}: skip_rows: expected 0 or more, got {m.skip_rows}")
    if not isinstance(doc.get("header", True), bool):
        raise ImportMapError(f"{path}: header: expected true or false, got {doc['header']!r}")
    m.header = doc.get("header", True)
    m.layout = fields.text(doc.get("layout", "point_rows"), f"{path}: layout", ImportMapError)
    if m.layout not in LAYOUTS:
        raise ImportMapError(f"{path}: layout: expected {' or '.join(LAYOUTS)}, got {m.layout!r}")


def _read_units(m: TableMap, doc: dict, path: str) -> None:
    """load_map's units (joints, length), into `m` as factors to degrees and millimetres."""
    units = fields.mapping(doc.get("units") or {}, f"{path}: units", ImportMapError)
    for key in units:
        if key not in ("joints", "length"):
            raise ImportMapError(f"{path}: units.{key}: unknown key; the keys are joints, length")
    ju, lu = str(units.get("joints", "deg")), str(units.get("length", "mm"))
    if ju not in JOINT_UNITS:
        raise ImportMapError(f"{path}: units.joints: expected {' or '.join(JOINT_UNITS)}, got {ju!r}")
    if lu not in LENGTH_UNITS:
        raise ImportMapError(f"{path}: units.length: expected {', '.join(LENGTH_UNITS)}, got {lu!r}")
    m.joint_factor, m.length_factor = JOINT_UNITS[ju], LENGTH_UNITS[lu]


def _read_columns(m: TableMap, doc: dict, path: str) -> None:
    """load_map's columns (and for layout pose_rows, the points' columns), into `m`."""
    cols = fields.mapping(doc.get("columns"), f"{path}: columns", ImportMapError)
    for key in cols:
        if key not in COLUMN_KEYS:
            raise ImportMapError(f"{path}: columns.{key}: unknown key; the keys are {', '.join(COLUMN_KEYS)}")
    if "joints" not in cols:
        raise ImportMapError(f"{path}: columns.joints: missing (the joint columns, in joint order)")
    m.columns = {"joints": _refs(cols["joints"], "columns.joints", path)}
    for key in ("point", "pose", "time", "station", "load"):
        if cols.get(key) is not None:
            m.columns[key] = _ref(cols[key], f"columns.{key}", path)
    if m.layout == "point_rows":
        if "xyz" not in cols:
            raise ImportMapError(f"{path}: columns.xyz: missing (layout point_rows: the x, y, z columns)")
        m.columns["xyz"] = _refs(cols["xyz"], "columns.xyz", path, 3)
        if "points" in doc:
            raise ImportMapError(f"{path}: points: only for layout pose_rows (point_rows: columns.point)")
    else:
        if "xyz" in cols or "point" in cols:
            raise ImportMapError(
                f"{path}: columns.{'xyz' if 'xyz' in cols else 'point'}: layout pose_rows takes "
                "the points' columns from `points` (point id -> [x, y, z])"
            )
        pts = fields.mapping(doc.get("points"), f"{path}: points (layout pose_rows)", ImportMapError)
        if not pts:
            raise ImportMapError(f"{path}: points: expected at least one point id -> [x, y, z]")
        m.points = {str(k): _refs(v, f"points.{k}", path, 3) for k, v in pts.items()}


def _read_positions(m: TableMap, doc: dict, path: str) -> None:
    """load_map's `positions` (how column positions count), required once a column is given by position; without a
    header every column must be."""
    all_refs = [
        *m.columns["joints"],
        *m.columns.get("xyz", []),
        *(m.columns[k] for k in ("point", "pose", "time", "station", "load") if k in m.columns),
        *(r for v in (m.points or {}).values() for r in v),
    ]
    if any(isinstance(r, int) for r in all_refs):
        if "positions" not in doc:
            raise ImportMapError(
                f"{path}: positions: missing; a column is given by position: say how positions "
                "count, `positions: 1-based` (the first column is 1) or `positions: 0-based`"
            )
        pos = str(doc["positions"])
        if pos not in POSITIONS:
            raise ImportMapError(f"{path}: positions: expected 1-based or 0-based, got {pos!r}")
        m.base = POSITIONS[pos]
    if not m.header and any(isinstance(r, str) for r in all_refs):
        raise ImportMapError(f"{path}: header: false, so columns can only be given by position")


def _looks_separated(line: str, separator: str) -> str | None:
    """The separator a line seems to use instead of `separator` (the one splitting it into the most fields)."""
    counts = {s: line.count(s) for s in SEPARATORS if s != separator}
    best = max(counts, key=counts.get)
    return best if counts[best] > line.count(separator) else None


def _resolve(
    m: TableMap, ref: str | int, header: list[str] | None, path: Path, row: int, mat: MatColumns | None = None
) -> Column:
    if isinstance(ref, int):
        index = ref - m.base
        if index < 0:
            raise ImportMapError(
                f"{m.source}: column {ref}: positions are {'1' if m.base else '0'}-based, the first column is {m.base}"
            )
        if mat is not None and index >= len(header):
            raise ImportMapError(f"{path}: column {ref}: the file has {len(header)} columns; it holds {mat.holds}")
        name = header[index] if header is not None and index < len(header) else None
        return Column(index, f"column {ref}" + (f" ({name!r})" if name else ""))
    if ref not in header and mat is not None:
        k = mat.matrices.get(ref)
        hint = f"; {ref!r} is a matrix: name its columns '{ref}(:,1)' ... '{ref}(:,{k})'" if k else ""
        raise ImportMapError(
            f"{path}: no variable {ref!r} (the map {m.source} names it); the file holds {mat.holds}{hint}"
        )
    if ref not in header:
        known = ", ".join(repr(h) for h in header[:12]) + (" ..." if len(header) > 12 else "")
        raise ImportMapError(
            f"{path}: row {row}: no column {ref!r} (the map {m.source} names it); the header has {known}"
        )
    index = header.index(ref)
    pos = index + (m.base if m.base is not None else 1)
    return Column(index, f"column {ref!r} ({'' if m.base is not None else '1-based '}position {pos})")


def _rows(path: Path, m: TableMap) -> tuple[list[str], list[tuple[int, list[str]]]]:
    """(the file's lines, (file row number, cells) of every non-blank line after skip_rows)."""
    lines = [line for _, block in read_blocks(path, ImportMapError) for line in split_lines(block)]
    out = []
    try:
        for k, cells in enumerate(csv.reader(lines[m.skip_rows :], delimiter=m.separator)):
            if any(c.strip() for c in cells):
                out.append((m.skip_rows + k + 1, [c.strip() for c in cells]))
    except csv.Error as exc:
        raise ImportMapError(
            f"{path}: not a {SEPARATORS.get(m.separator, repr(m.separator))}-separated file ({exc})"
        ) from None
    return lines, out


def _width_note(path: Path, row: int, cells: list[str], need: int, m: TableMap, line: str) -> str:
    """One line for a row with fewer cells than the map needs, saying when the file looks otherwise separated."""
    note = f"{path}: row {row} has {len(cells)} column{'s' if len(cells) != 1 else ''}"
    other = _looks_separated(line, m.separator)
    if other is not None:
        return (
            f"{note}; the file looks {SEPARATORS[other]}-separated: set separator: {other!r}"
            if other != "\t"
            else f"{note}; the file looks tab-separated: set separator: '\\t'"
        )
    return f"{note}, the map needs {need} ({m.source})"


@dataclass
class Imported:
    """An import: the table, and per point the rows read and those skipped for having no reading."""

    table: MeasurementTable
    rows: dict[str, int]  # point -> rows read (with a reading or without)
    missing: dict[str, int]  # point -> rows without a reading (NaN or empty x, y, z), skipped


@dataclass
class _Source:
    """One file of an import: its rows (file row number, cells), and its text lines to explain a short row."""

    path: Path
    rows: list[tuple[int, list[str]]]
    raw: list[str] | None  # None: a .mat file
    col: dict  # map key -> Column or list of Columns, resolved in this file
    pts: dict  # pose_rows: point -> [x, y, z] Columns


def import_table(paths: str | Path | list, m: TableMap, joints: str | Path | None = None) -> Imported:
    """The measurement table (mm, deg) of the export at `paths` (one file, or several: one file per point, text or
    MATLAB .mat) read through the map `m`, the files' rows one after the other. With `joints`, the robot's side
    (joints, time, pose, station) is that file's and `paths` hold the positions alone, joined to it by row: row k of
    each is measured at row k of `joints`. Rows without a reading (NaN or empty x, y, z) are skipped and counted;
    more than MAX_MISSING of a point's rows without one is an error."""
    paths = [Path(p) for p in ([paths] if isinstance(paths, str | Path) else paths)]
    poses: dict[tuple, str] = {}
    counts: dict[str, list[int]] = {}  # point -> [rows, missing]
    robot = None if joints is None else _open(Path(joints), m, ROBOT_KEYS, with_points=False)
    parts = []
    for p in paths:
        if robot is None:
            src = _open(p, m, COLUMN_KEYS, with_points=True)
            parts.append(_read_rows(src, src, m, poses, counts))
            continue
        src = _open(p, m, POSITION_KEYS, with_points=True)
        if len(src.rows) != len(robot.rows):
            raise ImportMapError(
                f"{p}: {len(src.rows)} rows, the joints file {robot.path} {len(robot.rows)}: files "
                "joined by row need as many rows each"
            )
        parts.append(_read_rows(robot, src, m, poses, counts))
    sources = ", ".join(map(str, ([robot.path] if robot else []) + paths))
    for point, (n, k) in counts.items():
        if k > MAX_MISSING * n:
            raise ImportMapError(
                f"{sources}: point {point}: {k} of {n} rows have no reading (NaN or empty), more "
                f"than {MAX_MISSING:.0%}: does the map name the right columns?"
            )
    parts = [t for t in parts if t is not None]
    if not parts:
        raise ImportMapError(f"{sources}: no measured point in any row")
    n = sum(len(t) for t in parts)
    table = (
        parts[0]
        if len(parts) == 1
        else MeasurementTable(
            seq=np.arange(1, n + 1),
            t_s=np.concatenate([t.t_s for t in parts]),
            pose=[v for t in parts for v in t.pose],
            station=[v for t in parts for v in t.station],
            point=[v for t in parts for v in t.point],
            q_deg=np.vstack([t.q_deg for t in parts]),
            xyz=np.vstack([t.xyz for t in parts]),
            source=sources,
            extra={k: np.concatenate([t.extra[k] for t in parts]) for k in parts[0].extra},
        )
    )
    return Imported(table, {p: c[0] for p, c in counts.items()}, {p: c[1] for p, c in counts.items()})


def _open(path: Path, m: TableMap, keys: tuple[str, ...], with_points: bool) -> _Source:
    """The file at `path` (a text export, or a .mat file by its suffix) with the map's columns `keys` (and, with
    `with_points`, the points of pose_rows) resolved in it."""
    refs = {k: v for k, v in m.columns.items() if k in keys}
    pts_refs = (m.points or {}) if with_points else {}
    wanted = [r for v in [*refs.values(), *pts_refs.values()] for r in (v if isinstance(v, list) else [v])]
    if is_mat(path):
        mat = read_mat(path, ImportMapError)
        header, hrow, raw, rows = mat.header, 0, None, []
    else:
        mat = None
        raw, rows = _rows(path, m)
        if not rows:
            raise ImportMapError(f"{path}: no rows after the {m.skip_rows} skipped")
        header, hrow = None, m.skip_rows + 1
        if m.header:
            hrow, header = rows.pop(0)
            names = [r for r in wanted if isinstance(r, str)]
            if names and not set(names) & set(header):
                if _looks_separated(raw[hrow - 1], m.separator):
                    raise ImportMapError(_width_note(path, hrow, header, 0, m, raw[hrow - 1]))
                shown = ", ".join(map(repr, names[:4])) + (" ..." if len(names) > 4 else "")
                raise ImportMapError(f"{path}: row {hrow}: none of the map's columns ({shown}) is in the header")
    col = {
        k: (
            [_resolve(m, r, header, path, hrow, mat) for r in v]
            if isinstance(v, list)
            else _resolve(m, v, header, path, hrow, mat)
        )
        for k, v in refs.items()
    }
    pts = {p: [_resolve(m, r, header, path, hrow, mat) for r in v] for p, v in pts_refs.items()}
    _one_role_each(col, pts, m.source)
    if mat is not None:
        used = sorted({c.index for c in _flat(col, pts)})
        lengths = {header[i]: len(mat.cells[i]) for i in used}
        if len(set(lengths.values())) > 1:
            shown = ", ".join(f"{h} {n}" for h, n in lengths.items())
            raise ImportMapError(
                f"{path}: the map's columns have different row counts ({shown}); each needs one row per measurement"
            )
        n = next(iter(lengths.values()), 0)
        keep = set(used)
        rows = [(k + 1, [mat.cells[i][k] if i in keep else "" for i in range(len(header))]) for k in range(n)]
    if not rows:
        raise ImportMapError(f"{path}: no data rows")
    return _Source(path, rows, raw, col, pts)


def _number(m: TableMap, src: _Source, row: int, cells: list[str], c: Column, factor: float = 1.0) -> float:
    """The number in column `c` of a row, read with the map's decimal mark, times `factor`; one line naming the row
    and column when it is no finite number."""
    text = cells[c.index]
    t = text.replace(",", ".") if m.decimal == "," else text
    try:
        v = float(t)
    except ValueError:
        hint = " (a decimal comma? set decimal: ',')" if m.decimal == "." and "," in text else ""
        raise ImportMapError(f"{src.path}: row {row}: {c.label}: not a number: {text!r}{hint}") from None
    if not math.isfinite(v) or t.strip().lower().lstrip("+-") in ("nan", "inf", "infinity"):
        raise ImportMapError(f"{src.path}: row {row}: {c.label}: not a finite number: {text!r}")
    return v * factor


def _reading(m: TableMap, meas: _Source, row: int, cells: list[str], cs: list[Column]) -> list[float] | None:
    """The position in mm, or None when the tracker had no reading there (a NaN or all three empty)."""
    texts = [cells[c.index].strip().lower().lstrip("+-") for c in cs]
    if "nan" in texts or not any(texts):
        return None
    return [_number(m, meas, row, cells, c, m.length_factor) for c in cs]


def _ident(src: _Source, row: int, cells: list[str], c: Column) -> str:
    """The id in column `c` of a row (a pose, station or point: printable, no comma, not empty)."""
    text = cells[c.index]
    if not text or not text.isprintable() or "," in text:
        raise ImportMapError(f"{src.path}: row {row}: {c.label}: not an id (printable, no comma, not empty): {text!r}")
    return text


def _read_rows(
    robot: _Source, meas: _Source, m: TableMap, poses: dict[tuple, str], counts: dict[str, list[int]]
) -> MeasurementTable | None:
    """The rows of one file (`robot` is `meas`), or of a positions file `meas` joined by row to the joints file
    `robot`; `poses` (joint values -> pose id) is shared by the files of one import, `counts` (point -> [rows,
    without a reading]) is added to. None when no row has a reading."""
    need_r = 1 + max(c.index for c in _flat(robot.col, robot.pts))  # a joints file has no points
    need_m = 1 + max(c.index for c in _flat(meas.col, meas.pts)) if meas is not robot else need_r

    fixed_point = meas.path.stem if m.point == FILE_POINT else m.point
    if not fixed_point or not fixed_point.isprintable() or "," in fixed_point:
        raise ImportMapError(f"{meas.path}: the file's name {fixed_point!r} is no point id (printable, no comma)")
    col = {**robot.col, **meas.col}
    out_pose, out_station, out_point, out_q, out_xyz, out_t, out_load = [], [], [], [], [], [], []
    for (row, cells), (mrow, mcells) in zip(robot.rows, meas.rows, strict=True):
        for src, r, c, need in ((robot, row, cells, need_r), (meas, mrow, mcells, need_m)):
            if len(c) < need:
                raise ImportMapError(_width_note(src.path, r, c, need, m, src.raw[r - 1]))
        q = [_number(m, robot, row, cells, c, m.joint_factor) for c in col["joints"]]
        t = _number(m, robot, row, cells, col["time"]) if "time" in col else float(row)  # no time: the row, an order
        load = _number(m, robot, row, cells, col["load"]) if "load" in col else 0.0
        if not load >= 0:
            raise ImportMapError(
                f"{robot.path}: row {row}: {col['load'].label}: a payload of {load:g} kg (a load is >= 0 kg)"
            )
        station = _ident(robot, row, cells, col["station"]) if "station" in col else m.station
        pose = (
            _ident(robot, row, cells, col["pose"])
            if "pose" in col
            else poses.setdefault(tuple(q), f"P{len(poses) + 1:04d}")
        )
        if m.layout == "point_rows":
            measured = [(_ident(meas, mrow, mcells, col["point"]) if "point" in col else fixed_point, col["xyz"])]
        else:  # a point whose three cells are empty was not measured at this pose: no row, nothing missing
            measured = [(p, cs) for p, cs in meas.pts.items() if any(mcells[c.index] for c in cs)]
        for point, cs in measured:
            xyz = _reading(m, meas, mrow, mcells, cs)
            count = counts.setdefault(point, [0, 0])
            count[0] += 1
            if xyz is None:
                count[1] += 1
                continue
            out_xyz.append(xyz)
            out_pose.append(pose)
            out_station.append(station)
            out_point.append(point)
            out_q.append(q)
            out_t.append(t)
            out_load.append(load)
    if not out_xyz:
        return None
    n = len(out_xyz)
    extra = {LOAD_COLUMN: [f"{v:.10g}" for v in out_load]} if "load" in col else {}
    return MeasurementTable(
        seq=np.arange(1, n + 1),
        t_s=np.array(out_t),
        pose=out_pose,
        station=out_station,
        point=out_point,
        q_deg=np.array(out_q, dtype=float),
        xyz=np.array(out_xyz, dtype=float),
        extra=extra,
        source=str(meas.path),
    )


def _all_refs(m: TableMap) -> list[str | int]:
    out = []
    for v in m.columns.values():
        out += v if isinstance(v, list) else [v]
    for v in (m.points or {}).values():
        out += v
    return out


def _flat(col: dict, pts: dict) -> list[Column]:
    out = []
    for v in col.values():
        out += v if isinstance(v, list) else [v]
    for v in pts.values():
        out += v
    return out


def _one_role_each(col: dict, pts: dict, source) -> None:
    """Refuse a map that reads two things from one column (two reflectors' x, all six joints): the table would hold
    the same number twice as if measured twice."""
    roles: dict[int, tuple[str, Column]] = {}
    named = [
        (f"joint {k + 1}" if key == "joints" else f"{key} {'xyz'[k]}" if key == "xyz" else key, c)
        for key, v in col.items()
        for k, c in enumerate(v if isinstance(v, list) else [v])
    ]
    named += [(f"point {p} {'xyz'[k]}", c) for p, cs in pts.items() for k, c in enumerate(cs)]
    for role, c in named:
        if c.index in roles:
            raise ImportMapError(
                f"{source}: {roles[c.index][0]} and {role} are both read from {c.label}: "
                "each comes from a column of its own"
            )
        roles[c.index] = (role, c)
