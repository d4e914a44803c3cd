"""`trackcal export-urdf`: a model (or a cell's or a robot's nominal chain) as a URDF (campaign.jobs.export_urdf)."""

from __future__ import annotations

import sys

from trackcal.campaign.cli.console import console
from trackcal.campaign.jobs.export_urdf import ExportUrdfOptions, export_urdf


def cmd_export_urdf(args) -> int:
    done = export_urdf(
        ExportUrdfOptions(
            out=args.out, model=args.model, cell=args.cell, robot=args.robot, accept_edited=args.accept_edited
        )
    )
    for warning in done.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    console.print(
        f"URDF of {done.joints} joints written to {done.urdf}; what it cannot hold (model extension: "
        f"{done.cause}, stations, intervals) to {done.sidecar}"
    )
    return 0
