"""`trackcal batch identify | diagnose`: many campaigns at once (campaign.jobs.batch on typed options)."""

from __future__ import annotations

from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from trackcal.campaign.cli.console import console
from trackcal.campaign.jobs.batch import BatchOptions, batch


def _mm(v) -> str:
    return "-" if v is None else f"{v * 1000:.1f}"


def cmd_batch(args) -> int:
    opts = BatchOptions(task=args.format, inputs=args.inputs, out=args.out, cell=args.cell, params=args.params,
                        weighting=args.weighting, scheduler=args.scheduler)  # fmt: skip
    with Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.fields[state]}"),
                  TimeElapsedColumn(), console=console, transient=True) as bar:  # fmt: skip
        task = bar.add_task(f"batch {opts.task}", total=None, state="")

        def show(done: int, left: int, failed: int, total: int, seconds_left: float | None) -> None:
            eta = "" if seconds_left is None else f", about {seconds_left:.0f} s left"
            bar.update(task, completed=done, total=total,
                       state=f"{done} done, {left} to do, {failed} failed{eta}")  # fmt: skip

        result = batch(opts, show)
    table = Table(title=f"batch {opts.task}: {result.computed} computed, {result.reused} already in {opts.out}, "
                        f"{len(result.failed)} failed")  # fmt: skip
    table.add_column("campaign", overflow="fold")
    if opts.task == "identify":
        cols = ("fit", "residual RMS (µm)", "x noise floor")
    else:
        cols = ("cause", "held-out geometric (µm)", "held-out chosen (µm)")
    for c in cols:
        table.add_column(c, justify="right", overflow="fold")
    for row in result.rows:
        if "error" in row:
            table.add_row(row["campaign"], "[red]failed[/]", row["error"], "")
        elif opts.task == "identify":
            table.add_row(row["campaign"], row["fit"], _mm(row["residual_rms_mm"]), f"{row['fit_ratio']:.2f}")
        else:
            table.add_row(row["campaign"], " + ".join(row["causes"]) or row["cause"], _mm(row["holdout_geometric_mm"]),
                          _mm(row["holdout_extended_mm"]))  # fmt: skip
    console.print(table)
    for row in result.failed:
        console.print(f"[red]failed[/]: {row['campaign']}: {row['error']}", soft_wrap=True)
    return 2 if result.failed else 0
