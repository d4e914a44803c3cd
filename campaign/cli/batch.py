"""`trackcal batch identify | diagnose | iso9283 | coverage | rho0`: many campaigns or Monte-Carlo runs at once
(campaign.jobs.batch and campaign.jobs.montecarlo on typed options)."""

from __future__ import annotations

from contextlib import contextmanager

from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table
from rich.text import Text

from trackcal.campaign.cli.console import console
from trackcal.campaign.jobs.batch import BatchOptions, batch
from trackcal.campaign.jobs.montecarlo import CoverageOptions, Rho0Options, coverage, rho0


def _mm(v) -> str:
    return "-" if v is None else f"{v * 1000:.1f}"


@contextmanager
def _progress(what: str):
    """A progress line: done, running, failed, time left."""
    with Progress(
        TextColumn("{task.description}", markup=False),
        BarColumn(),
        TextColumn("{task.fields[state]}", markup=False),
        TimeElapsedColumn(),
        console=console,
        transient=True,
    ) as bar:
        task = bar.add_task(what, total=None, state="")

        def show(done: int, running: int, failed: int, total: int, seconds_left: float | None) -> None:
            eta = "" if seconds_left is None else f", about {seconds_left:.0f} s left"
            bar.update(
                task, completed=done, total=total, state=f"{done}/{total} done, {running} running, {failed} failed{eta}"
            )

        yield show


def _change(w: dict | None) -> str:
    if not w:
        return "-"
    against = "nominal" if w["against"] == "nominal" else "previous"
    return f"{w['parameter']} {w['change']:+.4g} {w['unit']} ({abs(w['change']) / w['sigma']:.1f} σ vs {against})"


def cmd_batch(args) -> int:
    opts = BatchOptions(
        task=args.format,
        inputs=args.inputs,
        out=args.out,
        cell=getattr(args, "cell", None),
        params=getattr(args, "params", None),
        weighting=getattr(args, "weighting", "tracker"),
        scheduler=args.scheduler,
        model=getattr(args, "model", None),
    )
    with _progress(f"batch {opts.task}") as show:
        result = batch(opts, show)
    table = Table(
        title=f"batch {opts.task}: {result.computed} computed, {result.reused} already in {opts.out}, "
        f"{len(result.failed)} failed"
    )
    cols = {
        "identify": ("fit", "residual RMS (µm)", "x noise floor"),
        "diagnose": ("cause", "held-out geometric (µm)", "held-out chosen (µm)"),
        "iso9283": ("targets", "AP max (µm)", "RP max (µm)"),
    }[opts.task]
    for c in ("robot", "campaign", "date", *cols):
        table.add_column(
            c, justify="left" if c in ("robot", "campaign", "cause", "targets") else "right", overflow="fold"
        )
    if opts.task != "iso9283":
        table.add_column("worst parameter change", overflow="fold")
    for row in result.rows:
        head = (row["robot"], row["campaign"], row["date"][:10])
        if "error" in row:
            cells = (Text("failed", style="red"), row["error"], "")
        elif opts.task == "identify":
            cells = (row["fit"], _mm(row["residual_rms_mm"]), f"{row['fit_ratio']:.2f}")
        elif opts.task == "diagnose":
            cells = (
                " + ".join(row["causes"]) or row["cause"],
                _mm(row["holdout_geometric_mm"]),
                _mm(row["holdout_extended_mm"]),
            )
        else:
            cells = (row["targets"], _mm(row["ap_max_mm"]), _mm(row["rp_max_mm"]))
        tail = () if opts.task == "iso9283" else (_change(row.get("worst_change")),)
        table.add_row(*head, *cells, *tail)
    console.print(table)
    dated = {r["date_source"] for r in result.rows}
    if "file modified" in dated:
        console.print("dates: a session's campaign start; a table's file modification time")
    if opts.task != "iso9283":
        console.print(
            "worst parameter change: the largest change against its standard deviation, against the "
            "robot's previous campaign (both estimates' uncertainty), or against nominal for its "
            "first"
        )
    for row in result.failed:
        console.print(f"failed: {row['campaign']}: {row['error']}", soft_wrap=True, markup=False)
    return 2 if result.failed else 0


def cmd_coverage(args) -> int:
    opts = CoverageOptions(
        cell=args.cell,
        seeds=args.seeds,
        first_seed=args.first_seed,
        poses=args.poses,
        params=args.params,
        weighting=args.weighting,
        scheduler=args.scheduler,
        json=args.json,
    )
    with _progress("coverage of the 95 % intervals") as show:
        result = coverage(opts, show)
    table = Table(
        title=f"coverage of the 95 % intervals over {result.n} simulated campaigns (seeds "
        f"{opts.first_seed}..{opts.first_seed + opts.seeds - 1}, {opts.poses} poses each)"
    )
    for c in ("parameter", "truth inside", "coverage", "binomial p"):
        table.add_column(c, justify="left" if c == "parameter" else "right")
    for name, k, p in zip(
        [*result.names, "joint (F test)"], [*result.inside, result.joint], result.p_values, strict=True
    ):
        table.add_row(name, f"{k}/{result.n}", f"{k / result.n:.1%}", f"{p:.2g}")
    console.print(table)
    console.print(result.sentence, soft_wrap=True)
    return 0


def cmd_rho0(args) -> int:
    opts = Rho0Options(
        plan=args.plan, cell=args.cell, runs=args.runs, seed=args.seed, scheduler=args.scheduler, json=args.json
    )
    with _progress("Monte-Carlo rho0") as show:
        result = rho0(opts, show)
    console.print(result.sentence, soft_wrap=True)
    return 0
