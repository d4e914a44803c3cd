"""Round-trip overhead of one stationary measurement through EmsconTracker + MockEmscon over loopback.

The mock runs on a VirtualClock, so the simulated measurement time costs nothing: what is timed is the
client's encode/frame/decode, the mock's thread hand-off and two TCP exchanges (acknowledgement, then result).
Baseline, measured in the same run: a bare request/answer ping-pong of the same sizes (12-byte request,
16-byte acknowledgement + 156-byte result) between two plain sockets on loopback, no codec and no mock logic.
Printed: median and p95 per measurement, and the ratio to the baseline.
"""

from __future__ import annotations

import socket
import statistics
import threading
import time

from trackcal.drivers.emscon.client import EmsconTracker
from trackcal.mocks.clock import VirtualClock
from trackcal.mocks.servers.emscon import MockEmscon

N = 500
WARMUP = 20


def _ours(n: int) -> list[float]:
    server = MockEmscon(lambda e: (1000.0, 0.0, 0.0, 0.01, 0.01, 0.01), VirtualClock()).start()
    tracker = EmsconTracker(*server.address, timeout_s=5.0, measure_timeout_s=5.0)
    try:
        tracker.connect()
        tracker.initialize()
        tracker.find_reflector(1000.0, 0.0, 0.0, 5.0)
        times = []
        for i in range(n + WARMUP):
            t0 = time.perf_counter()
            tracker.measure()
            if i >= WARMUP:
                times.append(time.perf_counter() - t0)
        return times
    finally:
        tracker.close()
        server.stop()


def _baseline(n: int) -> list[float]:
    listener = socket.create_server(("127.0.0.1", 0))
    request, ack, result = bytes(12), bytes(16), bytes(156)

    def echo() -> None:
        conn, _ = listener.accept()
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        with conn:
            while True:
                got = b""
                while len(got) < len(request):
                    chunk = conn.recv(64)
                    if not chunk:
                        return
                    got += chunk
                conn.sendall(ack)
                conn.sendall(result)

    thread = threading.Thread(target=echo, daemon=True)
    thread.start()
    times = []
    with socket.create_connection(listener.getsockname()) as sock:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        for i in range(n + WARMUP):
            t0 = time.perf_counter()
            sock.sendall(request)
            need, got = len(ack) + len(result), 0
            while got < need:
                got += len(sock.recv(need - got))
            if i >= WARMUP:
                times.append(time.perf_counter() - t0)
    thread.join(timeout=2.0)
    listener.close()
    return times


def _p95(values: list[float]) -> float:
    return sorted(values)[int(0.95 * (len(values) - 1))]


def main() -> None:
    base = _baseline(N)
    ours = _ours(N)
    b_med, o_med = statistics.median(base), statistics.median(ours)
    print(f"emScon measure() round trip over loopback, {N} measurements (virtual clock, no simulated wait)")
    print(f"  baseline raw socket ping-pong : median {b_med * 1e6:8.1f} us   p95 {_p95(base) * 1e6:8.1f} us")
    print(f"  client + mock                 : median {o_med * 1e6:8.1f} us   p95 {_p95(ours) * 1e6:8.1f} us")
    print(f"  ratio (median)                : {o_med / b_med:.2f}x")
    print(f"  throughput                    : {1.0 / o_med:,.0f} measurements/s")


if __name__ == "__main__":
    main()
