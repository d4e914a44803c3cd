"""What every driver client checks of the limits it is given: nothing waits forever (DESIGN.md's habits), so each
timeout (and each rate a wait is computed from) must be positive, and a settle wait's tolerance and window sane.
A settle wait on a stream of numbered frames (`SettleWindow`, the KR C2's RSI and ABB's EGM). And the two pieces of
every wait on a device: the time left before a deadline (`time_left`: the client's own
DeviceTimeout once there is none) and one read of a stream socket within a timeout (`receive`: bytes, None when none
came, ConnectionLost when the socket fails or the peer closes it).

One place for the checks and loops the emScon, KR C2 (EKI, RSI), UR, meteo and PLC clients made each in their own
words (the PLC's reads are pymodbus's own, bounded by its timeout)."""

from __future__ import annotations

import math
import socket
import time
from collections.abc import Callable

from trackcal.drivers.errors import ConnectionLost, DeviceError, DeviceTimeout


def require_positive(**limits: float) -> None:
    """ValueError naming the first of `limits` that is not a positive number (zero, negative or NaN)."""
    for name, value in limits.items():
        if not value > 0:
            raise ValueError(f"{name} must be positive: nothing waits forever")


def require_settle_limits(tolerance_deg: float, window_s: float, timeout_s: float) -> None:
    """A settle wait (Robot.wait_settled): a positive tolerance and timeout, a window of zero or more seconds."""
    if not (tolerance_deg > 0 and window_s >= 0 and timeout_s > 0):
        raise ValueError("tolerance_deg and timeout_s must be positive, window_s non-negative")


class SettleWindow:
    """A settle wait judged on a stream's frames, numbered one controller cycle (`cycle_s`) apart (KR C2 RSI, ABB
    EGM): the joints have settled at the first frame that stays within `tolerance_deg` of the window's first frame
    for `window_s` of controller time; `timeout_s` of controller time past `start_seq` without that is a
    DeviceTimeout. Counting frames, not the PC's clock, keeps the judgement the controller's, whatever the load."""

    def __init__(
        self, tolerance_deg: float, window_s: float, timeout_s: float, cycle_s: float, start_seq: int, device: str
    ):
        self.tolerance_deg, self.window_s, self.timeout_s = tolerance_deg, window_s, timeout_s
        self.cycle_s, self.start_seq, self.device = cycle_s, start_seq, device
        self.anchor: tuple[float, ...] | None = None  # the window's first frame
        self.anchor_seq = 0

    def settled(self, seq: int, joints: tuple[float, ...]) -> bool:
        """Whether the frame `seq` with `joints` ends the window (frames fed in order)."""
        if self.anchor is None or any(
            abs(a - b) > self.tolerance_deg for a, b in zip(joints, self.anchor, strict=True)
        ):
            self.anchor, self.anchor_seq = joints, seq
        if (seq - self.anchor_seq) * self.cycle_s >= self.window_s - 1e-9:
            return True
        if (seq - self.start_seq + 1) * self.cycle_s > self.timeout_s:
            raise DeviceTimeout(
                f"joints not settled within {self.tolerance_deg} deg over {self.window_s} s after {self.timeout_s} s "
                "of controller time",
                device=self.device,
            )
        return False

    def restart(self) -> None:
        """The stream skipped frames (the reader fell behind its history): the window starts again."""
        self.anchor = None

    def frames_wanted(self, next_seq: int) -> int:
        """Frames still needed, from `next_seq` on, to end the window if they all stay within the tolerance."""
        have = 0 if self.anchor is None else next_seq - 1 - self.anchor_seq
        return math.ceil(self.window_s / self.cycle_s - 1e-9) - have + (1 if self.anchor is None else 0)


def time_left(deadline: float, expired: Callable[[], DeviceError]) -> float:
    """Seconds before `deadline` (time.monotonic()); once none are left, raises expired(): the client's own error,
    which says what it waited for and how long (a DeviceTimeout)."""
    left = deadline - time.monotonic()
    if left <= 0:
        raise expired()
    return left


def receive(
    sock: socket.socket,
    nbytes: int,
    timeout_s: float,
    *,
    device: str,
    failed: str,
    closed: str,
    drop: Callable[[], None],
) -> bytes | None:
    """One read of at most `nbytes` from a stream socket within `timeout_s`: the bytes, or None when none came in
    time (also when no time is left). A read that fails, or the peer closing the stream, is the end of the
    connection: `drop()` (the client lets go of its socket), then ConnectionLost "`failed`: <the error>" or
    `closed`."""
    if not timeout_s > 0:
        return None
    try:
        sock.settimeout(timeout_s)
        data = sock.recv(nbytes)
    except TimeoutError:
        return None
    except OSError as exc:
        drop()
        raise ConnectionLost(f"{failed}: {exc}", device=device) from exc
    if not data:
        drop()
        raise ConnectionLost(closed, device=device)
    return data


def claim_socket(address: str, device: str) -> socket.socket:
    """This PC's claim on a controller: an abstract Unix socket bound to `address` (a leading NUL, unix(7): no file,
    released by the kernel when the process ends, kill -9 included), held until closed. A second claim raises
    ConnectionLost (its cause the OSError, EADDRINUSE) before anything touches the robot."""
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        sock.bind(address)
    except OSError as exc:
        sock.close()
        raise ConnectionLost(
            f"another trackcal process on this PC drives this controller ({exc.strerror})", device=device
        ) from exc
    return sock
