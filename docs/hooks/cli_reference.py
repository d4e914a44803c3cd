"""mkdocs hook: each command's usage and options, from the parser the command line itself builds; and sections
of the README shown in a page without a copy.

A reference page writes `<!-- cli: NAME -->` (or `<!-- cli: GROUP NAME -->`, e.g. `batch identify`); the build
replaces it with the usage line `trackcal NAME --help` prints and a table of its arguments, so the pages cannot
drift from the code. A marker naming no command fails the build (tests/test_docs.py builds with --strict).
`<!-- readme: NAME -->` (in a page at the top of docs/) is the README's text between `<!-- start: NAME ... -->`
and `<!-- end: NAME -->`, its links to docs/ made relative to the page; its examples run once, as the README's.
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

from mkdocs.exceptions import PluginError

from trackcal.campaign.cli import HelpWithDefaults, build_parser

MARKER = re.compile(r"<!-- cli: ([a-z0-9 -]+?) -->")
README_MARKER = re.compile(r"<!-- readme: ([a-z0-9-]+) -->")
README = Path(__file__).resolve().parents[2] / "README.md"


def parser_of(words: list[str]) -> argparse.ArgumentParser:
    parser = build_parser()
    for word in words:
        sub = next((a for a in parser._actions if isinstance(a, argparse._SubParsersAction)), None)
        if sub is None or word not in sub.choices:
            raise PluginError(f"<!-- cli: {' '.join(words)} -->: trackcal has no command {' '.join(words)!r}")
        parser = sub.choices[word]
    return parser


def cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def rendered(words: list[str]) -> str:
    parser = parser_of(words)
    formatter = HelpWithDefaults(parser.prog)
    usage = parser.format_usage().removeprefix("usage: ").strip()
    rows = []
    for action in parser._actions:
        if action.help == argparse.SUPPRESS or isinstance(action, argparse._HelpAction):
            continue
        name = ", ".join(action.option_strings) or action.metavar or action.dest
        if action.option_strings and action.nargs != 0:
            name += " " + formatter._format_args(action, formatter._get_default_metavar_for_optional(action))
        elif not action.option_strings:
            name = formatter._format_args(action, formatter._get_default_metavar_for_positional(action))
        need = "yes" if action.required else ""
        rows.append(f"| `{cell(name)}` | {cell(formatter._expand_help(action))} | {need} |")
    table = "\n".join(["| argument | meaning | required |", "| --- | --- | --- |", *rows])
    return f"```text\n{usage}\n```\n\n{table}\n\nExit codes: [conventions](index.md#exit-codes).\n"


def readme_section(name: str) -> str:
    text = README.read_text(encoding="utf-8")
    found = re.search(rf"<!-- start: {name}\b.*?-->\n(.*?)<!-- end: {name} -->", text, re.S)
    if found is None:
        raise PluginError(f"<!-- readme: {name} -->: README.md has no section {name!r}")
    return found.group(1).replace("](docs/", "](").replace("](CHANGELOG.md)", "](changelog.md)")


def on_page_markdown(markdown: str, page, config, files) -> str:
    markdown = README_MARKER.sub(lambda m: readme_section(m.group(1)), markdown)
    return MARKER.sub(lambda m: rendered(m.group(1).split()), markdown)
