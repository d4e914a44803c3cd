"""The trackcal command line: the command table (campaign.cli.commands) as argparse, and the one place that
turns an error into a line on stderr.

Every user mistake ends in one line and exit code 2. The command line catches one error base per layer:
calib.errors.CalibError (the mathematics refuses its input), campaign.errors.CampaignError (a file, plan,
session or option the campaign cannot use) and drivers.errors.DeviceError (a device that cannot be reached).
A job's OptionError names the option it concerns; here it is spelled as the command's flag (`--params: ...`).
"""

from __future__ import annotations

import argparse
import gc
import importlib
import sys

from trackcal.calib.errors import CalibError
from trackcal.campaign.cli.allocator import keep_freed_blocks
from trackcal.campaign.cli.blas import limited_blas
from trackcal.campaign.errors import CampaignError, OptionError
from trackcal.drivers.errors import DeviceError

USER_ERRORS = (CalibError, CampaignError, DeviceError)  # one line, exit 2


def flag(option: str) -> str:
    """The command-line flag of a job's option field: test_pose -> --test-pose."""
    return "--" + option.replace("_", "-")


def message_of(exc: Exception) -> str:
    """The line a user error is shown as: a job's option errors name the command's flags."""
    return exc.spelled(flag) if isinstance(exc, OptionError) else str(exc)


class HelpWithDefaults(argparse.HelpFormatter):
    """Each option's help ends with its default, when it has one worth showing (not None, not a flag's False)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        default = action.default
        if (
            "%(default)" in text
            or not action.option_strings
            or default is None
            or default is False
            or default == argparse.SUPPRESS
        ):
            return text
        return f"{text} (default: %(default)s)"


class Parser(argparse.ArgumentParser):
    """An option mistake is one line naming the command it belongs to (`trackcal plan: error: ...`), exit 2.
    Options are spelled in full: argparse would take a prefix (`plan --config 6` as `--configs 6`), and a
    misspelt option silently meaning another is worse than an error. Subparsers are made by this class too."""

    def __init__(self, *args, **kwargs) -> None:
        kwargs.setdefault("formatter_class", HelpWithDefaults)
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message}\n")


def build_parser() -> Parser:
    from trackcal.campaign.cli.commands import COMMANDS, GROUPS  # lazy: loads numpy; its BLAS starts under main's limit

    ap = Parser(prog="trackcal", description="Robot calibration with a laser tracker.")
    sub = ap.add_subparsers(dest="command", required=True)
    groups: dict[str, argparse._SubParsersAction] = {}
    for cmd in COMMANDS:
        where = sub
        if cmd.group is not None:
            if cmd.group not in groups:
                g = sub.add_parser(cmd.group, help=GROUPS[cmd.group])
                groups[cmd.group] = g.add_subparsers(dest="format", required=True)
            where = groups[cmd.group]
        p = where.add_parser(cmd.name, help=cmd.help, description=cmd.description)
        for flags, options in cmd.args:
            p.add_argument(*flags, **options)
        p.set_defaults(handler=cmd.handler, parser=p)
    return ap


def main(argv: list[str] | None = None) -> int:
    try:
        # the BLAS threads before anything imports numpy: its OpenBLAS starts its threads as it loads, and with more
        # than one a worker spun for about 0.1 s of CPU at every command's start before the limit reached it
        with limited_blas():
            ap = build_parser()
            args, unknown = ap.parse_known_args(argv)
            if unknown:  # argparse would report them for `trackcal`, not for the command they were given to
                args.parser.error(f"unrecognized arguments: {' '.join(unknown)}")
            module, _, function = args.handler.partition(":")
            keep_freed_blocks()
            # imported here, once the command is known: start-up time (`--help` and `export` need no pinocchio)
            handler = getattr(importlib.import_module(module), function)
            # the objects the imports made (numpy's, scipy's, pinocchio's modules) live as long as the command: out of
            # the collector's walks while it runs (issue 41: identify of the UR10's Series B 10 % faster, diagnose
            # 0.07 s), given back to it after (a caller of main() in-process: tests, notebooks)
            gc.freeze()
            try:
                return handler(args)
            finally:
                gc.unfreeze()
    except USER_ERRORS as exc:
        print(f"error: {message_of(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
