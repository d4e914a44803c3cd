"""How the report draws (issue 41: the report is part of every `run --sim`'s CPU): without pyplot, each figure laid
out in one pass, as Figure.tight_layout lays it out in two, and drawn once, when it is saved (tight_layout leaves a
placeholder layout engine behind, and savefig then draws the whole figure a second time before the one that makes
the PNG)."""

import subprocess
import sys
from collections import Counter

import numpy as np
import pytest
from matplotlib import _tight_layout
from matplotlib.figure import Figure

from tests.helpers import kr270_campaign
from trackcal.campaign.jobs.end_of_run import analysed
from trackcal.campaign.jobs.identify import choose_params, run_identify
from trackcal.campaign.report.analysis import Provenance
from trackcal.campaign.report.figures import subplots, tight
from trackcal.campaign.report.html import write_report

DRAWS_PYPLOT = """
import sys
from pathlib import Path
import trackcal.campaign.report.html, trackcal.campaign.report.iso9283
from trackcal.campaign.report.figures import save_png, subplots, tight
fig, ax = subplots(figsize=(2, 2))
ax.plot([0, 1], [1, 0])
tight(fig)
save_png(fig, Path(sys.argv[1]), dpi=50)
print("matplotlib" in sys.modules, "matplotlib.pyplot" in sys.modules)
"""


def test_the_report_modules_draw_without_pyplot(tmp_path):
    out = subprocess.run(
        [sys.executable, "-c", DRAWS_PYPLOT, str(tmp_path / "f.png")], capture_output=True, text=True, check=True
    )
    assert out.stdout.split() == ["True", "False"]  # matplotlib drew the figure; pyplot was never imported
    assert (tmp_path / "f.png").read_bytes().startswith(b"\x89PNG\r\n\x1a\n")


def test_each_report_figure_is_drawn_once(kr270, tmp_path, monkeypatch):
    _, table = kr270_campaign(kr270, seed=41, n_poses=12)
    outcome = run_identify(kr270, table, choose_params(kr270, None), "tracker")
    plan = {"poses_deg": [list(q) for q in dict.fromkeys(tuple(q) for q in table.q_deg.tolist())], "repeat": 1}
    prov = Provenance(session="s", campaign_started="2026-12-04 10:00 UTC", model_path="model.json", cell_ref="kr270")
    analysis = analysed(kr270, table, outcome.doc, plan=plan, verdict=None, diagnosis=None, provenance=prov)
    draws: Counter = Counter()
    draw = Figure.draw

    def counted(fig, renderer):
        draws[id(fig)] += 1
        return draw(fig, renderer)

    monkeypatch.setattr(Figure, "draw", counted)
    write_report(analysis, tmp_path)
    pngs = sorted(tmp_path.rglob("*.png"))
    # the plan, the residuals per axis and per pose, the parameters: one figure each, each drawn once
    assert [p.name for p in pngs] == ["parameters.png", "plan.png", "residuals_per_pose.png", "residuals_xyz.png"]
    assert sorted(draws.values()) == [1] * len(pngs)


def report_like_figure(kind: int):
    """Figures laid out as the report's are: a suptitle over panels sharing an axis with legends, panels of rotated
    tick labels, a grid with an unused panel, one panel of long tick labels."""
    x = np.linspace(-40.0, 40.0, 50)
    if kind == 0:
        fig, axes = subplots(1, 3, figsize=(13, 3.8), sharey=True)
        for ax in axes:
            ax.plot(x, np.exp(-x * x / 200.0), label="N(0.1, 10.0) µm")
            ax.legend(loc="upper center", fontsize=7)
            ax.set_xlabel("residual x (µm)")
        fig.suptitle("residuals after calibration, per axis (station frames), with the fitted normal")
    elif kind == 1:
        fig, axes = subplots(2, 1, figsize=(13, 6), sharex=True)
        for ax in axes:
            ax.bar(np.arange(40), np.abs(x[:40]))
            ax.set_title("residual distance per configuration", fontsize=10)
        axes[1].set_xticks(np.arange(40))
        axes[1].set_xticklabels([f"Q{i}_S1" for i in range(40)], rotation=90, fontsize=7)
    elif kind == 2:
        fig, axes = subplots(2, 4, figsize=(14, 6))
        for ax in axes.ravel()[:7]:
            ax.plot(x, x**3, ".", ms=3)
            ax.set_ylabel("|residual| (µm)")
        axes[1, 3].axis("off")
        fig.suptitle("geometric residuals against joint angles and time")
    else:
        fig, ax = subplots(figsize=(6, 3.8))
        ax.errorbar(x[:12], np.arange(12), xerr=np.ones(12), fmt="o")
        ax.set_yticks(np.arange(12))
        ax.set_yticklabels([f"phiy{i}_a_long_parameter_name" for i in range(12)])
    return fig


SUBPLOT_PARAMETERS = ("left", "right", "bottom", "top", "wspace", "hspace")


@pytest.mark.parametrize("kind", range(4))
def test_tight_lays_a_figure_out_as_tight_layout_does_in_one_pass(kind, monkeypatch):
    ours, theirs = report_like_figure(kind), report_like_figure(kind)
    theirs.tight_layout()
    passes = []
    measure = _tight_layout._auto_adjust_subplotpars

    def counted(*args, **kwargs):
        passes.append(1)
        return measure(*args, **kwargs)

    monkeypatch.setattr(_tight_layout, "_auto_adjust_subplotpars", counted)
    tight(ours)
    assert [getattr(ours.subplotpars, p) for p in SUBPLOT_PARAMETERS] == [
        getattr(theirs.subplotpars, p) for p in SUBPLOT_PARAMETERS
    ]
    assert len(passes) == 1  # tight_layout takes two
