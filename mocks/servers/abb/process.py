"""Start and stop the mock ABB controller in a process of its own (a controller is another machine: a client that
hangs, or a test that kills it to make it disappear, must not take the mock's threads along), ready when it says so
on stdout (never a fixed sleep)."""

from __future__ import annotations

import select
import subprocess
import sys
import tempfile
import time

from trackcal.mocks.servers.process import MockProcess


class MockAbbProcess(MockProcess):
    """`with MockAbbProcess(seed=1) as abb:` ... `abb.address`, `abb.fault("guardstop")`, `abb.state()`, `abb.kill()`"""

    def __init__(
        self, host: str = "127.0.0.1", seed: int = 0, args: list[str] | None = None, ready_timeout_s: float = 60.0
    ) -> None:
        super().__init__(host, seed, ready_timeout_s, control_port=0)
        self.args = list(args or [])
        self.port = 0

    @property
    def address(self) -> tuple[str, int]:
        return self.host, self.port

    def start(self) -> MockAbbProcess:
        cmd = [
            sys.executable,
            "-m",
            "trackcal.mocks.servers.abb",
            "--host",
            self.host,
            "--seed",
            str(self.seed),
            *self.args,
        ]
        self._stderr = tempfile.TemporaryFile()  # noqa: SIM115 (closed in stop)
        self.proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=self._stderr)
        assert self.proc.stdout is not None
        ready, _, _ = select.select([self.proc.stdout], [], [], self.ready_timeout_s)
        line = self.proc.stdout.readline().decode("ascii", "replace").split() if ready else []
        if len(line) != 3 or line[0] != "ready":
            err = self.stderr().strip()
            self.stop()
            raise RuntimeError(f"mock ABB controller did not start within {self.ready_timeout_s} s: {err}")
        self.port, self.control_port = int(line[1]), int(line[2])
        return self

    def fault(self, kind: str) -> None:
        reply = self.control(f"fault {kind}")
        if reply != "ok":
            raise ValueError(reply)

    def busy(self, n: int) -> None:
        if self.control(f"busy {n}") != "ok":
            raise ValueError("busy refused")

    def kill(self) -> None:
        """The controller disappears (power cut, cable pulled): SIGKILL, no goodbye on any connection."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()

    def wait_for(self, predicate, timeout_s: float = 10.0) -> dict:
        """Poll state() until predicate(state) holds; returns that state (TimeoutError otherwise)."""
        deadline = time.monotonic() + timeout_s
        while True:
            state = self.state()
            if predicate(state):
                return state
            if time.monotonic() > deadline:
                raise TimeoutError(f"mock ABB state never satisfied the condition: {state}")
            time.sleep(0.02)
