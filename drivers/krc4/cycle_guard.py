"""The KR C4's motion guard, read once per RSI cycle and answered within the cycle (issue 40: from the PLC's door to
the brake in a cycle or two of 4 ms).

The KR C2 client (drivers.kuka.client) reads the guard in the moving thread every GUARD_S (40 ms, between waits for
the EKI answer), and its stop request then waits for the KRL's StopPoll (nPollMs of configs/krc4/trackcal_eki.dat):
about 7 cycles of 4 ms from the door to the brake on average, 11 at worst (docs/krc4.md, measured). On the KR C4
one thread reads the guard once per RSI cycle (rsi cycle_s, on a fixed schedule: the PLC's poll period is the
cycle) while a move or a settle runs, and keeps what it read. During a move, a reason (or `stop()` asked from
another thread) sets the RSI link's stop flag: the answer to the next frame carries <Stop>1</Stop>
(configs/krc4/trackcal_rsi_ethernet.xml), which the controller acts on in its next cycle (interrupt 18 of
trackcal_eki.src: BRAKE). The moving thread reads the kept state instead of the PLC (one reader, one read per
poll: `state`) and still sends the EKI stop request; the move ends with the controller's answer (Error 6) and the
guard's code. The flag falls back to 0 when the move ends, so the next stop is a new rising edge.

Only an answered stream (ONLYSEND FALSE) can carry the stop: a passive KR C4 keeps the KR C2's guard.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable, Iterator

from trackcal.drivers.kuka.rsi_link import RsiLink

Reader = Callable[[], "str | None"]


class CycleGuard:
    """Reads `read` (the motion guard: the PLC) once per RSI cycle while armed; raises the RSI stop flag during a
    move (`moving()`) when it, or `asked()` (stop() from another thread), names a reason."""

    def __init__(self, read: Reader, asked: Reader, moving: Callable[[], bool], rsi: RsiLink) -> None:
        self._read, self._asked, self._moving = read, asked, moving
        self.rsi = rsi
        self._cond = threading.Condition()
        self._read_lock = threading.Lock()  # the PLC is read by one thread at a time
        self._armed = 0
        self._closed = False
        self._thread: threading.Thread | None = None
        self.reason: str | None = None  # what the last read said
        self.tripped: str | None = None  # the reason that raised the stop flag during the running move
        self.polls = 0  # reads of the guard (tests, the bench)

    def start(self) -> None:
        with self._cond:
            self._closed = False
        self._thread = threading.Thread(target=self._run, name="krc4-guard", daemon=True)
        self._thread.start()

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify_all()
        thread, self._thread = self._thread, None
        if thread is not None:
            thread.join(timeout=2.0)

    @contextlib.contextmanager
    def armed(self) -> Iterator[None]:
        """Read the guard every cycle for the duration (a move, a settle); the state is read once at once, so it
        is current from the first instant. The stop flag falls when the last armed section ends."""
        with self._cond:
            self._armed += 1
            self._cond.notify_all()
        try:
            self.poll()
            yield
        finally:
            with self._cond:
                self._armed -= 1
                if not self._armed:
                    self.rsi.stop_requested, self.tripped = False, None

    def state(self) -> str | None:
        """The guard's reason as last read while armed (the moving thread's view: no PLC traffic); read now when
        not armed."""
        with self._cond:
            if self._armed:
                return self.reason
        return self.poll()

    def poll(self) -> str | None:
        """One read of the guard; during a move a reason (the guard's, or stop() asked) raises the stop flag."""
        with self._read_lock:
            reason = self._read()
            self.polls += 1
        why = reason or self._asked()
        with self._cond:
            self.reason = reason
            if why and self._armed and self._moving() and not self.rsi.stop_requested:
                self.rsi.stop_requested, self.tripped = True, why
        return reason

    def _run(self) -> None:
        """One read per cycle from the arming on; a read that came more than a cycle late starts a new schedule."""
        due = None
        while True:
            with self._cond:
                if not self._armed:
                    due = None
                self._cond.wait_for(lambda: self._armed or self._closed)
                if self._closed:
                    return
                now = time.monotonic()
                due = now if due is None or now - due > self.rsi.cycle_s else due  # late: a new schedule
                if due > now:
                    self._cond.wait(due - now)  # woken early only by close() or an arming
                    if self._closed:
                        return
                    if not self._armed:
                        continue
            self.poll()
            due += self.rsi.cycle_s
