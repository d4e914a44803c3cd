"""Whether a Dask scheduler still answers while a map runs on it (campaign.jobs.batch.map_chunks, and through
WatchedExecutor every map of `plan --scheduler`).

A scheduler that is killed closes its connections, and distributed's client tries to reconnect for its timeout
before it cancels every future; one that is stopped (SIGSTOP, a hung machine) keeps its connections open and never
answers: the client waits on its futures for ever. A thread asks the scheduler who it is (its `identity` handler)
every PROBE_S; the scheduler is lost when a question fails, or when SCHEDULER_TIMEOUT_S (the time `--scheduler`
waits to connect, campaign.jobs.plan) have passed since its last answer.

A scheduler that answers can still have no worker: each one died (killed, out of memory) and none came back (a
nanny that failed to start its worker again logs it and stays up). Its tasks then wait for a worker for ever, and so
did `batch --scheduler` (a killed-worker test once waited past its 600 s, issue 37): the cluster counts as lost once
the scheduler has said for NO_WORKER_S that it has no worker.
"""

from __future__ import annotations

import re
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import CancelledError, Executor, Future, wait

from trackcal.campaign.errors import CampaignError

PROBE_S = 1.0
# how long the scheduler may have no worker at all: Dask's own time to live of a silent worker (distributed's
# distributed.scheduler.worker-ttl, "5 minutes"), ample for a nanny's restart or an adaptive cluster's first worker
NO_WORKER_S = 300.0
_IN_COMM = re.compile(r"^in <[^>]*>: ")


class SchedulerWatch:
    def __init__(self, client, timeout_s: float) -> None:
        self._client = client
        self.timeout_s = timeout_s
        self._answered = self._staffed = time.monotonic()  # _staffed: when the scheduler last had a worker
        self._error: str | None = None
        self._stop = threading.Event()
        # a daemon: a question to a stopped scheduler waits its own timeout, and nobody needs its answer then
        threading.Thread(target=self._probe, name="scheduler-watch", daemon=True).start()

    def _probe(self) -> None:
        while not self._stop.is_set():
            try:
                who = self._client.sync(self._client.scheduler.identity, callback_timeout=self.timeout_s)
            except Exception as exc:  # noqa: BLE001 - whatever the client raises, the scheduler did not answer
                if not self._stop.is_set():
                    text = _IN_COMM.sub("", " ".join(str(exc).split()))  # distributed's "in <TCP ...>: " prefix
                    self._error = f"{type(exc).__name__}: {text}" if text else type(exc).__name__
                return
            self._answered = time.monotonic()
            if not isinstance(who, dict) or who.get("n_workers", 1):  # one that does not say counts as staffed
                self._staffed = self._answered
            self._stop.wait(PROBE_S)

    def lost(self) -> str | None:
        """Why the scheduler is lost (one line), or None while it answers."""
        if self._error is not None:
            return f"it stopped answering ({self._error})"
        silent = time.monotonic() - self._answered
        if silent > self.timeout_s:
            return f"it has not answered for {silent:.0f} s"
        alone = time.monotonic() - self._staffed
        if alone > NO_WORKER_S:
            return f"it has had no worker for {alone:.0f} s (each one died, or none joined)"
        return None

    def close(self) -> None:
        self._stop.set()


class SchedulerLost(CampaignError):
    """The Dask scheduler was lost mid-map (killed, or silent for the watch's timeout): what was not finished is not
    done."""


class WatchedExecutor(Executor):
    """A Dask client's executor (distributed's ClientExecutor) with its scheduler watched: `map` gives its results in
    order as they come and raises SchedulerLost once the scheduler is lost (killed: the client gives up and cancels
    the futures; stopped: no answer for the watch's timeout), where the plain executor's map would wait for ever on a
    stopped one. `watch` and `_client` stay reachable for the batch's own loop."""

    def __init__(self, inner: Executor, watch: SchedulerWatch, scheduler: str) -> None:
        self._inner, self.watch, self.scheduler = inner, watch, scheduler
        self._client = getattr(inner, "_client", None)

    def submit(self, fn: Callable, /, *args, **kwargs) -> Future:
        return self._inner.submit(fn, *args, **kwargs)

    def map(self, fn: Callable, *iterables: Iterable, timeout=None, chunksize: int = 1) -> Iterator:
        futures = [self._inner.submit(fn, *args) for args in zip(*iterables, strict=False)]
        return self._results(futures)

    def _results(self, futures: list[Future]) -> Iterator:
        for fut in futures:
            while not wait([fut], timeout=PROBE_S).done:
                self.check(cancelled=False)
            if fut.cancelled():
                self.check(cancelled=True)
            try:
                yield fut.result()
            except CancelledError:  # the client gave up on the scheduler
                self.check(cancelled=True)
                raise

    def check(self, cancelled: bool) -> None:
        """SchedulerLost if the scheduler is lost (or the client cancelled a future: it gave up reconnecting)."""
        why = self.watch.lost() or ("the client gave up reconnecting" if cancelled else None)
        if why:
            raise SchedulerLost(f"the Dask scheduler {self.scheduler} was lost mid-run: {why}")

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        self.watch.close()
        self._inner.shutdown(wait=False)
