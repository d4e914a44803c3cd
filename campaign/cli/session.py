"""`trackcal export | check`: a session's measurement table, and its verification (light: no pinocchio, no
matplotlib)."""

from __future__ import annotations

from pathlib import Path

from trackcal.campaign.cli.console import console, labelled
from trackcal.campaign.errors import InputError
from trackcal.campaign.jobs.completeness import completeness
from trackcal.campaign.session.session import changed_copies, write_export
from trackcal.campaign.session.store import SessionStore


def incomplete_note(store: SessionStore) -> None:
    """The first line of what `export` and `report` print for a session whose campaign has not reached its end."""
    done = completeness(store)
    if not done.complete:
        console.print(labelled("note", "yellow", f"{store.directory}: {done.sentence()}"), soft_wrap=True)


def cmd_export(args) -> int:
    store = SessionStore.open(args.session, readonly=True)
    incomplete_note(store)
    try:
        n = write_export(store, Path(args.csv))
    except OSError as exc:
        raise InputError(f"{args.csv}: cannot write ({exc.strerror})") from None
    console.print(f"{n} measurements written to {args.csv}")
    return 0


def cmd_check(args) -> int:
    store = SessionStore.open(args.session, readonly=True)  # refuses a damaged session or a broken chain
    events = store.events()
    n = sum(e.kind == "measurement" for e in events)
    console.print(
        f"{store.directory}: sound (SQLite integrity check ok; {len(events)} events, {n} measurements, "
        f"in an unbroken hash chain; head {store.head})",
        soft_wrap=True,
    )
    console.print(
        f"{completeness(store).sentence()} (pin the head above: the chain finds edits, not a forger who recomputes it)",
        soft_wrap=True,
    )
    changed = changed_copies(store)
    if changed:
        console.print(
            labelled(
                "note",
                "yellow",
                f"{', '.join(changed)} beside the database differ from the stored "
                "copies (the stored copies are the record)",
            ),
            soft_wrap=True,
        )
    return 0
