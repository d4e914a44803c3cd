"""`trackcal export`: a session's measurement table (light: no pinocchio, no matplotlib)."""

from __future__ import annotations

from pathlib import Path

from campaign.console import console
from campaign.errors import InputError
from campaign.session.session import write_export
from campaign.session.store import SessionStore


def cmd_export(args) -> int:
    try:
        n = write_export(SessionStore.open(args.session, readonly=True), Path(args.csv))
    except OSError as exc:
        raise InputError(f"{args.csv}: cannot write ({exc.strerror})") from None
    console.print(f"{n} measurements written to {args.csv}")
    return 0
