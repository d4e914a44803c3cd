"""Start and stop the mock UR controller as a subprocess (ur_rtde's constructors hold the GIL while they wait, so a
mock in the client's process hangs), ready when its ports accept connections (never a fixed sleep)."""

from __future__ import annotations

import socket
import subprocess
import sys
import tempfile
import time

from trackcal.mocks.servers.process import MockProcess
from trackcal.mocks.servers.ur.server import CONTROL_PORT, DASHBOARD_PORT, RTDE_PORT


class MockUrProcess(MockProcess):
    """`with MockUrProcess("127.0.0.5", seed=1) as ur:` ... `ur.inject("protective_stop")`, `ur.state()`."""

    def __init__(
        self,
        host: str = "127.0.0.1",
        seed: int = 0,
        args: list[str] | None = None,
        ready_timeout_s: float = 20.0,
        control_port: int = CONTROL_PORT,
    ) -> None:
        super().__init__(host, seed, ready_timeout_s, control_port)
        self.args = [*(args or []), "--control-port", str(control_port)]

    def start(self) -> MockUrProcess:
        cmd = [
            sys.executable,
            "-m",
            "trackcal.mocks.servers.ur",
            "--host",
            self.host,
            "--seed",
            str(self.seed),
            *self.args,
        ]
        # stderr to a file, not a pipe: nobody reads a pipe while the mock runs, and a full one would block it
        self._stderr = tempfile.TemporaryFile()  # noqa: SIM115 (closed in stop)
        self.proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=self._stderr)
        deadline = time.monotonic() + self.ready_timeout_s
        while True:
            if self.proc.poll() is not None:
                err = self.stderr().strip()
                self.stop()
                raise RuntimeError(f"mock UR controller exited with {self.proc_returncode}: {err}")
            if all(self._accepts(p) for p in (self.control_port, RTDE_PORT, DASHBOARD_PORT)):
                return self
            if time.monotonic() > deadline:
                self.stop()
                raise TimeoutError(f"mock UR controller on {self.host} not ready within {self.ready_timeout_s} s")
            time.sleep(0.05)

    def _accepts(self, port: int) -> bool:
        try:
            with socket.create_connection((self.host, port), timeout=1.0):
                return True
        except OSError:
            return False

    def inject(self, fault: str) -> None:
        reply = self.control(fault)
        if reply != "ok":
            raise ValueError(reply)
