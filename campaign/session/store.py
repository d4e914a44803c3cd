"""The session store: one SQLite database (WAL) per session directory, append-only events.

Schema (version 1), `SESSION/session.sqlite`:

    meta(key TEXT PRIMARY KEY, value TEXT)          -- written once at creation: schema, cell (YAML text of
                                                     -- cell, robot and tool), plan (JSON), mode, seed, ...
    events(id INTEGER PRIMARY KEY AUTOINCREMENT,     -- strictly increasing, never updated or deleted
           t_wall REAL,                              -- wall clock (s since the epoch)
           t_campaign REAL,                          -- seconds since the campaign start (the table's t_s)
           step INTEGER,                             -- index of the plan step, -1 outside steps
           kind TEXT,                                -- see KINDS
           data TEXT)                                -- JSON

Every `append` is its own committed transaction with synchronous=FULL: once it returns, the event
survives a crash of the process (kill -9) or of the machine. The engine appends a measurement before it
issues the next motion, and marks a step done only after its events are stored.
"""

from __future__ import annotations

import json
import sqlite3
import time
from dataclasses import dataclass
from pathlib import Path

from campaign.errors import CampaignError

SCHEMA_VERSION = "1"
DB_NAME = "session.sqlite"
KINDS = (
    "campaign_started",  # {"resumed": bool}
    "step_started",  # {"step": {...}}
    "step_done",  # {}
    "call",  # {"device", "op", "args", "result" | "error": {"type", "message", "code"}}
    "measurement",  # {"pose", "station", "point", "q_deg", "xyz_mm", "std_mm", "env"}
    "prompt",  # {"kind", "text"}
    "operator",  # {"answer"}
    "warning",  # {"message"}
    "error",  # {"message", "type"}
    "campaign_done",  # {}
)


class StoreError(CampaignError):
    """A session directory that cannot be used (missing, not a session, other schema)."""


@dataclass
class Event:
    id: int
    t_wall: float
    t_campaign: float
    step: int
    kind: str
    data: dict


class SessionStore:
    def __init__(self, directory: Path, conn: sqlite3.Connection):
        self.directory = directory
        self.conn = conn

    @staticmethod
    def _connect(path: Path) -> sqlite3.Connection:
        conn = sqlite3.connect(str(path), isolation_level=None, timeout=30.0)
        conn.execute("PRAGMA journal_mode=WAL")
        conn.execute("PRAGMA synchronous=FULL")
        return conn

    @classmethod
    def create(cls, directory: str | Path, meta: dict[str, str]) -> SessionStore:
        directory = Path(directory)
        if (directory / DB_NAME).exists():
            raise StoreError(f"{directory}: already holds a session (use `trackcal resume {directory}`)")
        try:
            directory.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise StoreError(f"{directory}: cannot create the session directory ({exc.strerror})") from None
        conn = cls._connect(directory / DB_NAME)
        with conn:
            conn.execute("BEGIN")
            conn.execute("CREATE TABLE meta(key TEXT PRIMARY KEY, value TEXT NOT NULL)")
            conn.execute(
                "CREATE TABLE events(id INTEGER PRIMARY KEY AUTOINCREMENT, t_wall REAL NOT NULL, "
                "t_campaign REAL NOT NULL, step INTEGER NOT NULL, kind TEXT NOT NULL, data TEXT NOT NULL)"
            )
            conn.executemany("INSERT INTO meta VALUES (?, ?)", [("schema", SCHEMA_VERSION), *meta.items()])
            conn.execute("COMMIT")
        return cls(directory, conn)

    @classmethod
    def open(cls, directory: str | Path, readonly: bool = False) -> SessionStore:
        directory = Path(directory)
        path = directory / DB_NAME
        if not path.exists():
            raise StoreError(f"{directory}: not a trackcal session (no {DB_NAME})")
        if readonly:
            conn = sqlite3.connect(f"file:{path}?mode=ro", uri=True, isolation_level=None, timeout=30.0)
        else:
            conn = cls._connect(path)
        try:
            schema = conn.execute("SELECT value FROM meta WHERE key='schema'").fetchone()
        except sqlite3.DatabaseError as exc:
            raise StoreError(f"{path}: not a trackcal session database ({exc})") from None
        if schema is None or schema[0] != SCHEMA_VERSION:
            raise StoreError(f"{path}: session schema {schema and schema[0]!r}, this trackcal reads {SCHEMA_VERSION}")
        return cls(directory, conn)

    def meta(self) -> dict[str, str]:
        return dict(self.conn.execute("SELECT key, value FROM meta").fetchall())

    def append(self, kind: str, data: dict, step: int = -1, t_campaign: float = 0.0) -> int:
        if kind not in KINDS:
            raise ValueError(f"unknown event kind {kind!r}")
        cur = self.conn.execute(
            "INSERT INTO events(t_wall, t_campaign, step, kind, data) VALUES (?, ?, ?, ?, ?)",
            (time.time(), float(t_campaign), int(step), kind, json.dumps(data, sort_keys=True)),
        )
        return int(cur.lastrowid)

    def events(self, kind: str | None = None) -> list[Event]:
        sql = "SELECT id, t_wall, t_campaign, step, kind, data FROM events"
        rows = self.conn.execute(sql + (" WHERE kind=? ORDER BY id" if kind else " ORDER BY id"),
                                 (kind,) if kind else ()).fetchall()  # fmt: skip
        return [Event(r[0], r[1], r[2], r[3], r[4], json.loads(r[5])) for r in rows]

    def done_steps(self) -> set[int]:
        """Steps that need not run again: ended, or whose measurement is committed (a kill between the
        measurement and the step's end must not measure the pose twice)."""
        return {r[0] for r in self.conn.execute("SELECT step FROM events WHERE kind IN ('step_done', 'measurement')")}

    def close(self) -> None:
        self.conn.close()
