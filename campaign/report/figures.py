"""matplotlib for the report's figures, off-screen (Agg)."""

from __future__ import annotations


def pyplot():
    """matplotlib.pyplot with the off-screen backend; imported on first use (start-up time of the commands
    that draw nothing)."""
    import matplotlib  # lazy: ~0.2 s at start-up

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # lazy: pyplot costs ~0.3 s at start-up

    return plt
