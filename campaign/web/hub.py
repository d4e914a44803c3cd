"""The page's side of a campaign: a subscriber of the engine's documents (`Hub.__call__`) that keeps the
session's events as the store holds them and hands each new one to the connected pages without ever waiting
on them, and the page as one more operator (`PageOperator`) that answers prompts through it.

Threads: the engine calls the hub (documents, the prompt offered and polled, the cell's door and E-stop read
while a prompt waits) in its own thread; the server (server.py) runs an asyncio loop in another, where pages
connect and answer. The two meet under one lock held for microseconds, and the engine's side hands events to
the loop with `call_soon_threadsafe`, which never blocks: a page that hangs, or a server thread that died,
costs the campaign nothing (its operator drops out: campaign.cells.operator.FirstAnswer).
"""

from __future__ import annotations

import secrets
import threading
import time
from collections.abc import Callable

from trackcal.campaign.engine.engine import Document
from trackcal.campaign.session.store import SessionStore
from trackcal.campaign.web.state import StoredEvent
from trackcal.drivers.errors import ConnectionLost


class Hub:
    """`store`: the session (its events so far are the start of the mirror; each document the store committed
    since is read back by its id, in the engine's thread, so the mirror is the session's events exactly).
    `plan`: state.plan_view of the campaign."""

    def __init__(self, store: SessionStore, plan: dict) -> None:
        self.store, self.plan = store, plan
        self.lock = threading.Lock()
        self.events: list[StoredEvent] = [
            StoredEvent(e.id, e.step, e.t_campaign, e.kind, e.data) for e in store.events()
        ]
        self._head = store.head
        self.csrf = secrets.token_urlsafe(24)
        self.live: dict = {
            "open": None,
            "controller": None,
            "door_closed": None,
            "estop_ok": None,
            "outcome": None,
            "stop": None,
            "clients": 0,
        }
        self._answer: str | None = None
        self._listeners: list[Callable[[str, object], None]] = []
        self.doc_wall: dict[int, float] = {}  # event id -> wall time the hub got its document (bench_web)
        self.alive: Callable[[], bool] = lambda: True  # the server says whether its thread runs

    # ---------------------------------------------------------------- the engine's thread
    def __call__(self, doc: Document) -> None:
        """A subscriber: the documents the store committed (its head moved) become events of the mirror."""
        now = time.time()
        d = doc.data
        if doc.name == "call" and d.get("device") == "cellio" and d.get("op") == "door_closed" and "result" in d:
            self.set_live(door_closed=bool(doc.data["result"]))
        if doc.name == "stop":
            self.set_live(stop={"exit_status": doc.data.get("exit_status"), "reason": doc.data.get("reason", "")})
        if self.store.head == self._head:
            return  # not stored (progress, a stop other than success)
        self._head = self.store.head
        row = self.store.conn.execute(
            "SELECT id, step, t_campaign, kind, data FROM events ORDER BY id DESC LIMIT 1"
        ).fetchone()
        event = StoredEvent(row[0], row[1], row[2], row[3], doc.data if row[3] != "campaign_done" else {})
        with self.lock:
            self.events.append(event)
            self.doc_wall[event.id] = now
            listeners = list(self._listeners)
        for push in listeners:
            push("event", event)

    def set_live(self, **values) -> None:
        with self.lock:
            changed = {k: v for k, v in values.items() if self.live.get(k) != v}
            self.live.update(changed)
            listeners = list(self._listeners)
        if changed:
            for push in listeners:
                push("live", changed)

    # ---------------------------------------------------------------- the server's thread
    def subscribe(self, push: Callable[[str, object], None]) -> tuple[list[StoredEvent], dict]:
        """Register a page's push (called from any thread, must not block) and return the events so far and the
        live values, atomically: every later event reaches `push`."""
        with self.lock:
            self._listeners.append(push)
            return list(self.events), dict(self.live)

    def unsubscribe(self, push) -> None:
        with self.lock:
            if push in self._listeners:
                self._listeners.remove(push)

    def answer(self, prompt_id: int, client: str, source: str) -> str | None:
        """A page's answer to the prompt `prompt_id`: None if taken, else why not (the prompt is not open, the
        client does not hold control)."""
        with self.lock:
            if self.live["controller"] != client:
                return "another page holds control"
            if self.live["open"] != prompt_id:
                return "this prompt is not waiting for an answer (answered already, or not yet offered)"
            if self._answer is None:
                self._answer = source
        return None

    def take_control(self, client: str) -> None:
        self.set_live(controller=client)

    def claim_control(self, client: str) -> None:
        """The first page to connect holds control."""
        with self.lock:
            first = self.live["controller"] is None
        if first:
            self.set_live(controller=client)


class PageOperator:
    """The page as an operator (drivers.interfaces.SharedOperator): the prompt offered is the session's last
    prompt event (the page answers it by its event id); the answer is "page CLIENT from ADDRESS"."""

    def __init__(self, hub: Hub) -> None:
        self.hub = hub

    def offer(self, kind: str, target: str, text: str) -> None:
        self._check()
        prompt = next((e.id for e in reversed(self.hub.events) if e.kind == "prompt"), None)
        with self.hub.lock:
            self.hub._answer = None
        self.hub.set_live(open=prompt)

    def poll(self) -> str | None:
        with self.hub.lock:
            answer = self.hub._answer
        if answer is not None:
            self.hub.set_live(open=None)
            return answer
        self._check()
        return None

    def withdraw(self) -> None:
        self.hub.set_live(open=None)

    def _check(self) -> None:
        if not self.hub.alive():
            raise ConnectionLost("the operator's page stopped (its server thread ended)", device="operator page")
