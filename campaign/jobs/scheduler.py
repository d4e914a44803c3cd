"""Whether a Dask scheduler still answers while a map runs on it (campaign.jobs.batch.map_chunks).

A scheduler that is killed closes its connections, and distributed's client tries to reconnect for its timeout
before it cancels every future; one that is stopped (SIGSTOP, a hung machine) keeps its connections open and never
answers: the client waits on its futures for ever. A thread asks the scheduler who it is (its `identity` handler)
every PROBE_S; the scheduler is lost when a question fails, or when SCHEDULER_TIMEOUT_S (the time `--scheduler`
waits to connect, campaign.jobs.plan) have passed since its last answer.
"""

from __future__ import annotations

import re
import threading
import time

PROBE_S = 1.0
_IN_COMM = re.compile(r"^in <[^>]*>: ")


class SchedulerWatch:
    def __init__(self, client, timeout_s: float) -> None:
        self._client = client
        self.timeout_s = timeout_s
        self._answered = time.monotonic()
        self._error: str | None = None
        self._stop = threading.Event()
        # a daemon: a question to a stopped scheduler waits its own timeout, and nobody needs its answer then
        threading.Thread(target=self._probe, name="scheduler-watch", daemon=True).start()

    def _probe(self) -> None:
        while not self._stop.is_set():
            try:
                self._client.sync(self._client.scheduler.identity, callback_timeout=self.timeout_s)
            except Exception as exc:  # noqa: BLE001 - whatever the client raises, the scheduler did not answer
                if not self._stop.is_set():
                    text = _IN_COMM.sub("", " ".join(str(exc).split()))  # distributed's "in <TCP ...>: " prefix
                    self._error = f"{type(exc).__name__}: {text}" if text else type(exc).__name__
                return
            self._answered = time.monotonic()
            self._stop.wait(PROBE_S)

    def lost(self) -> str | None:
        """Why the scheduler is lost (one line), or None while it answers."""
        if self._error is not None:
            return f"it stopped answering ({self._error})"
        silent = time.monotonic() - self._answered
        if silent > self.timeout_s:
            return f"it has not answered for {silent:.0f} s"
        return None

    def close(self) -> None:
        self._stop.set()
