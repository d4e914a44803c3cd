"""issue 41: a command runs with the objects its imports made frozen out of the collector's walks (gc.freeze), and
gives them back when it ends, however it ends: a caller of main() in-process (tests, notebooks) collects as before."""

import gc
import types

import pytest

import trackcal.campaign.cli as cli
from trackcal.campaign.errors import CampaignError


@pytest.mark.parametrize("ending", ["returns", "fails"])
def test_a_command_runs_frozen_and_unfreezes_after(monkeypatch, ending):
    seen = []

    def handler(args):
        seen.append(gc.get_freeze_count())
        if ending == "fails":
            raise CampaignError("the command failed")
        return 0

    # every command's handler is looked up by module and name: this one answers for `identify`
    monkeypatch.setattr(cli.importlib, "import_module", lambda name: types.SimpleNamespace(**{"cmd_identify": handler}))
    monkeypatch.setattr(cli, "keep_freed_blocks", lambda: None)
    code = cli.main(["identify", "table.csv", "--cell", "ur10-ipa", "--out", "model.json"])
    assert code == (0 if ending == "returns" else 2)
    assert seen and seen[0] > 1000  # the imports' objects (the interpreter's and pytest's among them) were frozen
    assert gc.get_freeze_count() == 0
