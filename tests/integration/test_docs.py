"""The manual (issue 37): a README of at most 250 lines, a site that builds with `mkdocs build --strict`, and one
reference page per command whose usage and options come from the command line's own parser (docs/hooks), so that
they cannot drift from the code. The examples of the pages run in tests/test_readme.py."""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys

import pytest
from mkdocs.exceptions import PluginError

from tests.helpers import ROOT
from trackcal.campaign.cli.commands import COMMANDS

README_MAX_LINES = 250  # issue 37: what it is, the two commands, one campaign end to end, links to the site
HOOK = ROOT / "docs" / "hooks" / "cli_reference.py"


def hook():
    spec = importlib.util.spec_from_file_location("cli_reference", HOOK)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def command_words() -> set[str]:
    return {f"{c.group} {c.name}" if c.group else c.name for c in COMMANDS}


def test_the_readme_is_short():
    lines = (ROOT / "README.md").read_text(encoding="utf-8").count("\n")
    assert lines <= README_MAX_LINES, f"README.md has {lines} lines; the rest belongs to the manual (docs/)"


def test_the_site_builds_strictly(tmp_path):
    """mkdocs --strict: a broken link or anchor, a page outside the nav, a nav entry without its page, or a usage
    marker naming no command fails the build."""
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1")
    done = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stderr[-4000:]
    page = (tmp_path / "site" / "reference" / "plan" / "index.html").read_text(encoding="utf-8")
    assert "--configs" in page and "<!-- cli:" not in page  # the generated usage, not the marker
    start = (tmp_path / "site" / "getting-started" / "index.html").read_text(encoding="utf-8")
    assert "--session sessions/kr270-a" in re.sub(r"<[^>]+>", "", start)  # the README's campaign, shown, not copied


def test_every_command_has_its_reference_page():
    marked = {
        m
        for p in (ROOT / "docs" / "reference").glob("*.md")
        for m in re.findall(r"<!-- cli: ([a-z0-9 -]+?) -->", p.read_text(encoding="utf-8"))
    }
    assert command_words() <= marked, f"no reference page shows {sorted(command_words() - marked)}"


@pytest.mark.parametrize("words", sorted(command_words()))
def test_the_generated_usage_has_every_option_and_its_help(words):
    """Each option of the parser is in the page, with its help as `--help` prints it (defaults and %% expanded)."""
    module = hook()
    parser = module.parser_of(words.split())
    text = module.rendered(words.split())
    assert parser.format_usage().removeprefix("usage: ").strip() in text
    for action in parser._actions:
        if action.help in (None, "==SUPPRESS==") or action.dest == "help":
            continue
        assert all(flag in text for flag in action.option_strings), (words, action.option_strings)
        assert "%%" not in text and "%(" not in text


def test_a_marker_naming_no_command_fails_the_build():
    with pytest.raises(PluginError, match="no command"):
        hook().on_page_markdown("<!-- cli: calibrate -->", page=None, config=None, files=None)


def test_a_readme_section_is_shown_with_its_links_made_relative_and_a_missing_one_fails_the_build():
    shown = hook().on_page_markdown("<!-- readme: campaign -->", page=None, config=None, files=None)
    assert "trackcal run --cell kr270" in shown and "](docs/" not in shown and "](reference/run.md)" in shown
    with pytest.raises(PluginError, match="no section"):
        hook().on_page_markdown("<!-- readme: nowhere -->", page=None, config=None, files=None)
