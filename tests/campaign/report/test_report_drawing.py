"""How the report draws (issue 41: the report is part of every `run --sim`'s CPU): without pyplot, and each figure
drawn once, when it is saved (Figure.tight_layout leaves a placeholder layout engine behind, and savefig then draws
the whole figure a second time before the one that makes the PNG)."""

import subprocess
import sys
from collections import Counter

from matplotlib.figure import Figure

from tests.helpers import kr270_campaign
from trackcal.campaign.jobs.end_of_run import analysed
from trackcal.campaign.jobs.identify import choose_params, run_identify
from trackcal.campaign.report.analysis import Provenance
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
