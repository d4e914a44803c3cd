"""`trackcal filter`: a robot program's targets corrected for an identified model, each with its predicted accuracy
(campaign.jobs.filter_program on typed options): the filtered program, filter.json, filter.html and a table here."""

from __future__ import annotations

import sys

from rich.table import Table

from trackcal.campaign.cli.console import print_table
from trackcal.campaign.jobs.filter_program import FilterOptions, run_filter
from trackcal.campaign.report.filter_page import HEADER, filter_rows


def cmd_filter(args) -> int:
    done = run_filter(
        FilterOptions(
            program=args.program,
            more=tuple(args.more),
            model=args.model,
            out=args.out,
            tolerance_mm=args.tolerance_mm,
            strict=args.strict,
            accept_edited=args.accept_edited,
            accept_poor=args.accept_poor,
            allow_outside=args.allow_outside,
        )
    )
    for warning in [*done.model_warnings, *done.result.warnings]:
        print(f"warning: {warning}", file=sys.stderr)
    table = Table(title=f"{done.read.language} program filtered")
    for i, h in enumerate(HEADER[:-1]):
        table.add_column(h, justify="left" if i < 6 else "right")
    table.add_column(HEADER[-1], max_width=40)  # the reason wraps (it is also a warning line below the table)
    doc_rows = {"targets": done.rows}
    for row in filter_rows(doc_rows):
        table.add_row(*row)
    print_table(table)
    kept = [r for r in done.rows if r["status"] == "kept"]
    for r in kept:
        named = "" if r["name"] == f"line {r['line']}" else f" ({r['name']})"
        print(f"warning: {r['file']}: line {r['line']}{named}: kept as it was (commented): {r['why']}", file=sys.stderr)
    n = len(done.rows)
    tol = "" if args.tolerance_mm is None else f"; {done.failed} fail the tolerance of {args.tolerance_mm:g} mm"
    if done.extrapolated:
        tol += (
            f"; {done.extrapolated} outside the space the model was measured in (their bounds are "
            f"extrapolations: {done.unknown} pass/fail unknown)"
        )
    print(f"{n - len(kept)} of {n} targets filtered{tol}")
    print(f"filtered program written to {', '.join(str(p) for p in done.written)}")
    print(f"report written to {done.report_json} and {done.report_html}")
    return 1 if args.strict and (done.failed or done.unknown) else 0
