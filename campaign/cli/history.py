"""`trackcal history`: one robot's calibrations over time (campaign.jobs.history on typed options)."""

from __future__ import annotations

from rich.table import Table

from trackcal.campaign.cli.console import console
from trackcal.campaign.jobs.history import HistoryOptions, history


def cmd_history(args) -> int:
    dates = args.dates.split(",") if args.dates else None
    h = history(
        HistoryOptions(calibrations=args.calibrations, dates=dates, json=args.json, accept_edited=args.accept_edited)
    )
    table = Table(title="identified parameters (± 95 %); * moved since the previous calibration")
    table.add_column("parameter", overflow="fold")
    for c in h.calibrations:
        table.add_column(f"{c.date:%Y-%m-%d}", justify="right", overflow="fold")
    names = list(dict.fromkeys(n for c in h.calibrations for n in c.names))
    for name in names:
        row = [name]
        for i, c in enumerate(h.calibrations):
            if name not in c.names:
                row.append("-")
                continue
            p = c.model.doc["parameters"][name]
            step = h.steps[i - 1] if i > 0 else None
            moved = step is not None and name in step.names and bool(step.moved[step.names.index(name)])
            row.append(f"{p['value']:.4f} ± {p['ci95']:.4f}{' *' if moved else ''}")
        table.add_row(*row)
    tcp = ["TCP at the test pose: correction (mm) ± 1σ 3-D"]
    tcp += [
        "-" if c.tcp_sigma_mm is None else f"{c.tcp_correction_mm:.3f} ± {c.tcp_sigma_mm:.3f}" for c in h.calibrations
    ]
    table.add_row(*tcp)
    console.print(table)
    for note in h.notes:
        console.print(f"note: {note}", soft_wrap=True)
    console.print(h.sentence, soft_wrap=True)
    if args.json:
        console.print(f"history written to {args.json}")
    return 0
