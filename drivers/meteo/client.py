"""Serial meteo sensor client (pyserial) implementing drivers.interfaces.Meteo.

One `read()` = flush stale input, send the request b"M<n>\\r\\n" with this client's next request number n,
collect lines until the answer echoing N=<n> or the deadline, parse each with drivers.meteo.codec. An answer
to another number (a late answer to an earlier request, or a second reader's on the same port) is discarded;
a line without a number is refused (ProtocolError). Nothing waits longer than `timeout_s` (plus one poll
slice).

pyserial notes (installed pyserial 3.5, serial/serialutil.py and serial/serialposix.py):
- `serial.serial_for_url(url, ...)` opens plain device paths too (a pty slave such as /dev/pts/5 in tests)
  and URLs such as socket://host:port or rfc2217:// for serial-over-LAN adapters.
- `Serial.read_until` restarts a full `timeout` for every byte it reads (serialutil.py, read_until calls
  read(1), each with its own Timeout), so a slow trickle can stretch it to twice the timeout; this client
  therefore reads with a short per-read timeout against its own monotonic deadline instead.
"""

from __future__ import annotations

import contextlib
import functools
import time

import serial

from trackcal.drivers.errors import ConnectionLost, DeviceTimeout, ProtocolError
from trackcal.drivers.interfaces import Environment
from trackcal.drivers.meteo.codec import MAX_LINE_BYTES, MAX_SEQ, parse_line, request
from trackcal.drivers.transport import require_positive, time_left

_POLL_S = 0.02  # per-read timeout slice; the overall deadline is timeout_s


class SerialMeteo:
    """A T/P/H sensor on a serial line. `port` is a device path or a pyserial URL."""

    def __init__(self, port: str, baudrate: int = 9600, timeout_s: float = 1.0) -> None:
        require_positive(timeout_s=timeout_s)
        self.port = port
        self.baudrate = baudrate
        self.timeout_s = timeout_s
        self.device = f"meteo {port}"
        self._serial: serial.SerialBase | None = None
        self._seq = 0  # the number of the next request, 0..MAX_SEQ, wrapping

    def connect(self) -> None:
        if self._serial is not None:
            return
        try:
            self._serial = serial.serial_for_url(
                self.port,
                baudrate=self.baudrate,
                bytesize=serial.EIGHTBITS,
                parity=serial.PARITY_NONE,
                stopbits=serial.STOPBITS_ONE,
                timeout=min(_POLL_S, self.timeout_s),
                write_timeout=self.timeout_s,
            )
        except (serial.SerialException, OSError, ValueError) as exc:
            raise ConnectionLost(f"cannot open serial port while connecting: {exc}", device=self.device) from exc

    def read(self) -> Environment:
        port = self._serial
        if port is None:
            raise ConnectionLost("not connected (call connect() first) while reading", device=self.device)
        seq, self._seq = self._seq, (self._seq + 1) % (MAX_SEQ + 1)
        try:
            port.reset_input_buffer()  # a late answer to an earlier, timed-out request is stale: drop it
            port.write(request(seq))
            port.flush()
            return self._read_answer(port, seq)
        except serial.SerialTimeoutException as exc:
            raise DeviceTimeout(f"request not written within {self.timeout_s} s", device=self.device) from exc
        except (serial.SerialException, OSError) as exc:
            self.close()
            raise ConnectionLost(f"serial I/O failed while reading: {exc}", device=self.device) from exc

    def _read_answer(self, port: serial.SerialBase, seq: int) -> Environment:
        """The answer to request `seq`; answers to other numbers are skipped until the deadline."""
        deadline = time.monotonic() + self.timeout_s
        buffer = bytearray()
        skipped = 0
        while True:
            newline = buffer.find(b"\n")
            if newline >= 0:
                line, buffer = bytes(buffer[: newline + 1]), buffer[newline + 1 :]
                try:
                    reading = parse_line(line)
                except ProtocolError as exc:
                    raise ProtocolError(str(exc), device=self.device) from exc
                if reading.seq is None:
                    raise ProtocolError(
                        f"answer {line!r} carries no request number N= (sent M{seq})", device=self.device
                    )
                if reading.seq == seq:
                    return reading.to_environment()
                skipped += 1  # not ours: a late answer, or another reader's on this port
                continue
            if len(buffer) > MAX_LINE_BYTES:
                raise ProtocolError(
                    f"no line end within {MAX_LINE_BYTES} bytes (got {bytes(buffer[:40])!r}...)",
                    device=self.device,
                )
            time_left(deadline, functools.partial(self._no_answer, seq, buffer, skipped))
            buffer += port.read(max(1, min(port.in_waiting, MAX_LINE_BYTES + 1)))

    def _no_answer(self, seq: int, buffer: bytearray, skipped: int) -> DeviceTimeout:
        got = f"; partial line {bytes(buffer)!r}" if buffer else ""
        if skipped:
            got += f"; discarded {skipped} answer(s) to other requests (another reader on the port?)"
        return DeviceTimeout(f"no answer to request M{seq} within {self.timeout_s} s{got}", device=self.device)

    def close(self) -> None:
        port, self._serial = self._serial, None
        if port is not None:
            with contextlib.suppress(serial.SerialException, OSError):
                port.close()

    def __enter__(self) -> SerialMeteo:
        self.connect()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()
