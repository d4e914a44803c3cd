"""matplotlib for the report's figures, off-screen (Agg)."""

from __future__ import annotations

from pathlib import Path

from trackcal.calib.io.files import atomic_open, writing
from trackcal.campaign.errors import InputError


def pyplot():
    """matplotlib.pyplot with the off-screen backend; imported on first use (start-up time of the commands
    that draw nothing)."""
    import matplotlib  # lazy: ~0.2 s at start-up

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # lazy: pyplot costs ~0.3 s at start-up

    return plt


def save_png(fig, path: Path, dpi: int) -> Path:
    """The figure as a PNG at `path`, written atomically, then closed."""
    with writing(path, InputError), atomic_open(path, "wb") as fh:
        fig.savefig(fh, format="png", dpi=dpi)
    pyplot().close(fig)
    return path
