"""`history` on typed options: one robot's calibrations over time, and whether it changed.

    trackcal history SESSION_OR_MODEL ... [--json out.json]

Each argument is a session folder (its model.json, dated by the campaign's first event) or a model.json (dated by
`--dates` or its file's modification time, said so). In time order: every identified parameter with its 95 %
interval; between each calibration and the next, and between the first and the last, the test of
`calib.history` (one F test for the whole robot at 5 %, the parameters that moved beyond their Bonferroni-corrected
interval); how far each model moves the TCP at the cell's test pose from the nominal robot's, with the 1-sigma 3-D
uncertainty of the model's TCP there (model.json's test_pose, calib.tcp_figure); one sentence:
"recalibrate: ... changed since <date>" or "no significant change since <date>".
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from trackcal.calib.history import Change, compare_estimates
from trackcal.calib.io import fields
from trackcal.calib.io.files import write_json
from trackcal.calib.model_file import Model
from trackcal.campaign.errors import InputError, OptionError
from trackcal.campaign.jobs.trusted import trusted_model
from trackcal.campaign.session.session import SessionFiles
from trackcal.campaign.session.store import DB_NAME, SessionStore


@dataclass
class Calibration:
    label: str  # what the user gave
    date: datetime
    date_source: str  # "campaign start" or "file modified"
    model: Model
    names: list[str]
    values: np.ndarray  # boundary units (mm, deg)
    cov: np.ndarray
    dof: int
    tcp_correction_mm: float | None = None  # model.json's test_pose (calib.tcp_figure)
    tcp_sigma_mm: float | None = None  # 1-sigma 3-D
    checked: list[str] = field(default_factory=list)  # the model's warning lines (campaign.jobs.trusted)


def _utc(t: float) -> datetime:
    return datetime.fromtimestamp(t, UTC)


def session_start(directory: Path) -> datetime:
    """When a session's campaign started: its first event."""
    store = SessionStore.open(directory, readonly=True)
    try:
        first = store.events()[:1]
    finally:
        store.close()
    if not first:
        raise InputError(f"{directory}: the session holds no event")
    return _utc(first[0].t_wall)


def _date_of(path: Path) -> tuple[Path, datetime, str]:
    """(model.json, date, where the date comes from) of a session folder or a model file."""
    if path.is_dir():
        if not (path / DB_NAME).exists():
            raise InputError(f"{path}: neither a trackcal session nor a model.json")
        files = SessionFiles(path)
        if not files.model.exists():
            raise InputError(f"{path}: the session has no model.json (run `trackcal resume {path} --analyse`)")
        return files.model, session_start(path), "campaign start"
    if not path.exists():
        raise InputError(f"{path}: no such session or model")
    return path, _utc(path.stat().st_mtime), "file modified"


def _tcp_figure(model: Model, path: str | Path) -> tuple[float | None, float | None]:
    """(how far the calibration moves the TCP at the test pose from the nominal robot's, mm; the model's 1-sigma 3-D
    uncertainty of the TCP there, mm): model.json's `test_pose` (calib.tcp_figure, the figure identify prints and the
    report shows); (None, None) for a model without one (no test pose, or written before it was recorded)."""
    tp = model.doc.get("test_pose")
    if tp is None:
        return None, None
    tp = fields.mapping(tp, f"{path}: test_pose", InputError)
    return (
        fields.json_number(tp.get("correction_mm"), f"{path}: test_pose.correction_mm", InputError),
        fields.json_number(tp.get("sigma_mm"), f"{path}: test_pose.sigma_mm", InputError),
    )


def model_estimate(doc: dict, path: str | Path) -> tuple[list[str], np.ndarray, np.ndarray, int]:
    """(parameter names, values in boundary units (mm, deg), their covariance, degrees of freedom) of a model.json
    document; InputError when it has no covariance."""
    names = [str(n) for n in doc.get("covariance_order", [])]
    cov = np.asarray(doc.get("covariance", []), dtype=float)
    if not names or cov.shape != (len(names), len(names)):
        raise InputError(f"{path}: no parameter covariance (a model from trackcal identify or diagnose has one)")
    values = np.array([doc["parameters"][n]["value"] for n in names], dtype=float)
    return names, values, cov, int(doc.get("dof", 1))


def load_calibration(label: str, date: datetime | None = None, accept_edited: bool = False) -> Calibration:
    """One calibration, its model checked (campaign.jobs.trusted; its warning lines in `checked`)."""
    model_path, found, source = _date_of(Path(label))
    model, checked = trusted_model(str(model_path), accept_edited)
    names, values, cov, dof = model_estimate(model.doc, model_path)
    cal = Calibration(label, date or found, "given" if date else source, model, names, values, cov, dof)
    cal.checked = checked
    cal.tcp_correction_mm, cal.tcp_sigma_mm = _tcp_figure(model, model_path)
    return cal


@dataclass(frozen=True)
class HistoryOptions:
    calibrations: list[str]
    dates: list[str] | None = None  # ISO dates, one per calibration
    json: str | None = None
    accept_edited: bool = False  # use models whose digest does not match their content (calib.model_trust)


@dataclass
class History:
    calibrations: list[Calibration]
    steps: list[Change]  # between each calibration and the next
    overall: Change | None  # first against last (None with one calibration)
    sentence: str
    notes: list[str] = field(default_factory=list)


def _dates(opts: HistoryOptions) -> list[datetime | None]:
    if opts.dates is None:
        return [None] * len(opts.calibrations)
    if len(opts.dates) != len(opts.calibrations):
        raise OptionError(
            "{0}: give one date per calibration ({n} calibrations, {m} dates)",
            "dates",
            n=len(opts.calibrations),
            m=len(opts.dates),
        )
    out = []
    for text in opts.dates:
        try:
            d = datetime.fromisoformat(text)
        except ValueError:
            raise OptionError(
                "{0}: {text!r} is no ISO date (e.g. 2026-08-01 or 2026-08-01T14:00)", "dates", text=text
            ) from None
        out.append(d if d.tzinfo else d.replace(tzinfo=UTC))
    return out


def _change(a: Calibration, b: Calibration) -> Change:
    return compare_estimates(a.names, a.values, a.cov, a.dof, b.names, b.values, b.cov, b.dof)


def history(opts: HistoryOptions) -> History:
    if not opts.calibrations:
        raise OptionError("{0}: give at least one session or model", "calibrations")
    cals = [load_calibration(c, d, opts.accept_edited) for c, d in zip(opts.calibrations, _dates(opts), strict=True)]
    cals.sort(key=lambda c: c.date)
    robots = {c.model.chain.name for c in cals}
    if len(robots) > 1:
        raise InputError(f"the calibrations are of different robots ({', '.join(sorted(robots))}): one at a time")
    steps = [_change(a, b) for a, b in zip(cals, cals[1:], strict=False)]
    overall = _change(cals[0], cals[-1]) if len(cals) > 1 else None
    if overall is None:
        sentence = f"one calibration ({cals[0].date:%Y-%m-%d}): nothing to compare yet"
    else:
        last_change = max((i for i, s in enumerate(steps) if s.changed), default=None)
        if overall.changed or last_change is not None:
            since = cals[0] if last_change is None else cals[last_change]
            moved = overall if overall.changed else steps[last_change]
            names = [n for n, m in zip(moved.names, moved.moved, strict=True) if m]
            which = f": {', '.join(names)} moved beyond their uncertainty" if names else ""
            sentence = (
                f"recalibrate: the robot changed since {since.date:%Y-%m-%d} "
                f"(p = {moved.p_value:.2g} < {moved.alpha}){which}"
            )
        else:
            sentence = f"no significant change since {cals[0].date:%Y-%m-%d} (p = {overall.p_value:.2g})"
    poor = [c for c in cals if c.model.doc.get("fit") == "poor"]
    if overall is not None and poor:
        ratios = ", ".join(f"{c.label} {c.model.doc.get('fit_ratio', float('nan')):.1f}x" for c in poor)
        sentence = (
            f"cannot tell: the fit of {', '.join(c.label for c in poor)} is poor (residual RMS / noise floor: "
            f"{ratios}), so its intervals understate what the model misses and a change cannot be judged "
            f"against them (the test alone says: {sentence}); identify with the cause `trackcal diagnose` "
            "names, then compare again"
        )
    notes = [f"{c.label}: dated by its {c.date_source}" for c in cals if c.date_source == "file modified"]
    notes += [w for c in cals for w in c.checked]
    out = History(cals, steps, overall, sentence, notes)
    if opts.json:
        write_json(opts.json, history_doc(out))
    return out


def _change_doc(c: Change) -> dict:
    return {
        "p_value": c.p_value,
        "statistic": c.statistic,
        "dof": list(c.dof),
        "alpha": c.alpha,
        "changed": c.changed,
        "parameters": {
            n: {"difference": float(d), "sigma": float(s), "moved": bool(m)}
            for n, d, s, m in zip(c.names, c.difference, c.sigma, c.moved, strict=True)
        },
    }


def history_doc(h: History) -> dict:
    return {
        "calibrations": [
            {
                "source": c.label,
                "date": c.date.isoformat(),
                "date_source": c.date_source,
                "robot": c.model.chain.name,
                "tcp_correction_mm": c.tcp_correction_mm,
                "tcp_sigma_mm": c.tcp_sigma_mm,
                "parameters": {
                    n: {"value": float(v), "ci95": c.model.doc["parameters"][n]["ci95"]}
                    for n, v in zip(c.names, c.values, strict=True)
                },
            }
            for c in h.calibrations
        ],
        "steps": [_change_doc(s) for s in h.steps],
        "overall": None if h.overall is None else _change_doc(h.overall),
        "sentence": h.sentence,
        "notes": h.notes,
    }
