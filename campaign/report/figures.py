"""matplotlib for the report's figures, off-screen: a Figure on an Agg canvas, without pyplot (issue 41: pyplot's
import and figure manager cost start-up time and nothing the report needs), each figure laid out once and drawn
once, when saved."""

from __future__ import annotations

from pathlib import Path

from trackcal.calib.io.files import atomic_open, writing
from trackcal.campaign.errors import InputError


def subplots(nrows: int = 1, ncols: int = 1, *, figsize: tuple[float, float], **kwargs):
    """(figure, axes) as pyplot.subplots gives them, on an Agg canvas; kwargs are Figure.subplots' (sharex, squeeze,
    ...). Nothing holds the figure but the caller."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # lazy: matplotlib costs ~0.2 s at start-up
    from matplotlib.figure import Figure  # lazy: matplotlib's import, ~0.2 s, only for a report

    fig = Figure(figsize=figsize)
    FigureCanvasAgg(fig)
    return fig, fig.subplots(nrows, ncols, **kwargs)


def tight(fig) -> None:
    """Figure.tight_layout's layout, in one pass, with no layout engine left on the figure. tight_layout measures
    every axes' decorations twice (its engine's rect (0, 0, 1, 1) makes a second pass within the margins of the
    first, giving the same subplot parameters: tests/campaign/report/test_report_drawing.py) and leaves a placeholder
    engine, with which savefig draws the whole figure once more before the draw that makes the PNG."""
    from matplotlib.layout_engine import TightLayoutEngine  # lazy: matplotlib's import, only for a report

    TightLayoutEngine(rect=None).execute(fig)


def save_png(fig, path: Path, dpi: int) -> Path:
    """The figure as a PNG at `path`, written atomically."""
    with writing(path, InputError), atomic_open(path, "wb") as fh:
        fig.savefig(fh, format="png", dpi=dpi)
    return path
