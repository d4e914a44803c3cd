"""`compensate` on typed options: joint targets corrected with an identified model (calib.compensate), the
targets CSV in, the compensated CSV out, and optionally the robot controller's program (its family's ProgramWriter,
drivers/families.py) or a KR C2 program.

    trackcal compensate --model model.json TARGETS.csv --out OUT.csv [--program NAME | --krl NAME] [--krl-dir DIR]
        [--strict] [--accept-edited] [--accept-poor]

TARGETS.csv: columns q1_deg..qn_deg (n = the model's joints), optional `name`, other columns ignored.
OUT.csv: name (if given), status (`ok`, or why the target could not be compensated: outside the joint limits,
a singular pose such as the KUKA HOME 0,-90,90,0,0,0), q1_deg..qn_deg (nominal), q1_comp_deg..qn_comp_deg
(compensated, 1e-6 deg), dq1_deg..dqn_deg (correction), position_error_mm and orientation_error_deg (the identified
model at the compensated targets against the intended pose), uncompensated_position_mm (the identified model at the
nominal targets), iterations, rounded_position_error_mm (the TCP error of the targets rounded to the 1e-4 deg the
program carries). A target that was not compensated keeps its row, the compensated columns empty, and stays in the
program as its nominal target under a comment saying it is not compensated and why (`strict`: no program is written
at all, one line says which targets); the program's points carry the targets' names (the writer's `labels`). A target
whose correction exceeds the cell's `max_correction` is one of them (calib.compensate).
The model is checked first (campaign.jobs.trusted: digest, units, physical bounds, covariance) and an unusable one
(poorly determined, calib.model_trust) refused unless `accept_poor`.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from trackcal.calib.compensate import NEAR_SINGULAR, CompensationReport, compensate, pose_error
from trackcal.calib.errors import CalibError
from trackcal.calib.io.files import atomic_open, writing
from trackcal.calib.io.table import joint_columns, read_joint_rows
from trackcal.calib.model.cell import MAX_CORRECTION_DEG, MAX_CORRECTION_MM, load_cell
from trackcal.calib.model_file import Model
from trackcal.campaign.errors import InputError, OptionError
from trackcal.campaign.jobs.trusted import trusted_model, usable_model
from trackcal.drivers.errors import ProgramError
from trackcal.drivers.families import ProgramWriter, families

COMP_DECIMALS = 6


def read_targets(path: str, dof: int) -> tuple[np.ndarray, list[str] | None]:
    """Joint targets (N, dof) in degrees and their names (None without a `name` column)."""
    q, others = read_joint_rows(path, dof, what="targets")
    return q, others.get("name")


def row_label(i: int, names: list[str] | None) -> str:
    """Row i (0-based) of the CSV (header = row 1) and the target's name when it has one."""
    return f"row {i + 2}" + (f" ({names[i]})" if names and names[i] else "")


def row_labels(path: str, names: list[str] | None, n: int) -> list[str]:
    """Labels for messages: the file, the CSV row and the target's name when it has one."""
    return [f"{path}: {row_label(i, names)}" for i in range(n)]


def write_output(path: str, names, q_deg: np.ndarray, qc_deg: np.ndarray, report, rounded_mm: np.ndarray) -> None:
    n = q_deg.shape[1]
    header = (["name"] if names is not None else []) + ["status"] + joint_columns(n)
    header += [f"q{j + 1}_comp_deg" for j in range(n)] + [f"dq{j + 1}_deg" for j in range(n)]
    header += ["position_error_mm", "orientation_error_deg", "uncompensated_position_mm", "iterations"]
    header += ["rounded_position_error_mm"]
    with writing(path, InputError), atomic_open(path, "w", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(header)
        for i in range(len(q_deg)):
            row = ([names[i]] if names is not None else []) + [report.failures[i] or "ok"]
            row += [f"{v:.4f}" for v in q_deg[i]]
            if report.failures[i]:  # nothing to run: the compensated columns stay empty
                row += [""] * (2 * n + 2) + [f"{report.uncompensated_position_mm[i]:.4f}", "", ""]
            else:
                row += [f"{v:.{COMP_DECIMALS}f}" for v in qc_deg[i]] + [f"{v:.6f}" for v in qc_deg[i] - q_deg[i]]
                row += [
                    f"{report.position_error_mm[i]:.3e}",
                    f"{report.orientation_error_deg[i]:.3e}",
                    f"{report.uncompensated_position_mm[i]:.4f}",
                    str(int(report.iterations[i])),
                    f"{rounded_mm[i]:.4f}",
                ]
            w.writerow(row)


@dataclass(frozen=True)
class CompensateOptions:
    """What `trackcal compensate` is asked."""

    targets: str  # CSV of nominal joint targets
    model: str  # model.json
    out: str  # the compensated CSV
    tcp: str | None = None  # "X,Y,Z" mm in the last joint frame; None: the centroid of the model's tool points
    krl: str | None = None  # also a KR C2 program of this name
    krl_dir: str | None = None  # its directory (and the --program's); None: the directory of `out`
    speed: int = 10  # PTP axis speed and acceleration override, %
    program: str | None = None  # also the program of this name of the model's robot controller (its family's)
    strict: bool = False  # a target that cannot be compensated: no program at all (default: its nominal, commented)
    accept_edited: bool = False  # use a model whose digest does not match its content (calib.model_trust)
    accept_poor: bool = False  # use a model marked unusable (poorly determined, calib.model_trust)
    allow_outside: bool = False  # compensate targets outside the joint ranges the model's extension was fitted on


@dataclass
class Compensation:
    report: CompensationReport
    labels: list[str]  # per target, for messages (`row_labels`)
    rounded_mm: np.ndarray  # TCP error of the targets rounded to the 1e-4 deg of the KRL program
    near_singular: np.ndarray  # rows (0-based) of compensated targets near a singularity
    krl_files: tuple[Path, ...] | None = None  # NAME.src, NAME.dat
    program_files: tuple[Path, ...] = ()  # the --program's files
    doc: dict = field(default_factory=dict)  # report.to_doc()
    model_warnings: list[str] = field(default_factory=list)  # e.g. a model without a digest, an accepted poor one


def parse_tcp(text: str | None, model: Model) -> np.ndarray:
    if text is None:
        if not model.points:
            raise OptionError("the model has no tool points: give {0} X,Y,Z (mm, last joint frame)", "tcp")
        return np.mean(list(model.points.values()), axis=0)
    try:
        tcp = np.array([float(v) for v in text.split(",")])
    except ValueError:
        raise OptionError("{0} {text}: expected X,Y,Z in mm", "tcp", text=text) from None
    if tcp.shape != (3,) or not np.all(np.isfinite(tcp)):
        raise OptionError("{0} {text}: expected 3 finite numbers X,Y,Z in mm", "tcp", text=text)
    return tcp


# The family whose program --krl writes, and --program for a robot config that names no controller (configs/robots:
# `controller`): the KR C2, trackcal's first family.
KRL_FAMILY = "krc2"


def model_cell(model: Model):
    """The cell the model names, None when it cannot be loaded."""
    try:
        return load_cell(str(model.doc.get("cell", "")))
    except CalibError:
        return None


def correction_bound(model: Model) -> tuple[float, float]:
    """(mm, deg): the `max_correction` of the model's cell, the defaults (calib.model.cell) without one."""
    cell = model_cell(model)
    return (
        (MAX_CORRECTION_MM, MAX_CORRECTION_DEG) if cell is None else (cell.max_correction_mm, cell.max_correction_deg)
    )


def not_compensated_note(failure: str) -> str:
    """The comment a program carries above a target it moves to unchanged."""
    return f"NOT COMPENSATED, its nominal target: {failure}"


def program_of(model: Model) -> ProgramWriter:
    """The program of the model's robot controller: the family its cell's robot config names (`controller`), else
    the KR C2's (a cell that cannot be loaded, or a robot config without `controller`)."""
    cell = model_cell(model)
    name = None if cell is None else cell.robot_doc.get("controller")
    family = families().get(str(name)) if name else None
    return (family.program if family is not None else None) or families()[KRL_FAMILY].program


def write_program(
    writer: ProgramWriter,
    name: str,
    q_deg,
    out_dir: str | Path,
    speed_pct: int = 10,
    labels: list[str] | None = None,
    notes: list[str | None] | None = None,
) -> tuple[Path, ...]:
    """The program's files in out_dir (created if needed), each written atomically; their paths. `labels` name the
    rows (default: the writer's labels of unnamed rows); `notes` comment them (drivers.families.ProgramWriter)."""
    texts = writer.texts(name, q_deg, speed_pct, labels or writer.labels(None, len(q_deg)), notes)
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
        for file, data in texts.items():
            with atomic_open(out / file, "wb") as fh:
                fh.write(data)
    except OSError as exc:
        raise ProgramError(f"{out}: cannot write the {writer.language} program ({exc.strerror or exc})") from None
    return tuple(out / file for file in texts)


def run_compensate(opts: CompensateOptions) -> Compensation:
    """`trackcal compensate`: the targets corrected, written to opts.out (and the programs asked for); refuses a
    program it cannot write before anything is written, and a file in which no target could be compensated."""
    model, model_warnings = trusted_model(opts.model, opts.accept_edited)
    q_deg, names = read_targets(opts.targets, model.chain.dof)
    model_warnings += usable_model(model, opts.model, opts.accept_poor)
    tcp = parse_tcp(opts.tcp, model)
    if opts.krl_dir and not (opts.krl or opts.program):
        raise OptionError("{0} needs {1} NAME", "krl_dir", "krl")
    krl = families()[KRL_FAMILY].program
    programs = [("program", opts.program, program_of(model))] if opts.program else []
    programs += [("krl", opts.krl, krl)] if opts.krl else []
    if len(programs) == 2 and programs[0][2] is krl:
        raise OptionError(
            "{0} and {1} name the same {language} program: give one", "program", "krl", language=krl.language
        )
    for option, name, writer in programs:  # refuse before anything is written
        try:
            writer.check_name(name)
        except ProgramError as exc:
            raise OptionError("{0}: {exc}", option, exc=exc) from None
        if model.chain.dof != 6:
            raise OptionError(
                "{0}: a {language} program needs a 6-axis robot, the model's has {dof}",
                option,
                language=writer.language,
                dof=model.chain.dof,
            )
        if not 1 <= opts.speed <= 100:
            raise OptionError("{0} {speed}: the axis speed override is a percentage 1..100", "speed", speed=opts.speed)
    qc, report = compensate(
        model, np.radians(q_deg), tcp, max_correction=correction_bound(model), allow_outside=opts.allow_outside
    )
    qc_deg = np.degrees(qc)
    # the KRL program carries 1e-4 deg (as the controller reports angles): what rounding costs at the TCP
    krl_deg = np.round(qc_deg, 4)
    rounded_mm, _ = pose_error(model, np.radians(krl_deg), np.radians(q_deg), tcp)
    write_output(opts.out, names, q_deg, qc_deg, report, rounded_mm)
    ok = report.ok
    if not ok.any():
        first = report.failures[0]
        raise InputError(
            f"{opts.targets}: no target could be compensated (row 2: {first}; {opts.out} has each row's reason)"
        )
    labels = row_labels(opts.targets, names, len(q_deg))
    out = Compensation(
        report,
        labels,
        rounded_mm,
        np.flatnonzero(ok & (report.conditioning < NEAR_SINGULAR)),
        doc=report.to_doc(),
        model_warnings=model_warnings,
    )
    if programs and opts.strict and not ok.all():
        failed = [f"{row_label(i, names)}: {report.failures[i]}" for i in np.flatnonzero(~ok)]
        raise OptionError(
            "{0}: {n} target(s) could not be compensated ({first}{more}): no program written ({out} has "
            "each row's reason)",
            "strict",
            n=len(failed),
            first=failed[0],
            more=" ..." if len(failed) > 1 else "",
            out=opts.out,
        )
    notes = [not_compensated_note(f) if f else None for f in report.failures]
    directory = opts.krl_dir or str(Path(opts.out).parent)
    for option, name, writer in programs:
        try:
            files = write_program(writer, name, krl_deg, directory, opts.speed, writer.labels(names, len(ok)), notes)
        except ProgramError as exc:
            raise OptionError("{0}: {exc}", option, exc=exc) from None
        if option == "krl":
            out.krl_files = files
        else:
            out.program_files = files
    return out
