"""The session store: one SQLite database per session directory, append-only, hash-chained events.

The database file alone is the record. It runs in rollback-journal mode (journal_mode=DELETE) with
synchronous=FULL: when `append` returns, the event is in `session.sqlite` itself and on the disk, so a copy
of that one file, taken between two events, holds every event committed before it, and kill -9 or a power
cut loses nothing committed. (A `session.sqlite-journal` exists only while a write is in flight; SQLite
rolls it back at the next open.) The cell, robot, tool, plan and hardware config the session was created
with are stored in it too (`documents`), so resume and replay need nothing else.

Schema (version 2), `SESSION/session.sqlite`:

    meta(key TEXT PRIMARY KEY, value TEXT)        -- written once at creation: schema, mode, seed, ...
    documents(name TEXT PRIMARY KEY,              -- 'plan.json', 'config/cell.yaml', 'config/robot.yaml', ...
              text TEXT, sha256 TEXT)             -- the file as it was at creation, and its hash
    events(id INTEGER PRIMARY KEY AUTOINCREMENT,  -- 1, 2, 3, ...: never updated or deleted
           t_wall REAL,                           -- wall clock (s since the epoch)
           t_campaign REAL,                       -- seconds since the campaign start (the table's t_s)
           step INTEGER,                          -- index of the plan step, -1 outside steps
           kind TEXT,                             -- see KINDS
           data TEXT,                             -- canonical JSON
           hash TEXT)                             -- sha256(previous hash + this event, canonical JSON)

The chain starts from the hash of the header (schema, meta and the documents' hashes), so an edited event,
a removed one or an edited plan shows as the first event whose hash does not follow (`verify`). It detects
corruption and edits, not a forger who recomputes every hash after his edit: `trackcal check` prints the
head hash, which a note taken at the end of a campaign pins down.

One process per session: a process that writes (run, resume, replay into) holds an exclusive `flock` on
`SESSION/session.lock` for as long as it has the store open; the kernel drops it when the process dies,
kill -9 included, so no stale lock is ever left. Readers (export, check, replay's recording) take no lock.
"""

from __future__ import annotations

import fcntl
import hashlib
import json
import os
import sqlite3
import time
from dataclasses import dataclass
from pathlib import Path

from trackcal.campaign.errors import CampaignError

SCHEMA_VERSION = "2"
DB_NAME = "session.sqlite"
LOCK_NAME = "session.lock"
TABLES = {
    "meta": "CREATE TABLE meta(key TEXT PRIMARY KEY, value TEXT NOT NULL)",
    "documents": "CREATE TABLE documents(name TEXT PRIMARY KEY, text TEXT NOT NULL, sha256 TEXT NOT NULL)",
    "events": "CREATE TABLE events(id INTEGER PRIMARY KEY AUTOINCREMENT, t_wall REAL NOT NULL, "
    "t_campaign REAL NOT NULL, step INTEGER NOT NULL, kind TEXT NOT NULL, data TEXT NOT NULL, "
    "hash TEXT NOT NULL)",
}
# What SQLite itself adds for these tables (the PRIMARY KEY indexes, AUTOINCREMENT's counter): with TABLES, the whole
# schema. Anything else in sqlite_master (a trigger that rewrites events, a view, an index) is not trackcal's.
SQLITE_OWN = {
    ("index", "sqlite_autoindex_meta_1"),
    ("index", "sqlite_autoindex_documents_1"),
    ("table", "sqlite_sequence"),
}


def refuse_links(directory: Path, *names: str) -> None:
    """The session folder is the user's: neither it nor a file of it may be a symbolic link, which would make trackcal
    write (as root, on many cell PCs) wherever the link points."""
    for path in (directory, *(directory / n for n in names)):
        if path.is_symlink():
            raise StoreError(
                f"{path}: a symbolic link: trackcal opens no session folder or file through a link "
                f"(copy the session to a real directory)"
            )


KINDS = (  # the engine's documents (their data's schema: campaign/engine/documents.py, one TypedDict per kind)
    "campaign_started",  # StartDoc
    "step_started",  # StepStartedDoc
    "step_done",  # StepDoneDoc
    "call",  # CallDoc
    "measurement",  # MeasurementDoc
    "prompt",  # PromptDoc
    "operator",  # OperatorDoc
    "warning",  # WarningDoc
    "error",  # ErrorDoc
    "campaign_done",  # {}: a successful StopDoc
    "station_fit",  # StationFitDoc (engine/station_fit.py)
    "identity",  # IdentityDoc (cells/identity.py): the devices' identities at a run's start
)


class StoreError(CampaignError):
    """A session that cannot be used (missing, locked, damaged, broken chain, other schema, cannot be written)."""


@dataclass
class Event:
    id: int
    t_wall: float
    t_campaign: float
    step: int
    kind: str
    data: dict


def canonical(value) -> str:
    """The one JSON text of a value that hashes are computed over (sorted keys, no spaces)."""
    return json.dumps(value, sort_keys=True, separators=(",", ":"), ensure_ascii=False)


def sha256(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()


def event_hash(
    previous: str, event_id: int, t_wall: float, t_campaign: float, step: int, kind: str, data_text: str
) -> str:
    """sha256 of the previous event's hash, then this event as canonical JSON (its fields, then its data)."""
    return sha256(previous + canonical([event_id, t_wall, t_campaign, step, kind]) + data_text)


def _utc(t: float) -> str:
    return time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime(t))


class SessionLock:
    """The exclusive OS lock of a session directory, held by one process; its file says who holds it."""

    def __init__(self, fd: int):
        self._fd = fd

    @classmethod
    def acquire(cls, directory: Path) -> SessionLock:
        path = directory / LOCK_NAME
        refuse_links(directory, LOCK_NAME)
        try:
            if not os.access(directory, os.W_OK):
                raise PermissionError(0, "read-only")
            # O_NOFOLLOW: a link put there between the check above and this open is not followed either (ELOOP)
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC, 0o644)
        except OSError as exc:
            raise StoreError(
                f"{directory}: cannot write there ({exc.strerror}): a campaign writes its session; copy "
                f"the directory to a writable place and resume the copy (export and check read it "
                f"where it is)"
            ) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 200, 0).decode(errors="replace").strip() or "another process"
            os.close(fd)
            raise StoreError(
                f"{directory}: in use by {holder} (one process per session: wait for it to end, or stop it)"
            ) from None
        try:
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"process {os.getpid()} since {_utc(time.time())}\n".encode(), 0)
        except OSError as exc:
            os.close(fd)
            raise StoreError(f"{path}: cannot write ({exc.strerror})") from None
        return cls(fd)

    def release(self) -> None:
        os.close(self._fd)  # closing the descriptor drops the flock


def _write_failure(directory: Path, what: str, exc: sqlite3.Error) -> StoreError:
    """One line for a write that did not happen: what failed, why, and that nothing committed is lost."""
    name = getattr(exc, "sqlite_errorname", "")
    if name == "SQLITE_FULL":
        why = "the disk is full"
    elif name.startswith("SQLITE_READONLY") or name.startswith("SQLITE_CANTOPEN"):
        why = "the session directory or database is read-only"
    else:
        why = str(exc)
    return StoreError(
        f"{directory}: cannot store {what}: {why}. Everything stored before is in "
        f"{directory / DB_NAME}: make room, or copy {directory} to another disk, then "
        f"`trackcal resume` it"
    )


def _damaged(path: Path, exc: sqlite3.Error) -> StoreError:
    if getattr(exc, "sqlite_errorname", "") == "SQLITE_READONLY_ROLLBACK":
        return StoreError(
            f"{path}: a write was interrupted and cannot be rolled back in a read-only place (copy "
            f"the session directory, {path.name}-journal included, to a writable one)"
        )
    return StoreError(
        f"{path}: damaged or not a trackcal session database ({exc}); a copy of the session taken "
        f"before the damage can be checked and resumed"
    )


@dataclass
class Verified:
    """What `SessionStore.verify` found: a sound database and an unbroken chain of `events` events."""

    events: int
    head: str


class SessionStore:
    def __init__(self, directory: Path, conn: sqlite3.Connection, lock: SessionLock | None):
        self.directory = directory
        self.path = directory / DB_NAME
        self.conn = conn
        self._lock = lock
        self._head = ""
        self._next_id = 1

    @staticmethod
    def _connect(path: Path) -> sqlite3.Connection:
        # mode=rw: never creates a file; a read-only file opens for reading. An interrupted write's journal is
        # rolled back by SQLite here (it needs write access, which a reader of a killed session has).
        # the path percent-encoded (Path.as_uri): a `?`, `#` or `%` in a folder name is part of the name, not of the URI
        conn = sqlite3.connect(f"{path.absolute().as_uri()}?mode=rw", uri=True, isolation_level=None, timeout=30.0)
        conn.execute("PRAGMA synchronous=FULL")
        return conn

    @classmethod
    def create(cls, directory: str | Path, meta: dict[str, str], documents: dict[str, str]) -> SessionStore:
        """A new session in `directory` (created if needed), holding its lock."""
        directory = Path(directory)
        try:
            directory.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise StoreError(f"{directory}: cannot create the session directory ({exc.strerror})") from None
        lock = SessionLock.acquire(directory)
        path = directory / DB_NAME
        try:
            if path.exists():
                raise StoreError(f"{directory}: already holds a session (use `trackcal resume {directory}`)")
            conn = sqlite3.connect(str(path), isolation_level=None, timeout=30.0)
            store = cls(directory, conn, lock)
            try:
                conn.execute("PRAGMA journal_mode=DELETE")
                conn.execute("PRAGMA synchronous=FULL")
                conn.execute("BEGIN")
                for ddl in TABLES.values():
                    conn.execute(ddl)
                conn.executemany("INSERT INTO meta VALUES (?, ?)", [("schema", SCHEMA_VERSION), *meta.items()])
                conn.executemany(
                    "INSERT INTO documents VALUES (?, ?, ?)",
                    [(name, text, sha256(text)) for name, text in documents.items()],
                )
                conn.execute("COMMIT")
            except sqlite3.Error as exc:
                conn.close()
                path.unlink()  # not a session: the directory stays free for the next `run`
                why = "the disk is full" if getattr(exc, "sqlite_errorname", "") == "SQLITE_FULL" else str(exc)
                raise StoreError(f"{directory}: cannot create the session: {why}") from None
        except BaseException:
            lock.release()
            raise
        store._head = store.root()
        return store

    @classmethod
    def open(cls, directory: str | Path, readonly: bool = False) -> SessionStore:
        """An existing session, checked (`verify`); `readonly=False` takes its lock (resume)."""
        directory = Path(directory)
        path = directory / DB_NAME
        refuse_links(directory, DB_NAME)
        if not path.exists():
            raise StoreError(f"{directory}: not a trackcal session (no {DB_NAME})")
        lock = None if readonly else SessionLock.acquire(directory)
        try:
            try:
                conn = cls._connect(path)
            except sqlite3.Error as exc:
                raise _damaged(path, exc) from None
            store = cls(directory, conn, lock)
            try:
                store._check_schema()
                verified = store.verify()
            except BaseException:
                conn.close()
                raise
        except BaseException:
            if lock is not None:
                lock.release()
            raise
        store._head, store._next_id = verified.head, verified.events + 1
        return store

    def _check_schema(self) -> None:
        """The schema version, then the schema itself: trackcal's tables as it creates them and nothing else (a
        trigger could rewrite every event as it is read or appended, a view could stand in for a table)."""
        try:
            entries = self.conn.execute("SELECT type, name, sql FROM sqlite_master").fetchall()
            tables = {name for kind, name, _ in entries if kind == "table"}
            schema = "SELECT value FROM meta WHERE key='schema'"
            row = self.conn.execute(schema).fetchone() if "meta" in tables else None
        except sqlite3.Error as exc:
            raise _damaged(self.path, exc) from None
        if row is None:
            raise StoreError(f"{self.path}: not a trackcal session database (no schema version in it)")
        if row[0] != SCHEMA_VERSION:
            raise StoreError(
                f"{self.path}: session schema {row[0]}, this trackcal reads schema {SCHEMA_VERSION} "
                f"(hash-chained events, stored plan and config): use the trackcal that recorded "
                f"it"
            )
        foreign = sorted(
            f"{kind} {name}"
            for kind, name, sql in entries
            if (kind, name) not in SQLITE_OWN and not (kind == "table" and TABLES.get(name) == sql)
        )
        if foreign:
            raise StoreError(
                f"{self.path}: its schema is not trackcal's ({', '.join(foreign)} added or changed "
                f"after the session was created): the database was edited"
            )

    def verify(self) -> Verified:
        """SQLite's integrity check, the stored documents against their hashes, then the hash chain from the
        header to the last event; the first thing that fails is a StoreError naming it."""
        try:
            problems = [r[0] for r in self.conn.execute("PRAGMA integrity_check").fetchall()]
            if problems != ["ok"]:
                raise StoreError(
                    f"{self.path}: damaged database (SQLite integrity check: {problems[0]}"
                    f"{f'; {len(problems) - 1} more' if len(problems) > 1 else ''})"
                )
            for name, text, digest in self.conn.execute("SELECT name, text, sha256 FROM documents ORDER BY name"):
                if sha256(text) != digest:
                    raise StoreError(
                        f"{self.path}: the stored copy of {name} does not match its hash: changed after "
                        f"the session was created"
                    )
            previous, n = self.root(), 0
            rows = self.conn.execute("SELECT id, t_wall, t_campaign, step, kind, data, hash FROM events ORDER BY id")
            for event_id, t_wall, t_campaign, step, kind, text, digest in rows:
                n += 1
                if event_id != n or event_hash(previous, event_id, t_wall, t_campaign, step, kind, text) != digest:
                    before = "the session's header (meta, stored plan and config) or " if n == 1 else ""
                    raise StoreError(
                        f"{self.path}: event {event_id} ({kind}, step {step}) breaks the hash chain: "
                        f"{before}this event was changed, or one before it removed; events 1 to "
                        f"{n - 1} are intact"
                    )
                previous = digest
        except sqlite3.Error as exc:
            raise _damaged(self.path, exc) from None
        return Verified(n, previous)

    def root(self) -> str:
        """The chain's start: the hash of the schema, the meta and the stored documents' hashes."""
        meta = dict(self.conn.execute("SELECT key, value FROM meta").fetchall())
        docs = dict(self.conn.execute("SELECT name, sha256 FROM documents").fetchall())
        return sha256(canonical({"meta": meta, "documents": docs}))

    @property
    def head(self) -> str:
        """The hash of the last event (of the header while there is none)."""
        return self._head

    def meta(self) -> dict[str, str]:
        return dict(self.conn.execute("SELECT key, value FROM meta").fetchall())

    def documents(self) -> dict[str, str]:
        """The files stored at creation, by their name in the session directory."""
        return dict(self.conn.execute("SELECT name, text FROM documents ORDER BY name").fetchall())

    def append(self, kind: str, data: dict, step: int = -1, t_campaign: float = 0.0) -> int:
        """Store one event in its own committed transaction; returns its id. A failed write is a StoreError
        (nothing half-written: the transaction rolls back)."""
        if kind not in KINDS:
            raise ValueError(f"unknown event kind {kind!r}")
        event_id, t_wall, t_campaign, step = self._next_id, time.time(), float(t_campaign), int(step)
        text = canonical(data)
        digest = event_hash(self._head, event_id, t_wall, t_campaign, step, kind, text)
        try:
            self.conn.execute(
                "INSERT INTO events(id, t_wall, t_campaign, step, kind, data, hash) VALUES (?, ?, ?, ?, ?, ?, ?)",
                (event_id, t_wall, t_campaign, step, kind, text, digest),
            )
        except sqlite3.Error as exc:
            raise _write_failure(self.directory, f"event {event_id} ({kind})", exc) from None
        self._head, self._next_id = digest, event_id + 1
        return event_id

    def events(self, kind: str | None = None) -> list[Event]:
        sql = "SELECT id, t_wall, t_campaign, step, kind, data FROM events"
        rows = self.conn.execute(
            sql + (" WHERE kind=? ORDER BY id" if kind else " ORDER BY id"), (kind,) if kind else ()
        ).fetchall()
        return [Event(r[0], r[1], r[2], r[3], r[4], json.loads(r[5])) for r in rows]

    def done_steps(self) -> set[int]:
        """Steps that need not run again: ended, or whose measurement is committed (a kill between the
        measurement and the step's end must not measure the pose twice)."""
        return {r[0] for r in self.conn.execute("SELECT step FROM events WHERE kind IN ('step_done', 'measurement')")}

    def close(self) -> None:
        self.conn.close()
        if self._lock is not None:
            self._lock.release()
            self._lock = None
