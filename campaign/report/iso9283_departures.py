"""The report's box of departures from the standard's test conditions: every departure of every test once, with the
tests it applies to (campaign.jobs.iso9283_departures finds them)."""

from __future__ import annotations

import html

from trackcal.calib.iso9283 import IsoFigures

STYLE = "div.departures{border:2px solid #b60;padding:0.2em 1em;margin:1em 0;background:#fff8ee}"


def grouped(tests: list[IsoFigures]) -> dict[str, list[str]]:
    """Each departure -> the tests (session labels) it applies to, in the order they first appear."""
    out: dict[str, list[str]] = {}
    for t in tests:
        for d in t.departures:
            out.setdefault(d, []).append(t.session)
    return out


def departures_box(tests: list[IsoFigures]) -> list[str]:
    """The box's HTML: the departures, or that there is none."""
    found = grouped(tests)
    every = [t.session for t in tests]
    if not found:
        items = "<p>None: every test ran under the conditions ISO 9283:1998 sets for it.</p>"
    else:
        items = (
            "<ul>"
            + "".join(
                f"<li>{html.escape(d)}" + ("" if who == every else f" (tests: {html.escape(', '.join(who))})") + "</li>"
                for d, who in found.items()
            )
            + "</ul>"
        )
    return [f"<style>{STYLE}</style><div class=departures><h2>Departures from ISO 9283:1998</h2>{items}</div>"]
