"""`trackcal report`: the HTML report of a session, or of a table, a model, a plan and a verdict."""

from __future__ import annotations

from pathlib import Path

from trackcal.campaign.cli.session import incomplete_note
from trackcal.campaign.errors import InputError, UsageError
from trackcal.campaign.jobs.end_of_run import NotAnalysedError, report_files, report_session
from trackcal.campaign.session.store import SessionStore


def cmd_report(args) -> int:
    images = []
    if args.plots:
        d = Path(args.plots)
        if not d.is_dir():
            raise UsageError(f"--plots {args.plots}: not a directory")
        images = sorted(d.glob("*.png"))
    if args.session is not None:
        if args.table or args.model or args.plan or args.verdict or args.cell:
            raise UsageError("give a SESSION directory or --table, --model, --plan, --verdict, --cell; not both")
        store = SessionStore.open(args.session, readonly=True)
        incomplete_note(store)
        store.close()
        try:
            path = report_session(Path(args.session), Path(args.out) if args.out else None, images)
        except NotAnalysedError as exc:
            raise InputError(
                f"{exc.directory}: no {exc.missing} yet (the campaign has not been analysed: "
                f"trackcal resume {exc.directory} --analyse)"
            ) from None
    else:
        if not (args.table and args.model and args.out):
            raise UsageError("give a SESSION directory, or --table, --model and --out")
        path = report_files(args.table, args.model, args.out, args.plan, args.verdict, args.cell, images)
    print(f"report written to {path}")
    return 0
