"""Traceability of an ISO 9283 test: the tracker's serial number and calibration certificate as the session's hardware
config states them (campaign.cells.hardware: tracker.serial, certificate, certificate_date, certificate_due), for the
report's conditions, with the devices' identities read at each run's start (the tracker's serial checked against the
file's), and the check that the certificate was valid on the day the test was measured."""

from __future__ import annotations

from datetime import UTC, datetime
from pathlib import Path

from trackcal.campaign.cells.identity import identity_conditions, stated_tracker
from trackcal.campaign.session.store import SessionStore
from trackcal.drivers.interfaces import FROM_HARDWARE_FILE

NOT_STATED = "not stated (the hardware config's tracker.{0})"


def measured_on(store: SessionStore) -> str | None:
    """The UTC date (YYYY-MM-DD) of the session's first event: the day the test was measured."""
    events = store.events()
    return datetime.fromtimestamp(events[0].t_wall, UTC).date().isoformat() if events else None


def _stated(store: SessionStore) -> dict[str, str]:
    """The tracker's serial and its certificate, as the session's hardware config states them."""
    t = stated_tracker(store)
    if t is None:
        return {
            "tracker serial": "none (no hardware config: a simulated session)",
            "tracker certificate": "none (no hardware config: a simulated session)",
        }
    cert = t.get("certificate")
    text = (
        NOT_STATED.format("certificate")
        if cert is None
        else (
            f"{cert}, calibrated {t.get('certificate_date') or '(date not stated)'}, due "
            f"{t.get('certificate_due') or '(not stated)'}"
        )
    )
    serial = f"{t['serial']} ({FROM_HARDWARE_FILE})" if t.get("serial") else NOT_STATED.format("serial")
    return {"tracker serial": serial, "tracker certificate": text}


def traceability(store: SessionStore, directory: Path) -> dict[str, str]:
    """The report's traceability conditions of a session: the tracker's serial and certificate as the hardware file
    states them, then the devices' identities as read from them at each run's start (campaign.cells.identity)."""
    return {**_stated(store), **identity_conditions(store, stated_tracker(store))}


def expired_certificate(directory: str | Path) -> str | None:
    """One line when the session's tracker certificate was past its due date on the day of the test, else None."""
    store = SessionStore.open(Path(directory), readonly=True)
    try:
        t, day = stated_tracker(store), measured_on(store)
    finally:
        store.close()
    due = (t or {}).get("certificate_due")
    if due is None or day is None or day <= due:
        return None
    return (
        f"{directory}: the tracker's calibration certificate {t.get('certificate') or '(id not stated)'} "
        f"(serial {t.get('serial') or 'not stated'}) was due on {due}, before the test of {day}"
    )
