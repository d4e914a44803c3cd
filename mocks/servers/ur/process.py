"""Start and stop the mock UR controller as a subprocess (ur_rtde's constructors hold the GIL while they wait, so a
mock in the client's process hangs), ready when its ports accept connections (never a fixed sleep)."""

from __future__ import annotations

import contextlib
import json
import os
import socket
import subprocess
import sys
import tempfile
import time

from trackcal.mocks.servers.ur.server import CONTROL_PORT, DASHBOARD_PORT, RTDE_PORT


class MockUrProcess:
    """`with MockUrProcess("127.0.0.5", seed=1) as ur:` ... `ur.inject("protective_stop")`, `ur.state()`."""

    def __init__(self, host: str = "127.0.0.1", seed: int = 0, args: list[str] | None = None,
                 ready_timeout_s: float = 20.0, control_port: int = CONTROL_PORT) -> None:  # fmt: skip
        self.host, self.seed = host, seed
        self.control_port = control_port
        self.args = [*(args or []), "--control-port", str(control_port)]
        self.ready_timeout_s = ready_timeout_s
        self.proc: subprocess.Popen | None = None
        self.proc_returncode: int | None = None
        self._stderr = None

    def start(self) -> MockUrProcess:
        cmd = [sys.executable, "-m", "trackcal.mocks.servers.ur", "--host", self.host, "--seed", str(self.seed),
               *self.args]  # fmt: skip
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

    def stderr(self) -> str:
        """What the mock wrote on stderr so far."""
        if self._stderr is None:
            return ""
        fd = self._stderr.fileno()  # pread: the mock's write offset (shared with this file object) stays where it is
        return os.pread(fd, os.fstat(fd).st_size, 0).decode(errors="replace")

    def _accepts(self, port: int) -> bool:
        try:
            with socket.create_connection((self.host, port), timeout=1.0):
                return True
        except OSError:
            return False

    def control(self, line: str, timeout_s: float = 10.0) -> str:
        with socket.create_connection((self.host, self.control_port), timeout=timeout_s) as s:
            s.sendall(line.encode() + b"\n")
            buf = b""
            while not buf.endswith(b"\n"):
                data = s.recv(65536)
                if not data:
                    break
                buf += data
        return buf.decode().strip()

    def inject(self, fault: str) -> None:
        reply = self.control(fault)
        if reply != "ok":
            raise ValueError(reply)

    def state(self) -> dict:
        return json.loads(self.control("state"))

    def stop(self) -> None:
        if self.proc is None:
            return
        if self.proc.poll() is None:
            with contextlib.suppress(OSError):
                self.control("quit", timeout_s=2.0)
            try:
                self.proc.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.proc_returncode = self.proc.returncode
        self.proc = None
        if self._stderr is not None:
            self._stderr.close()
            self._stderr = None

    def __enter__(self) -> MockUrProcess:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()
