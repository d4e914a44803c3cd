"""`filter` on typed options: a robot program's targets corrected for an identified model (calib.program_filter), the
filtered program, its report (filter.json, filter.html).

    trackcal filter PROGRAM [MORE FILES] --model model.json --out DIR [--tolerance-mm X] [--strict]

The reader is the one a controller family registers for PROGRAM's suffix (drivers.families.program_readers); MORE
FILES are read with it (a KRL .src's .dat and the cell's $config.dat). The filtered files are written into DIR under
their own names, never over an input. A target that is not corrected keeps its text and gets an end-of-line comment
saying why (ProgramRead.write). The model is checked as `compensate` checks it (campaign.jobs.trusted).

The files are read and written as Latin-1: every byte maps to one character and back, so everything but the targets'
text stays byte for byte whatever the controller's code page (KRL editors write Windows-1252, the pendants UTF-8).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from trackcal.calib.io.files import atomic_open, write_json
from trackcal.calib.model_file import Model
from trackcal.calib.program_filter import FilterResult, filter_targets
from trackcal.campaign.errors import InputError, OptionError
from trackcal.campaign.jobs.compensate import correction_bound, model_cell
from trackcal.campaign.jobs.trusted import trusted_model, usable_model
from trackcal.campaign.report.filter_page import write_filter_page
from trackcal.drivers.errors import ProgramError
from trackcal.drivers.families import families, program_readers
from trackcal.drivers.program_text import ProgramRead

FORMAT = "trackcal-filter/1"
# the motions the readers name for a move relative to the current pose or through an expression (KRL LIN_REL,
# `LIN XP1:{X 10}`; RAPID Offs/RelTool)
RELATIVE = re.compile(r"_REL\b|\(expression\)|\bOffs\b|\bRelTool\b")
ENCODING = "latin-1"  # byte-transparent (module docstring)
NOTE = (
    "correction: how far the filter moves the TCP and turns the tool (the nominal robot's, mm and deg); "
    "predicted_mm: the model's TCP error of the target as written (~0 when filtered, the calibration's error "
    "there when kept); sigma_mm: the 1-sigma 3-D uncertainty of the model's TCP there (its parameters' "
    "covariance through the TCP Jacobian, and its lack of fit); bound95_mm: predicted_mm plus the radius holding "
    "the TCP with 95 % probability; lack_of_fit_mm: the model's misfit per coordinate beyond the noise floor, in "
    "every bound (null: not recorded); pass: bound95_mm <= tolerance_mm, unknown (null) for a target outside the "
    "space the model was measured in (measured_space, outside_joints_deg, outside_volume_mm: its bound is an "
    "extrapolation, bound_covered false)"
)


@dataclass(frozen=True)
class FilterOptions:
    """What `trackcal filter` is asked."""

    program: str  # the program's main file; its suffix picks the reader
    model: str  # model.json
    out: str  # directory of the filtered files and the report
    more: tuple[str, ...] = ()  # the program's other files (a KRL .dat, $config.dat)
    tolerance_mm: float | None = None  # pass/fail of each target's 95 % bound
    strict: bool = False  # the job says whether any target fails the tolerance or is unknown (the CLI exits 1)
    accept_edited: bool = False
    accept_poor: bool = False
    allow_outside: bool = False  # also filter targets outside the joint ranges the model's extension was fitted on


@dataclass
class FilterOutcome:
    read: ProgramRead
    result: FilterResult
    rows: list[dict]  # filter.json's targets
    written: list[Path]  # the filtered program's files
    report_json: Path
    report_html: Path
    model_warnings: list[str] = field(default_factory=list)

    @property
    def failed(self) -> int:
        """Targets that fail the tolerance (kept ones included)."""
        return sum(1 for r in self.rows if r["pass"] is False)

    @property
    def extrapolated(self) -> int:
        """Targets outside the space the model was measured in (their bounds are extrapolations)."""
        return sum(1 for r in self.rows if r["measured_space"] == "outside")

    @property
    def unknown(self) -> int:
        """Targets whose pass/fail against the tolerance is unknown: outside the measured space, within it."""
        return sum(1 for r in self.rows if r["pass"] is None and r["bound_covered"] is False)


def read_program(opts: FilterOptions) -> ProgramRead:
    """The program read by its family's reader, every file under its own name."""
    readers = program_readers()
    suffix = Path(opts.program).suffix.lower()
    if suffix not in readers:
        known = ", ".join(sorted(readers)) or "none"
        raise InputError(
            f"{opts.program}: no reader for {suffix or 'a file without a suffix'} programs (known: {known})"
        )
    files: dict[str, str] = {}
    for path in (opts.program, *opts.more):
        name = Path(path).name
        if name in files:
            raise InputError(f"{path}: two files named {name}: give each once")
        try:
            files[name] = Path(path).read_bytes().decode(ENCODING)
        except FileNotFoundError:
            raise InputError(f"{path}: no such file") from None
        except OSError as exc:
            raise InputError(f"{path}: cannot read ({exc.strerror or exc})") from None
    try:
        return readers[suffix](files)
    except ProgramError as exc:
        raise InputError(str(exc)) from None


def check_language(program: str, read: ProgramRead, model: Model) -> None:
    """InputError when the model's robot config names its controller and that controller runs programs of another
    language (a robot config naming none, or a cell that cannot be loaded, is not checked)."""
    cell = model_cell(model)
    name = None if cell is None else cell.robot_doc.get("controller")
    family = families().get(str(name)) if name else None
    if family is not None and family.program is not None and family.program.language != read.language:
        raise InputError(
            f"{program}: a {read.language} program, but the model's robot runs a {family.title} "
            f"controller ({family.program.language} programs): give the model of this program's robot"
        )


def reference_joints(model: Model) -> np.ndarray:
    """(n,) deg: where the robot is taken to be before the program's first target: the cell's test pose recorded in
    the model, else the middle of each joint's range (within a half turn of zero)."""
    test = model.doc.get("test_pose") or {}
    q = test.get("joints_deg")
    if isinstance(q, list) and len(q) == model.chain.dof:
        return np.asarray(q, dtype=float)
    lim = np.clip(model.chain.limits_array(), -np.pi, np.pi)
    return np.degrees(lim.mean(axis=1))


def _number(v) -> float | None:
    return float(v) if v is not None and np.isfinite(v) else None


def target_rows(read: ProgramRead, res: FilterResult, tolerance_mm: float | None) -> list[dict]:
    """filter.json's targets: where each is, what was done, its predicted accuracy and pass/fail."""
    rows = []
    for i, t in enumerate(read.targets):
        bound = _number(res.bound95_mm[i])
        dq = res.q_calibrated_deg[i] - res.q_nominal_deg[i]
        rows.append(
            {
                "file": t.file,
                "line": t.line,
                "name": t.name,
                "kind": "joint" if t.joint else "cartesian",
                "motion": t.motion,
                "status": "filtered" if not res.why[i] else "kept",
                "why": res.why[i] or None,
                "correction_mm": float(res.correction_mm[i]),
                "correction_deg": float(res.correction_deg[i]),
                "joint_correction_deg": _number(np.max(np.abs(dq))) if not res.why[i] else None,
                "predicted_mm": _number(res.predicted_mm[i]),
                "sigma_mm": _number(res.sigma_mm[i]),
                "bound95_mm": bound,
                "outside_fitted_ranges": bool(res.outside[i]),
                **measured_fields(res, i),
                "pass": verdict(bound, tolerance_mm, bool(res.extrapolated[i])),
            }
        )
    return rows


def verdict(bound: float | None, tolerance_mm: float | None, extrapolated: bool) -> bool | None:
    """A target's pass/fail against the tolerance: None without one; a target without a bound (kept, not reached)
    fails; one outside the measured space whose bound is within the tolerance is unknown (None), never a pass: its
    bound is an extrapolation (one beyond the tolerance fails: the model itself says it misses)."""
    if tolerance_mm is None:
        return None
    if bound is None or bound > tolerance_mm:
        return False
    return None if extrapolated else True


def measured_fields(res: FilterResult, i: int) -> dict:
    """filter.json's place of target i against the space the model was measured in: "measured_space" ("inside",
    "outside", "unknown"), "outside_joints_deg" ({joint_<j>: deg} of the joints outside their measured range),
    "outside_volume_mm" (its TCP's distance outside the measured volume), "bound_covered" (false: an extrapolation,
    its pass/fail unknown; null: unknown)."""
    known = bool(res.space_known[i]) or bool(res.extrapolated[i])
    joints = {f"joint_{j + 1}": float(d) for j, d in enumerate(res.outside_joints_deg[i]) if d > 0}
    where = "unknown" if not known else ("outside" if res.extrapolated[i] else "inside")
    return {
        "measured_space": where,
        "outside_joints_deg": joints,
        "outside_volume_mm": _number(res.outside_volume_mm[i]),
        "bound_covered": None if where == "unknown" else where == "inside",
    }


def outside_note(row: dict) -> str:
    """The program comment of a target outside the measured space: how far, and that its bound is an extrapolation
    ("" inside, unknown, or without a bound: not reached)."""
    if row["measured_space"] != "outside" or row["bound95_mm"] is None:
        return ""
    far = [f"A{j.split('_')[1]} by {d:.1f} deg" for j, d in row["outside_joints_deg"].items()]
    if row["outside_volume_mm"]:
        far.append(f"TCP {row['outside_volume_mm']:.0f} mm outside the measured volume")
    return f"outside the calibration's measured space ({', '.join(far)}): its accuracy is an extrapolation"


def _out_paths(opts: FilterOptions, read: ProgramRead) -> dict[str, Path]:
    """Each file's output path; refused when one would overwrite an input."""
    out = Path(opts.out)
    inputs = {Path(p).resolve() for p in (opts.program, *opts.more)}
    paths = {name: out / name for name in read.files}
    for path in paths.values():
        if path.resolve() in inputs:
            raise OptionError(
                "{0} {out}: would overwrite the input {path}: give another directory", "out", out=opts.out, path=path
            )
    return paths


def run_filter(opts: FilterOptions) -> FilterOutcome:
    """`trackcal filter`: the program filtered into opts.out, with filter.json and filter.html."""
    if opts.tolerance_mm is not None and not (np.isfinite(opts.tolerance_mm) and opts.tolerance_mm > 0):
        raise OptionError("{0} {tol}: a tolerance is a positive number of mm", "tolerance_mm", tol=opts.tolerance_mm)
    model, warnings = trusted_model(opts.model, opts.accept_edited)
    warnings += usable_model(model, opts.model, opts.accept_poor)
    read = read_program(opts)
    check_language(opts.program, read, model)
    if not read.targets:
        raise InputError(
            f"{opts.program}: no {read.language} target to filter (no literal pose or joint values used by a move)"
        )
    paths = _out_paths(opts, read)
    res = filter_targets(model, read.targets, reference_joints(model), correction_bound(model), opts.allow_outside)
    for i, t in enumerate(read.targets):  # a reader accepts no joints for a relative or computed move
        if RELATIVE.search(t.motion) and res.why[i]:
            res.why[i] = f"a relative or computed move ({t.motion}): where it goes depends on where the robot is"
    values = {i: v for i, v in enumerate(res.values) if v is not None}
    rows = target_rows(read, res, opts.tolerance_mm)
    notes = {
        i: "; ".join(n for n in (f"kept as it was: {w}" if w else "", outside_note(r)) if n)
        for i, (w, r) in enumerate(zip(res.why, rows, strict=True))
    }
    texts = read.write(values, {i: f"trackcal filter: {n}" for i, n in notes.items() if n})
    out = Path(opts.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
        for name, text in texts.items():
            with atomic_open(paths[name], "wb") as fh:
                fh.write(text.encode(ENCODING, errors="replace"))
    except OSError as exc:
        raise InputError(f"{out}: cannot write the filtered program ({exc.strerror or exc})") from None
    doc = {
        "format": FORMAT,
        "program": str(opts.program),
        "language": read.language,
        "model": str(opts.model),
        "tolerance_mm": opts.tolerance_mm,
        "lack_of_fit_mm": _number(res.lack_of_fit_mm),
        "targets": rows,
        "filtered": int(res.ok.sum()),
        "kept": int((~res.ok).sum()),
        "failed": sum(1 for r in rows if r["pass"] is False),
        "outside_measured": sum(1 for r in rows if r["measured_space"] == "outside"),
        "unknown": sum(1 for r in rows if r["pass"] is None and r["bound_covered"] is False),
        "warnings": [*warnings, *res.warnings],
        "note": NOTE,
    }
    write_json(out / "filter.json", doc, InputError)
    page = write_filter_page(out / "filter.html", doc)
    return FilterOutcome(read, res, rows, list(paths.values()), out / "filter.json", page, warnings)
