"""The devices' identities at the start of a run (#39): read from the tracker and the robot controller (each driver's
`identity()`, drivers.interfaces.DeviceIdentity), recorded in the session as an `identity` document, and compared
with the hardware file. A tracker whose serial number is not the one the file states (the instrument its calibration
certificate names) warns in one line, and so does a certificate already past its due date; the session keeps each
(a `warning` document) and the ISO 9283 report prints the identities and the serial check
(campaign.jobs.iso9283_trace).

The identities are read outside the recorded device calls: a replay plays back the campaign's calls, not who the
devices were, and keeps the recording's `identity` documents where they are (the session it replays).
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import asdict
from datetime import UTC, datetime
from pathlib import Path

from trackcal.campaign.cells.hardware import load_hardware
from trackcal.campaign.engine.documents import IdentityDoc, WarningDoc
from trackcal.campaign.engine.engine import Live
from trackcal.campaign.session.session import HARDWARE_COPY
from trackcal.campaign.session.store import SessionStore
from trackcal.drivers.errors import DeviceError

DEVICES = ("tracker", "robot")


def stated_tracker(store: SessionStore) -> dict | None:
    """The tracker section of the session's stored hardware config (None: a simulated session has none)."""
    text = store.documents().get(HARDWARE_COPY)
    return None if text is None else load_hardware(Path(store.directory) / HARDWARE_COPY, text).tracker


def read_identities(live: Live) -> IdentityDoc:
    """Each device's identity, or {"error": why} when it could not be read (a tracker or controller that does not
    answer the query: the run goes on, the report says so)."""
    out: dict[str, dict[str, str]] = {}
    for name in DEVICES:
        try:
            out[name] = asdict(getattr(live, name).identity())
        except DeviceError as exc:
            out[name] = {"error": str(exc)}
    return IdentityDoc(tracker=out["tracker"], robot=out["robot"])


def serial_matches(stated: str, read: str) -> bool:
    """Whether the hardware file's serial (text) names the serial number the tracker reports (an integer,
    GetTrackerInfoRT.lSerialNumber): the same text, or the file's last run of digits as that number ("AT901-390123"
    names 390123)."""
    if stated.strip().lower() == read.strip().lower():
        return True
    digits = re.findall(r"\d+", stated)
    return bool(digits) and read.strip().isdigit() and int(digits[-1]) == int(read)


def serial_mismatch(identity: IdentityDoc, stated: dict | None) -> str | None:
    """One line when the tracker's serial, as read from it, is not the one the hardware file states; None when they
    agree, or when either says nothing."""
    read = identity["tracker"].get("serial", "")
    serial = (stated or {}).get("serial")
    if not read or not serial or serial_matches(str(serial), read):
        return None
    cert = (stated or {}).get("certificate")
    return (
        f"the tracker reports serial number {read}, the hardware file's tracker.serial is {serial}: "
        f"{'its certificate ' + str(cert) if cert else 'the certificate'} may name another instrument"
    )


def certificate_expired(stated: dict | None, today: str) -> str | None:
    """One line when the hardware file's tracker certificate is past its due date on `today` (YYYY-MM-DD), else None:
    a test measured now is refused for an ISO 9283 report unless asked (campaign.jobs.iso9283_trace)."""
    due = (stated or {}).get("certificate_due")
    if due is None or today <= due:
        return None
    return (
        f"the tracker's calibration certificate {(stated or {}).get('certificate') or '(id not stated)'} was due "
        f"on {due}: what this run measures is refused for an ISO 9283 report unless "
        f"--accept-expired-certificate"
    )


class IdentityCheck:
    """A subscriber of a run's documents (placed last): on the run's `start` it reads the live devices' identities
    and emits the `identity` document, then a `warning` for a tracker serial the hardware file does not state and one
    for a tracker certificate past its due date."""

    def __init__(self, live: Live, emit: Callable[[str, dict], None], stated: dict | None) -> None:
        self.live, self.emit, self.stated = live, emit, stated

    def __call__(self, doc) -> None:
        if doc.name != "start":
            return
        identity = read_identities(self.live)
        self.emit("identity", dict(identity))
        today = datetime.now(UTC).date().isoformat()  # the day of the run, as the report dates the test
        for message in (serial_mismatch(identity, self.stated), certificate_expired(self.stated, today)):
            if message is not None:
                self.emit("warning", dict(WarningDoc(message=message)))


def describe(device: dict[str, str]) -> str:
    """One device's identity for a report: model, serial, software and where they come from."""
    if "error" in device:
        return f"not read ({device['error']})"
    parts = [
        device.get("model") or "model not stated",
        f"serial {device.get('serial') or 'not stated'}",
        device.get("software") or "software version not stated",
    ]
    return f"{', '.join(parts)} ({device.get('source', '')})"


def identity_conditions(store: SessionStore, stated: dict | None) -> dict[str, str]:
    """The report's rows of the devices' identities as the session's runs recorded them (each run's start, in order:
    a resume on other devices shows as a second identity), and the tracker's serial checked against the hardware
    file's (`stated`: its tracker section, None for a simulated session)."""
    docs = [e.data for e in store.events("identity")]
    if not docs:
        none = "not recorded (the session's runs read no device identity)"
        return {"tracker identity": none, "robot controller identity": none}
    rows = {}
    for name, label in (("tracker", "tracker identity"), ("robot", "robot controller identity")):
        seen = list(dict.fromkeys(describe(d[name]) for d in docs))
        rows[label] = "; then, after a resume: ".join(seen)
    mismatches = list(dict.fromkeys(m for d in docs if (m := serial_mismatch(IdentityDoc(**d), stated))))
    if stated is not None:
        rows["tracker serial check"] = (
            ("MISMATCH: " + "; ".join(mismatches))
            if mismatches
            else (
                "the serial read from the tracker is the hardware file's"
                if stated.get("serial") and all(d["tracker"].get("serial") for d in docs)
                else "not checked (a serial is missing on one side)"
            )
        )
    return rows
