"""The EGM position stream as a joint monitor: trackcal listens on a UDP port (the controller's EGM configuration names
this PC's address and port: the controller is the sender, ABB "Application manual - Externally Guided Motion",
3HAC073319-001, the UdpUc transmission protocol) and keeps every EgmRobot the controller sends (one per EGM cycle,
4 ms at the fastest), with its arrival time. Datagrams from any other address than the controller's are refused
(counted in `refused`), as the KR C2's RSI monitor refuses them.

The frames are numbered here in arrival order: a settle is counted in frames (controller time: one EGM cycle each),
freshness in wall time (`stale_s`: no frame for that long, the stream is stale)."""

from __future__ import annotations

import collections
import contextlib
import socket
import threading
import time

from trackcal.drivers.abb.egm_codec import EgmError, EgmRobot, decode
from trackcal.drivers.errors import ConnectionLost, DeviceFault, DeviceTimeout

EGM_STALE = "egm_stale"  # the stop code of a stream that went silent
HISTORY = 4096  # frames kept (16 s at 4 ms)


class EgmLink:
    def __init__(
        self,
        host: str,
        port: int,
        controller_host: str,
        *,
        cycle_s: float = 0.004,
        stale_s: float = 1.0,
        device: str = "",
    ) -> None:
        self.host, self.port = host, int(port)
        self.controller_host = controller_host
        self.cycle_s, self.stale_s = cycle_s, stale_s
        self.device = device or f"ABB EGM {host}:{port}"
        self.refused: list[tuple[str, int]] = []
        self.bad = 0  # datagrams from the controller that were no EgmRobot
        self._ips: frozenset[str] = frozenset()
        self._sock: socket.socket | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._cond = threading.Condition()
        self._frames: collections.deque[tuple[int, EgmRobot]] = collections.deque(maxlen=HISTORY)
        self._count = 0
        self._last_at: float | None = None

    @property
    def address(self) -> tuple[str, int]:
        assert self._sock is not None
        host, port = self._sock.getsockname()[:2]
        return str(host), int(port)

    def listen(self) -> None:
        """Bind the port and start receiving (idempotent)."""
        if self._sock is not None:
            return
        self._stop.clear()
        try:
            self._ips = frozenset(i[4][0] for i in socket.getaddrinfo(self.controller_host, None))
            sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        except OSError as exc:
            raise ConnectionLost(f"cannot resolve {self.controller_host}: {exc}", device=self.device) from exc
        try:
            sock.bind((self.host, self.port))
        except OSError as exc:
            sock.close()
            raise ConnectionLost(
                f"cannot listen for EGM on {self.host}:{self.port}: {exc.strerror or exc}", device=self.device
            ) from exc
        sock.settimeout(0.1)
        self._sock = sock
        self._thread = threading.Thread(target=self._run, name="abb-egm", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        sock = self._sock
        assert sock is not None
        while not self._stop.is_set():
            try:
                data, peer = sock.recvfrom(65536)
            except TimeoutError:
                continue
            except OSError:
                return
            if peer[0] not in self._ips:
                self.refused.append((peer[0], peer[1]))
                del self.refused[:-100]
                continue
            try:
                frame = decode(data)
            except EgmError:
                self.bad += 1
                continue
            with self._cond:
                self._count += 1
                self._frames.append((self._count, frame))
                self._last_at = time.monotonic()
                self._cond.notify_all()

    def wait_first(self, timeout_s: float) -> None:
        """The first frame within timeout_s, or DeviceTimeout."""
        with self._cond:
            if not self._cond.wait_for(lambda: self._count > 0, timeout=timeout_s):
                who = f" (refused {len(self.refused)} from other addresses)" if self.refused else ""
                raise DeviceTimeout(
                    f"no EGM frame within {timeout_s:g} s on {self.host}:{self.port}{who}", device=self.device
                )

    def stale(self) -> str | None:
        """Why the stream is stale (no frame for stale_s), None when fresh."""
        with self._cond:
            if self._last_at is None:
                return "no EGM frame received"
            age = time.monotonic() - self._last_at
        return f"no EGM frame for {age:.2f} s" if age > self.stale_s else None

    def require_fresh(self) -> None:
        reason = self.stale()
        if reason:
            raise DeviceFault(f"the EGM stream is stale: {reason}", code=EGM_STALE, device=self.device)

    @property
    def last_seq(self) -> int:
        with self._cond:
            return self._count

    def frames_from(self, seq: int) -> list[tuple[int, EgmRobot]]:
        with self._cond:
            return [(s, f) for s, f in self._frames if s >= seq]

    def wait_for_frame(self, seq: int, timeout_s: float) -> bool:
        with self._cond:
            return self._cond.wait_for(lambda: self._count >= seq, timeout=timeout_s)

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        if self._sock is not None:
            with contextlib.suppress(OSError):
                self._sock.close()
            self._sock = None
