"""mkdocs hook: each command's usage and options, from the parser the command line itself builds.

A reference page writes `<!-- cli: NAME -->` (or `<!-- cli: GROUP NAME -->`, e.g. `batch identify`); the build
replaces it with the usage line `trackcal NAME --help` prints and a table of its arguments, so the pages cannot
drift from the code. A marker naming no command fails the build (tests/test_docs.py builds with --strict).
"""

from __future__ import annotations

import argparse
import re

from mkdocs.exceptions import PluginError

from trackcal.campaign.cli import HelpWithDefaults, build_parser

MARKER = re.compile(r"<!-- cli: ([a-z0-9 -]+?) -->")


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
        if action.choices is not None and not isinstance(action.choices, range):
            name += " {" + ",".join(map(str, action.choices)) + "}"
        need = "required" if action.required else ""
        rows.append(f"| `{cell(name)}` | {cell(formatter._expand_help(action))} | {need} |")
    table = "\n".join(["| argument | meaning | |", "| --- | --- | --- |", *rows])
    return f"```text\n{usage}\n```\n\n{table}\n\nExit codes: [conventions](index.md#exit-codes).\n"


def on_page_markdown(markdown: str, page, config, files) -> str:
    return MARKER.sub(lambda m: rendered(m.group(1).split()), markdown)
