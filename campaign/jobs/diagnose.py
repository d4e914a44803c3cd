"""`diagnose` on typed options: what the geometric model gets wrong (calib.diagnose), and the verdict document
(verdict.json) written from a diagnosis."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from concurrent.futures import Executor, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

from trackcal.calib.diagnose import Diagnosis, diagnose
from trackcal.calib.diagnose.fits import rms
from trackcal.calib.diagnose.significance import LEVEL, MAP_LEVEL
from trackcal.calib.identify.noise import DEFAULT_WEIGHTING, TrackerNoise, noise_for
from trackcal.calib.io.files import write_json
from trackcal.calib.model.cell import Cell
from trackcal.calib.model_trust import sealed
from trackcal.campaign.errors import InputError, OptionError
from trackcal.campaign.jobs.identify import cell_and_table, choose_params, model_doc, sha256_of, still_warning
from trackcal.campaign.report.diagnosis_plots import plots
from trackcal.campaign.report.tcp import NOT_DERIVED, NotDerived, TcpDifference, tcp_difference, tcp_doc

# threads of one diagnosis: the folds of the joint map's search and held-out test are LAPACK reductions and
# factorisations called without the GIL (calib.diagnose.lapack; the held-out test 1.8x on 2 cores,
# docs/design/performance.md); a batch's processes already fill the cores and run theirs on one
THREADS = min(os.cpu_count() or 1, 2)
HELD_OUT_TEST = (
    f"a cause joins when its gain on held-out poses (partition and edge folds) passes a one-sided "
    f"Wilcoxon signed-rank test per pose at {100 * LEVEL:g} % ({100 * MAP_LEVEL:g} % for the joint error "
    "map), and its fit is physically plausible"
)


@dataclass(frozen=True)
class DiagnoseOptions:
    """What `trackcal diagnose` is asked."""

    data: str  # the measurement table
    cell: str  # cell name or path
    json: str  # verdict.json to write
    params: str | None = None  # geometric parameters; None: the irreducible set
    weighting: str = DEFAULT_WEIGHTING
    folds: int = 5  # cross-validation folds (whole poses held out)
    seed: int = 0  # of the assignment of poses to folds
    plots: str | None = None  # directory for the residual plots
    out: str | None = None  # model.json of the chosen model
    threads: int = THREADS  # run independent pieces of the diagnosis at once (1: one after the other)


@contextlib.contextmanager
def diagnosis_threads(threads: int = THREADS) -> Iterator[Executor | None]:
    """The executor a diagnosis runs its independent pieces in (`calib.diagnose.diagnose`): `threads`
    threads, or None for one."""
    with ThreadPoolExecutor(threads) if threads > 1 else contextlib.nullcontext() as ex:
        yield ex


@dataclass
class DiagnoseOutcome:
    diagnosis: Diagnosis
    verdict: dict
    plots: list[Path]
    still: str | None = None  # identify's still_warning: joints that never move, their parameters left at nominal


def run_diagnose(opts: DiagnoseOptions) -> DiagnoseOutcome:
    """`trackcal diagnose`: the verdict written to opts.json (its plots to opts.plots, the chosen model to
    opts.out)."""
    cell, table = cell_and_table(opts.cell, opts.data)
    if not 2 <= opts.folds <= max(2, len(table)):  # a fold holds at least one row out (and a huge count was a
        # list of that many empty blocks); more folds than poses hold out one pose each
        raise OptionError("{0} {folds}: from 2 to the table's {rows} rows", "folds", folds=opts.folds, rows=len(table))
    params, still = still_warning(cell, table, choose_params(cell, opts.params))
    with diagnosis_threads(opts.threads) as ex:
        d = diagnose(
            cell.chain,
            table,
            cell.tool_points,
            params,
            noise_for(opts.weighting, cell.tracker),
            folds=opts.folds,
            seed=opts.seed,
            tracker=TrackerNoise.of(cell.tracker),
            executor=ex,
        )
    digest = sha256_of(table.source)
    doc = verdict_doc(cell, d, digest)
    written = plots(cell, d, Path(opts.plots)) if opts.plots else []
    write_json(opts.json, doc, InputError)
    if opts.out:
        write_json(
            opts.out,
            sealed(model_doc(cell, d.table, d.extended or d.geometric, d.geometric, d.shift, digest)),
            InputError,
        )
    return DiagnoseOutcome(d, doc, written, still)


def verdict_doc(
    cell: Cell, d: Diagnosis, table_sha256: str | None, tcp: TcpDifference | None | NotDerived = NOT_DERIVED
) -> dict:
    """verdict.json: the causes, every candidate of every selection step with its evidence, the residuals,
    their structure and the gain; the cell and the sha256 of the table it was made from (a report refuses files of
    different campaigns); `tcp`: the diagnosis' TCP difference at the test pose when the caller has it
    (report.tcp.tcp_difference). A figure that cannot be computed is null, with a note saying why."""
    geo = d.geometric
    doc = {
        "cause": d.cause,
        "causes": d.causes,
        "cell": cell.name,
        "table_sha256": table_sha256,
        "candidates": [
            {
                "cause": c.cause,
                "step": c.step,
                "score": c.holdout_rms_mm,
                "holdout_rms_mm": c.holdout_rms_mm,
                "holdout_base_mm": c.holdout_base_mm,
                "gain_mm": c.gain_mm,
                "cv_scheme": c.cv_scheme,
                "cv_note": c.cv_note,
                "rms_mm": c.rms_mm,
                "f_pvalue": c.f_pvalue,
                "delta_bic": c.delta_bic,
                "n_params": c.n_params,
                "significant": c.significant,
                **c.detail,
            }
            for c in sorted(d.candidates, key=lambda c: (c.step, c.holdout_rms_mm is None, c.score()))
        ],
        "geometric": {
            "rms_mm": rms(geo.residuals),
            "variance_factor": geo.variance_factor,
            "p_at_noise_floor": d.variance_factor_pvalue,
        },
        "noise_floor_mm": d.noise_floor_mm,
        "noise_floor_source": d.floor_source,
        "tracker": cell.tracker.to_doc(),
        "noise_scale": d.noise_scale,
        "noise_note": noise_note(d),
        "structure": d.structure,
        "not_identifiable": d.not_identifiable,
        "holdout": {
            "rms_geometric_mm": d.holdout_geometric_mm,
            "rms_extended_mm": d.holdout_extended_mm,
            "folds": d.cv_scheme,
            "note": d.cv_note,
            "test": HELD_OUT_TEST,
        },
        "refused": d.refused,
    }
    ext = d.extended or geo
    doc["extended"] = {"rms_mm": rms(ext.residuals)}
    if isinstance(tcp, NotDerived):
        tcp = tcp_difference(cell, geo, d.extended)
    if tcp is not None:
        doc["test_pose"] = tcp_doc(tcp)
    return doc


def noise_note(d: Diagnosis) -> str:
    """How far the chosen model's residuals sit from the noise floor: a scale, not a cause."""
    pct = 100.0 * (d.noise_scale - 1.0)
    model = "extended" if d.extended is not None else "geometric"
    return (
        f"the {model} model's residuals are {abs(pct):.0f} % {'above' if pct >= 0 else 'below'} the noise "
        f"floor ({d.floor_source})"
    )
