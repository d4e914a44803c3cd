"""Deterministic mock of the serial meteo sensor on a pseudo-terminal.

`MockMeteo(seed, clock)` opens a pty pair (os.openpty); the client opens `.port_path` (the slave tty) with
pyserial exactly as it would open /dev/ttyUSB0. A background thread reads the master side and answers each
request line b"M<n>\\r\\n" with one measurement line encoded by drivers.meteo.codec, echoing N=<n>.

The answer to request number n carries a reading that is a pure function of (seed, n): a slow
sinusoidal drift per quantity (phase from the seed) plus small Gaussian noise drawn from a generator seeded
by (seed, n). The clock only paces the answer (`response_delay_s`), so a VirtualClock makes it instant.

Fault injection (`inject`), each for the next `times` requests (or until `clear_faults()` with times=None):
  BAD_CHECKSUM  a well-formed line whose checksum is off by one
  GARBAGE       a CR LF terminated line of seeded random bytes
  SILENCE       no answer at all
  OVERLONG      a babbling line of 120 bytes before its CR LF (longer than the 82-byte cap)
Whoever else sends requests on the port (a second reader) never changes the reading of request n.
"""

from __future__ import annotations

import contextlib
import enum
import math
import os
import random
import select
import threading
import tty

from trackcal.drivers.interfaces import RealClock
from trackcal.drivers.meteo.codec import H_RANGE_PCT, MAX_LINE_BYTES, Reading, encode_reading, parse_request
from trackcal.mocks.clock import VirtualClock

# Drift amplitudes and periods (in requests) and noise standard deviations. Amplitudes are of the order of
# a shop floor over an hour (a few tenths of a degree, half a hPa, a few %RH); noise at the resolution of
# the wire format (0.01 degC, 0.01 hPa, 0.1 %RH).
DRIFT_AMPLITUDE = (0.3, 0.5, 2.0)
DRIFT_PERIOD_REQUESTS = (720.0, 1500.0, 900.0)
NOISE_SIGMA = (0.01, 0.02, 0.1)


class MeteoFault(enum.Enum):
    BAD_CHECKSUM = "bad_checksum"
    GARBAGE = "garbage"
    SILENCE = "silence"
    OVERLONG = "overlong"


def reading_for(seed: int, n: int, base: tuple[float, float, float] = (20.0, 1013.25, 45.0)) -> Reading:
    """The reading the mock serves for request number n (without the number): a pure function of (seed, n,
    base)."""
    phases = random.Random(f"meteo-phase:{seed}")
    rng = random.Random(f"meteo-noise:{seed}:{n}")  # str seeds hash with SHA-512: stable across runs
    values = []
    terms = zip(base, DRIFT_AMPLITUDE, DRIFT_PERIOD_REQUESTS, NOISE_SIGMA, strict=True)
    for base_v, amp, period, sigma in terms:
        phase = phases.uniform(0.0, 2.0 * math.pi)
        values.append(base_v + amp * math.sin(2.0 * math.pi * n / period + phase) + rng.gauss(0.0, sigma))
    t, p, h = values
    return Reading(t, p, min(max(h, H_RANGE_PCT[0]), H_RANGE_PCT[1]))


class MockMeteo:
    def __init__(
        self,
        seed: int,
        clock: RealClock | VirtualClock | None = None,
        base: tuple[float, float, float] = (20.0, 1013.25, 45.0),
        response_delay_s: float = 0.05,
    ) -> None:
        self.seed = seed
        self.clock = clock if clock is not None else VirtualClock()
        self.base = base
        self.response_delay_s = response_delay_s
        self.requests = 0  # requests seen so far, from any reader
        self.answers: list[bytes] = []  # every line written, in order (for determinism checks)
        self._faults: list[tuple[MeteoFault, int | None]] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._master_fd, self._slave_fd = os.openpty()
        tty.setraw(self._slave_fd)  # no echo, no CR/LF translation before the client configures the port
        self.port_path = os.ttyname(self._slave_fd)

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> MockMeteo:
        if self._thread is None:
            self._thread = threading.Thread(target=self._serve, name=f"mock-meteo-{self.seed}", daemon=True)
            self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        for fd in (self._master_fd, self._slave_fd):
            with contextlib.suppress(OSError):
                os.close(fd)
        self._master_fd = self._slave_fd = -1

    def __enter__(self) -> MockMeteo:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.stop()

    # ------------------------------------------------------------------ fault injection
    def inject(self, fault: MeteoFault, times: int | None = 1) -> None:
        """Apply `fault` to the next `times` requests; times=None: until clear_faults()."""
        with self._lock:
            self._faults.append((fault, times))

    def clear_faults(self) -> None:
        with self._lock:
            self._faults.clear()

    def _next_fault(self) -> MeteoFault | None:
        with self._lock:
            if not self._faults:
                return None
            fault, times = self._faults[0]
            if times is not None:
                if times <= 1:
                    self._faults.pop(0)
                else:
                    self._faults[0] = (fault, times - 1)
            return fault

    # ------------------------------------------------------------------ protocol
    def answer(self, n: int, fault: MeteoFault | None = None) -> bytes:
        """The bytes answered to request n under `fault` (b"" for SILENCE); pure in (seed, base, n, fault)."""
        if fault is MeteoFault.SILENCE:
            return b""
        if fault is MeteoFault.GARBAGE:
            rng = random.Random(f"meteo-garbage:{self.seed}:{n}")
            alphabet = b"$*,=.0123456789ABCDEFMTPH\x00\xff~ "
            junk = bytes(rng.choice(alphabet) for _ in range(rng.randint(1, 60)))
            return junk.replace(b"\r", b"").replace(b"\n", b"") + b"\r\n"
        r = reading_for(self.seed, n, self.base)
        line = encode_reading(Reading(r.temperature_c, r.pressure_hpa, r.humidity_pct, n))
        if fault is MeteoFault.OVERLONG:
            return line[:-2] + b"," * (120 - len(line)) + b"\r\n"
        if fault is MeteoFault.BAD_CHECKSUM:
            star = line.rindex(b"*")
            wrong = (int(line[star + 1 : star + 3], 16) + 1) % 256
            line = line[: star + 1] + f"{wrong:02X}".encode("ascii") + b"\r\n"
        return line

    def _serve(self) -> None:
        pending = bytearray()
        while not self._stop.is_set():
            try:
                ready, _, _ = select.select([self._master_fd], [], [], 0.05)
                if not ready:
                    continue
                pending += os.read(self._master_fd, 1024)
            except OSError:
                if self._stop.is_set():
                    return
                continue  # EIO while no client holds the slave open: keep serving
            while (end := pending.find(b"\n")) >= 0:
                request, pending = bytes(pending[: end + 1]), pending[end + 1 :]
                n = parse_request(request)
                if n is not None:
                    self._answer_request(n)
                # any other line is ignored, as the real sensor does (see meteo-protocol.md)
            if len(pending) > MAX_LINE_BYTES:
                pending.clear()  # garbage without line ends never grows the buffer unbounded

    def _answer_request(self, n: int) -> None:
        self.requests += 1
        fault = self._next_fault()
        data = self.answer(n, fault)
        self.clock.sleep(self.response_delay_s)
        if data:
            self.answers.append(data)
            with contextlib.suppress(OSError):
                os.write(self._master_fd, data)
