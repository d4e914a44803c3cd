"""What the mock controllers run in processes of their own share (mocks/servers/abb/process.py,
mocks/servers/ur/process.py): the stderr file, the one-line control conversation, `state`, and a stop that asks
`quit` before it kills. Each subclass starts its own module and knows when it is ready."""

from __future__ import annotations

import contextlib
import json
import os
import socket
import subprocess
from abc import ABC, abstractmethod
from typing import Self


class MockProcess(ABC):
    """Base of MockAbbProcess and MockUrProcess: `start()` is theirs; it sets `proc` and `_stderr`."""

    def __init__(self, host: str, seed: int, ready_timeout_s: float, control_port: int) -> None:
        self.host, self.seed = host, seed
        self.ready_timeout_s = ready_timeout_s
        self.control_port = control_port
        self.proc: subprocess.Popen | None = None
        self.proc_returncode: int | None = None
        self._stderr = None

    @abstractmethod
    def start(self) -> Self:
        """Start the mock's process and return once it answers (each subclass knows its module and readiness)."""

    def stderr(self) -> str:
        """What the mock wrote on stderr so far."""
        if self._stderr is None:
            return ""
        fd = self._stderr.fileno()  # pread: the mock's write offset (shared with this file object) stays where it is
        return os.pread(fd, os.fstat(fd).st_size, 0).decode(errors="replace")

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
        if self.proc.stdout is not None:
            self.proc.stdout.close()
        self.proc_returncode = self.proc.returncode
        self.proc = None
        if self._stderr is not None:
            self._stderr.close()
            self._stderr = None

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()
