"""What every driver client checks of the limits it is given: nothing waits forever (DESIGN.md's habits), so each
timeout (and each rate a wait is computed from) must be positive, and a settle wait's tolerance and window sane.
And the two pieces of every wait on a device: the time left before a deadline (`time_left`: the client's own
DeviceTimeout once there is none) and one read of a stream socket within a timeout (`receive`: bytes, None when none
came, ConnectionLost when the socket fails or the peer closes it).

One place for the checks and loops the emScon, KR C2 (EKI, RSI), UR, meteo and PLC clients made each in their own
words (the PLC's reads are pymodbus's own, bounded by its timeout)."""

from __future__ import annotations

import socket
import time
from collections.abc import Callable

from trackcal.drivers.errors import ConnectionLost, DeviceError


def require_positive(**limits: float) -> None:
    """ValueError naming the first of `limits` that is not a positive number (zero, negative or NaN)."""
    for name, value in limits.items():
        if not value > 0:
            raise ValueError(f"{name} must be positive: nothing waits forever")


def require_settle_limits(tolerance_deg: float, window_s: float, timeout_s: float) -> None:
    """A settle wait (Robot.wait_settled): a positive tolerance and timeout, a window of zero or more seconds."""
    if not (tolerance_deg > 0 and window_s >= 0 and timeout_s > 0):
        raise ValueError("tolerance_deg and timeout_s must be positive, window_s non-negative")


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
